#!/usr/bin/python3
"""Where on a frame a variant's error lies: its hair pixels (truth alpha >
0.01) split by the truth's highlight x alpha (below 0.02, 0.02-0.1, above
0.1: the bright streaks) and by the truth's texture (the variance of its
composite over each pixel's 3x3 window: below the frame's median, median to
90th percentile, above), with each group's share of the hair pixels, its
share of the variant's squared error, and the mean square error of the
variant and of the frame's stochastic-transparency baselines (st16.*,
st64.*, those the frame has) in the evaluation's look (train.EVAL_LOOK,
the composite `hairfilter eval` scores).

    error_by_highlight.py [--weights VARIANT.safetensors] FRAME.exr ...

A Markdown table per frame; PyTorch on the CPU (weights/hfnet.py), the
frame's samples sanitised as the network sees them, the estimate read
where the variant reads it (weights/dataset.py).
"""
import argparse
import os
import sys

import numpy as np
import torch
from numpy.lib.stride_tricks import sliding_window_view

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import dataset  # noqa: E402
import hfnet  # noqa: E402
import train  # noqa: E402


def composite(y):
    """The evaluation's look (train.composite with train.EVAL_LOOK) of
    [h][w][3] (colour, highlight, alpha), [h][w][3]."""
    t = hfnet.nhwc_to_nchw(np.asarray(y, dtype=np.float32)[None])
    return hfnet.nchw_to_nhwc(train.composite(t, *train.eval_looks(1, "cpu")))[0]


def variant_output(net, path):
    """The variant's outputs [h][w][3] and the truth [h][w][3] of a frame."""
    feat, truth = dataset.load_frame(path, spp=net.cfg["spp"], dtype=np.float32)
    h, w = feat.shape[:2]
    parts = [feat.reshape(h, w, -1)]
    if net.cfg.get("estimate"):
        parts.append(dataset.load_estimate(path, dtype=np.float32))
    x = hfnet.nhwc_to_nchw(np.concatenate(parts, -1)[None])
    with torch.no_grad():
        out = hfnet.nchw_to_nhwc(net(x))[0]
    return np.asarray(out, dtype=np.float32), truth


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--weights", default=hfnet.bundled("kernel_mix.safetensors"))
    ap.add_argument("frames", nargs="+")
    args = ap.parse_args()
    torch.set_num_threads(2)
    net = hfnet.load_model_or_exit(args.weights, "error_by_highlight.py").eval()
    name = net.cfg.get("name", os.path.basename(args.weights))
    for path in args.frames:
        try:
            out, truth = variant_output(net, path)
            names, data = dataset.read_exr(path)
        except dataset.DatasetError as e:
            sys.exit(f"error_by_highlight.py: {e}")
        ct = composite(truth)
        err = {name: ((composite(out) - ct) ** 2).mean(-1)}
        for k in (16, 64):
            ch = [f"st{k}.color", f"st{k}.highlight", f"st{k}.alpha"]
            if all(c in names for c in ch):
                st = dataset.pick_channels(names, data, ch, path)
                err[f"ST {k}"] = ((composite(st) - ct) ** 2).mean(-1)
        hair = truth[..., 2] > 0.01
        if not hair.any():
            print(f"{path}: no hair pixels (truth alpha > 0.01)")
            continue
        hl = truth[..., 1] * truth[..., 2]
        g = ct.mean(-1)
        tex = sliding_window_view(np.pad(g, 1, mode="edge"), (3, 3)).var(axis=(-1, -2))
        q50, q90 = np.quantile(tex[hair], [0.5, 0.9])
        groups = [("highlight x alpha < 0.02", hl <= 0.02),
                  ("highlight x alpha 0.02-0.1", (hl > 0.02) & (hl <= 0.1)),
                  ("highlight x alpha > 0.1", hl > 0.1),
                  (f"texture < median ({q50:.2e})", tex <= q50),
                  (f"texture median to p90 ({q90:.2e})", (tex > q50) & (tex <= q90)),
                  ("texture > p90", tex > q90)]
        total = err[name][hair].sum()
        print(f"\n{path}: {int(hair.sum())} hair pixels\n")
        print("| group | hair pixels | share of the error | " +
              " | ".join(f"MSE {k}" for k in err) + " |")
        print("|---|---:|---:|" + "---:|" * len(err))
        for label, m in groups:
            m = m & hair
            if not m.any():
                print(f"| {label} | 0% | - |" + " - |" * len(err))
                continue
            print(f"| {label} | {m.sum() / hair.sum():.1%} | {err[name][m].sum() / total:.1%} | " +
                  " | ".join(f"{e[m].mean():.2e}" for e in err.values()) + " |")


if __name__ == "__main__":
    main()
