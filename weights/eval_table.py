#!/usr/bin/python3
"""One Markdown table of a `hairfilter eval --json` document, per frame bucket:

    eval_table.py OUT.json [--methods SUBSTR,SUBSTR,...] [--below]

A row per method (all of them, or those whose label holds one of the
--methods substrings, in that order; a substring no label holds is an
error that lists the labels), `PSNR / SSIM` overall and in every
bucket of the three frame groupings (strand width, coverage, resolution),
each column headed by its bucket and frame count (buckets without frames
left out): the table the weights' cards and docs/QUALITY.md quote.
--below adds, for each network, the count of frames where it is below its
own input and below stochastic transparency at 16 spp (PSNR / SSIM /
either), then a row per such frame: its file and the network's, the
input's and 16 spp's PSNR / SSIM (the frames the counts hold, as eval
marked them). Reads only what `hairfilter eval` wrote; it computes no
score of its own.
"""
import argparse
import json
import sys

FRAME_GROUPINGS = ("strand_width_frames", "coverage_frames", "resolution_frames")


def cell(v):
    """'PSNR / SSIM' of a bucket ('-' where it holds no frame)."""
    if not v or not v.get("frames"):
        return "-"
    psnr = "inf" if v.get("psnr") is None else f"{v['psnr']:.2f}"
    return f"{psnr} / {v['ssim']:.3f}"


def pick(methods, wanted):
    """The methods whose label holds one of the substrings wanted, in their
    order (all of them when none is wanted), and the substrings no label
    holds."""
    if not wanted:
        return list(methods), []
    out, missing = [], []
    for w in wanted:
        found = [m for m in methods if w in m["method"]]
        if not found:
            missing.append(w)
        out += [m for m in found if m not in out]
    return out, missing


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("json", help="the document `hairfilter eval --json` wrote")
    ap.add_argument("--methods", default="", help="comma-separated substrings of the labels")
    ap.add_argument("--below", action="store_true",
                    help="also the networks' frames below their own input and ST 16 spp")
    args = ap.parse_args(argv)
    try:
        with open(args.json) as f:
            doc = json.load(f)
    except OSError as e:
        sys.exit(f"eval_table.py: {args.json}: {e.strerror}")
    except ValueError as e:
        sys.exit(f"eval_table.py: {args.json}: not JSON ({e}); give the file that "
                 f"`hairfilter eval --json` wrote")
    if not isinstance(doc, dict) or doc.get("format") != "hairfilter-eval":
        sys.exit(f"eval_table.py: {args.json} is not a hairfilter eval document")
    groups = {g["key"]: g for g in doc["groupings"]}
    # Buckets that hold no frame (strand width "none") are left out.
    keep = {key: [i for i, b in enumerate(groups[key]["buckets"]) if b["frames"]]
            for key in FRAME_GROUPINGS}
    heads = [f"all {doc['frames']} frames"]
    for key in FRAME_GROUPINGS:
        heads += [f"{groups[key]['buckets'][i]['bucket']} ({groups[key]['buckets'][i]['frames']})"
                  for i in keep[key]]
    wanted = [s for s in args.methods.split(",") if s]
    rows, missing = pick(doc["methods"], wanted)
    if missing:
        # A table without the rows asked for would pass for a complete one.
        sys.exit(f"eval_table.py: --methods: no method of {args.json} has "
                 f"{', '.join(repr(w) for w in missing)} in its label"
                 f"{' (the others matched)' if len(missing) < len(wanted) else ''}"
                 f"; its labels: {'; '.join(m['method'] for m in doc['methods'])}")
    print("| method | " + " | ".join(heads) + " |")
    print("|---|" + "---:|" * len(heads))
    for m in rows:
        cells = [cell(m["overall"])]
        for key in FRAME_GROUPINGS:
            cells += [cell(m[key][i]) for i in keep[key]]
        label = f"**{m['method']}**" if m["kind"] == "network" else m["method"]
        print(f"| {label} | " + " | ".join(cells) + " |")
    if args.below:
        print("\n| network | below its own input (PSNR / SSIM / either) | below ST 16 spp "
              "(PSNR / SSIM / either) |\n|---|---:|---:|")
        for m in rows:
            if m["kind"] != "network":
                continue
            a, b = m["below_own_input"], m["below_st16"]
            print(f"| {m['method']} | {a['psnr']} / {a['ssim']} / {a['either']} of {a['frames']} "
                  f"| {b['psnr']} / {b['ssim']} / {b['either']} of {b['frames']} |")
        below_frames(doc, [m for m in rows if m["kind"] == "network"])


def score(v):
    """'PSNR / SSIM' of one frame's score ('-' where there is none)."""
    if not v:
        return "-"
    psnr = "inf" if v.get("psnr") is None else f"{v['psnr']:.2f}"
    return f"{psnr} / {v['ssim']:.4f}"


def below_frames(doc, nets):
    """A row per network and frame that `hairfilter eval` marked below its
    own input or below ST 16 spp (frame_rows' below_own_input and
    below_st16), with the three scores side by side."""
    out = []
    for r in doc.get("frame_rows", []):
        by = {m["method"]: m for m in r["methods"]}
        st16 = next((m for m in r["methods"] if m["method"] == "stochastic transparency 16 spp"),
                    None)
        for n in nets:
            m = by.get(n["method"])
            if not m or not (m.get("below_own_input") or m.get("below_st16")):
                continue
            which = " and ".join(w for w, k in (("own input", "below_own_input"),
                                                 ("16 spp", "below_st16")) if m.get(k))
            out.append(f"| {n['method']} | {r['file']} | {which} | {score(m)} | "
                       f"{score(m.get('own_input'))} | {score(st16)} |")
    if out:
        print("\n| network | frame | below | network | own input | 16 spp |\n"
              "|---|---|---|---:|---:|---:|")
        print("\n".join(out))


if __name__ == "__main__":
    main()
