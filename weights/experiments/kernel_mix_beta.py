#!/usr/bin/python3
"""How KernelMix mixes its two sums on a frame, and what a better mix would
give: its mixing weight beta over the hair pixels (0: the alpha-corrected
estimate's kernel-weighted sum, 1: the samples' own; protocol/FEATURES.md,
"Mixing the two sums"), and the mean square error over the hair pixels
(truth alpha > 0.01) of colour x alpha plus highlight x alpha against the
ground truth for its output with beta as learnt, with beta forced to 0 and
to 1, and for the better of those two at each pixel (an oracle no network
reaches, a bound on what the mixing output could gain), beside stochastic
transparency at 16 and 64 spp (the frame's st16.*, st64.*).

    kernel_mix_beta.py [--weights KERNELMIX.safetensors] FRAME.exr ...

A Markdown row per frame. PyTorch on the CPU (weights/hfnet.py), the
frame's samples sanitised as the network sees them (weights/dataset.py).
Not `hairfilter eval`'s look (a composite under a light): a linear error of
the premultiplied outputs, to compare the mixes with each other.
"""
import argparse
import os
import sys

import numpy as np
import torch

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import dataset  # noqa: E402
import hfnet  # noqa: E402


def premultiplied_error(o, g):
    """Per pixel: (colour x alpha - truth's)^2 + (highlight x alpha - truth's)^2
    of outputs o and truth g, both [h][w][3] (colour, highlight, alpha)."""
    return ((o[..., 0] * o[..., 2] - g[..., 0] * g[..., 2]) ** 2 +
            (o[..., 1] * o[..., 2] - g[..., 1] * g[..., 2]) ** 2).astype(np.float64)


def outputs(net, x):
    """The network's outputs [h][w][3] on NCHW input x with beta as learnt,
    forced to 0 and forced to 1, and its beta map [h][w]."""
    taps = hfnet.kernel_taps(net.cfg["kernel_radius"])
    with torch.no_grad():
        raw = net.raw_any_size(x)
        beta = torch.sigmoid(hfnet.KERNEL_MIX_GAIN * raw[:, taps + 3:taps + 4].float())
        out = {"learnt": hfnet.nchw_to_nhwc(net.finish(raw, x))[0]}
        for name, m in (("estimate", -1e4), ("samples", 1e4)):
            r = raw.clone()
            r[:, taps + 3] = m   # the mixing output: sigmoid saturates at 0 or 1
            out[name] = hfnet.nchw_to_nhwc(net.finish(r, x))[0]
    return out, beta[0, 0].numpy()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--weights", default=hfnet.bundled("kernel_mix.safetensors"))
    ap.add_argument("frames", nargs="+")
    args = ap.parse_args()
    net = hfnet.load_model_or_exit(args.weights, "kernel_mix_beta.py").eval()
    if not net.cfg.get("kernel_mix"):
        sys.exit(f"kernel_mix_beta.py: {args.weights} is not a KernelMix file (no kernel_mix in "
                 "its metadata)")
    head = ("| frame | hair pixels | beta p10 / p50 / p90 | learnt | beta 0 (estimate) | beta 1 "
            "(samples) | better of the two per pixel | ST 16 | ST 64 |\n"
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for path in args.frames:
        try:
            feat, truth = dataset.load_frame(path, spp=net.cfg["spp"], dtype=np.float32)
            est = dataset.load_estimate(path, dtype=np.float32)
        except dataset.DatasetError as e:
            sys.exit(f"kernel_mix_beta.py: {e}")
        h, w = feat.shape[:2]
        x = hfnet.nhwc_to_nchw(np.concatenate([feat.reshape(h, w, -1), est], -1)[None])
        out, beta = outputs(net, x)
        hair = truth[..., 2] > 0.01
        err = {k: premultiplied_error(v, truth)[hair].mean() for k, v in out.items()}
        oracle = np.minimum(premultiplied_error(out["estimate"], truth),
                            premultiplied_error(out["samples"], truth))[hair].mean()
        names, data = dataset.read_exr(path)
        st = []
        for k in (16, 64):
            if all(f"st{k}.{c}" in names for c in ("color", "highlight", "alpha")):
                c = dataset.pick_channels(names, data, [f"st{k}.color", f"st{k}.highlight",
                                                        f"st{k}.alpha"], path)
                st.append(f"{premultiplied_error(c, truth)[hair].mean():.3e}")
            else:
                st.append("-")
        b = np.percentile(beta[hair], [10, 50, 90])
        if head:   # after the first frame is read: a refused one prints no table
            print(head)
            head = None
        print(f"| {path} | {int(hair.sum())} | {b[0]:.3f} / {b[1]:.3f} / {b[2]:.3f} | "
              f"{err['learnt']:.3e} | {err['estimate']:.3e} | {err['samples']:.3e} | "
              f"{oracle:.3e} | {st[0]} | {st[1]} |")


if __name__ == "__main__":
    main()
