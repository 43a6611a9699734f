"""Where a network's error lies on thick hair: over the frames whose median
strand alpha (protocol/FEATURES.md, "Input statistics") is at least
--min-strand-alpha, the composite's MSE (the look of `hairfilter eval`,
train.EVAL_LOOK) and the alpha MSE of each result, on pixels the hair fully
covers (ground-truth alpha >= 0.9) and at edges (0 < alpha < 0.9); and, on
pixels whose samples are all covered, the MSE of a front-to-back composite
of the distinct fragments among the samples, each taken to cover the pixel
(`--layers`).

  python3 weights/experiments/thick_pixels.py [--layers] [--results st2,st16,st4] FRAME.exr|DIR...

Results are channel prefixes of the frames (st2: a network's result added by
eval_rows.py; st4, st16, st64: stochastic transparency)."""
import argparse
import glob
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import numpy as np  # noqa: E402

import dataset  # noqa: E402
import train  # noqa: E402

HAIR, LIGHT, BG = (np.array(v) for v in train.EVAL_LOOK)
FULL = 0.9


def composite(c, h, a):
    """hf_composite of (colour, highlight, alpha) planes: [h][w][3]."""
    return np.clip(a[..., None] * LIGHT * (HAIR * c[..., None] + h[..., None])
                   + (1 - a[..., None]) * BG, 0, 1)


def planes(names, data, prefix):
    """The (colour, highlight, alpha) planes of one result, channels
    prefix.color, prefix.highlight, prefix.alpha of a frame read by
    dataset.read_exr (names, data [h][w][c])."""
    return [data[..., names.index(f"{prefix}.{c}")] for c in dataset.TARGETS]


def layer_composite(samples):
    """(colour, highlight, alpha) of one pixel's samples [spp][4] (colour,
    highlight, alpha, depth), all covered: its distinct fragments (equal
    colour, highlight and alpha) front to back by their mean depth, each
    with its own alpha over the whole pixel."""
    frags = {}
    for s in samples:
        frags.setdefault((s[0], s[1], s[2]), []).append(s[3])
    t, a, c, h = 1.0, 0.0, 0.0, 0.0
    for _, (fc, fh, fa) in sorted((np.mean(d), k) for k, d in frags.items()):
        v = t * fa
        a, c, h, t = a + v, c + v * fc, h + v * fh, t * (1 - fa)
    return c / a, h / a, a


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--min-strand-alpha", type=float, default=0.3)
    ap.add_argument("--results", default="st2,st16,st4")
    ap.add_argument("--layers", action="store_true")
    ap.add_argument("paths", nargs="+")
    args = ap.parse_args(argv)
    files = sorted(f for p in args.paths
                   for f in (glob.glob(os.path.join(p, "*.exr")) if os.path.isdir(p) else [p]))
    results = args.results.split(",")
    acc, nframes = {}, 0
    for path in files:
        names, d = dataset.read_exr(path)
        ix = {n: i for i, n in enumerate(names)}
        spp = dataset.count_spp(names)

        def g(k):
            return d[..., ix[k]]
        samples = np.stack([np.stack([g(f"S{k}.{f}") for f in ("color", "highlight", "alpha", "depth")], -1)
                            for k in range(spp)], 2)
        cov = samples[..., 2] > 0
        n = cov.sum(-1)
        strand = np.where(n > 0, (samples[..., 2] * cov).sum(-1) / np.maximum(n, 1), 0)
        if not (n > 0).any() or np.median(strand[n > 0]) < args.min_strand_alpha:
            continue
        nframes += 1
        ga = g("gt.alpha")
        gt = composite(*planes(names, d, "gt"))
        classes = {f"full (alpha >= {FULL})": ga >= FULL, f"edge (0 < alpha < {FULL})": (ga > 0) & (ga < FULL)}
        allcov = n == spp
        if args.layers:
            classes["all samples covered"] = allcov
        for r in results:
            e = ((composite(*planes(names, d, r)) - gt) ** 2).mean(-1)
            ea = (g(r + ".alpha") - ga) ** 2
            for cname, m in classes.items():
                t = acc.setdefault((cname, r), [0.0, 0.0, 0])
                t[0] += e[m].sum()
                t[1] += ea[m].sum()
                t[2] += int(m.sum())
        if args.layers:
            est = np.array([layer_composite(s) for s in samples[allcov]]).reshape(-1, 3)
            e = ((composite(est[:, 0], est[:, 1], est[:, 2]) - gt[allcov]) ** 2).mean(-1)
            t = acc.setdefault(("all samples covered", "fragments front to back"), [0.0, 0.0, 0])
            t[0] += e.sum()
            t[2] += len(e)
    print(f"{nframes} frames of median strand alpha >= {args.min_strand_alpha}\n")
    print("| pixels | result | pixels | composite MSE | alpha MSE |\n|---|---|---:|---:|---:|")
    for (cname, r), (se, sa, cnt) in sorted(acc.items()):
        alpha = f"{sa / cnt:.5f}" if r in results else "-"
        print(f"| {cname} | {r} | {cnt} | {se / max(cnt, 1):.5f} | {alpha} |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
