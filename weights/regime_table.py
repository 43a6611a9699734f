#!/usr/bin/python3
"""Histograms of the input statistics of data sets, side by side, as
Markdown tables: how the frames of a training set spread over the regimes
`hairfilter eval` reports (strand width in pixels, coverage, resolution),
beside the evaluation sets.

    /usr/bin/python3 weights/regime_table.py train=data/regimes256 eval256=data/eval256 ...

A set is NAME=DIR[,DIR...]. Per frame the statistics are those of
weights/input_stats.py on the frame's first 4 samples (the definitions of
protocol/FEATURES.md, "Input statistics"); a crop counts at the size of the
whole frame it was cut from (the manifest's full_width and full_height), as
in `hairfilter eval`. The per-pixel table counts hair pixels (at least one
covered sample) by their strand width, the mean alpha of their covered
samples.
"""
import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import dataset  # noqa: E402
import input_stats  # noqa: E402

# The buckets of hairfilter eval (client/cli/eval_strata.c): the strand-width
# edges 0.03, 0.1, 0.3 and 0.7 rounded down to the bins of the input
# statistics, so that a frame lands in the bucket eval puts it in.
WIDTH_EDGES = [245.0 / 8192, 51.0 / 512, 153.0 / 512, 179.0 / 256]
WIDTH_NAMES = ["<0.03", "0.03-0.1", "0.1-0.3", "0.3-0.7", ">=0.7"]
FULL_EDGES = [0.1, 0.5, 0.9]
FULL_NAMES = ["<0.1", "0.1-0.5", "0.5-0.9", ">=0.9"]
SIDE_EDGES = [384, 768]
SIDE_NAMES = ["256 (<384)", "512 (384-767)", "1024+ (>=768)"]


def bucket(v, edges):
    return int(np.searchsorted(edges, v, side="right"))


def scan(dirs, spp=4):
    """Per-frame statistics and per-pixel width counts of the frames in dirs."""
    frames, pixels = [], np.zeros(len(WIDTH_NAMES), np.int64)
    for e in dataset.read_sets(dirs):
        feat, _ = dataset.load_frame(e["file"], spp=spp, dtype=np.float32,
                                     sanitise=False)
        frames.append(dataset.entry_stats(e, feat, spp))
        mean, n = input_stats.strand_alpha(feat, spp)
        w = mean[n > 0]
        pixels += np.bincount(np.searchsorted(WIDTH_EDGES, w, side="right"),
                              minlength=len(WIDTH_NAMES))
    return frames, pixels


def table(title, names, sets, column, unit="frames"):
    print(f"\n{title}\n")
    print(f"| set | {unit} | " + " | ".join(names) + " |")
    print("|---|---:|" + "---:|" * len(names))
    for name, rows in sets:
        counts = column(rows)
        total = int(sum(counts))
        cells = [f"{c} ({100.0 * c / total:.0f}%)" if total else "0" for c in counts]
        print(f"| {name} | {total} | " + " | ".join(cells) + " |")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sets", nargs="+", metavar="NAME=DIR[,DIR...]")
    ap.add_argument("--spp", type=int, default=4)
    args = ap.parse_args(argv)
    sets = []
    for s in args.sets:
        name, _, dirs = s.partition("=")
        if not dirs:
            ap.error(f"{s}: want NAME=DIR[,DIR...]")
        frames, pixels = scan([d for d in dirs.split(",") if d], args.spp)
        sets.append((name, (frames, pixels)))

    def frame_hist(key, edges, names):
        def col(rows):
            c = [0] * len(names)
            for st in rows[0]:
                if np.isfinite(st[key]):
                    c[bucket(st[key], edges)] += 1
            return c
        return col

    table("Frames by strand width in pixels (strand_alpha_p50)", WIDTH_NAMES, sets,
          frame_hist("strand_alpha_p50", WIDTH_EDGES, WIDTH_NAMES))
    table("Hair pixels by strand width in pixels (mean alpha of the covered samples)",
          WIDTH_NAMES, sets, lambda rows: [int(x) for x in rows[1]], unit="pixels")
    table("Frames by full coverage (hair pixels whose samples are all covered)", FULL_NAMES,
          sets, frame_hist("full_coverage", FULL_EDGES, FULL_NAMES))
    table("Frames by resolution (long side of the whole frame)", SIDE_NAMES, sets,
          frame_hist("long_side", SIDE_EDGES, SIDE_NAMES))
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except dataset.DatasetError as e:
        # A data directory or frame that cannot be used: its own words, no traceback.
        sys.exit(f"regime_table.py: {e}")
