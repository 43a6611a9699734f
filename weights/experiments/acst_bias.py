#!/usr/bin/python3
"""The bias of stochastic transparency's alpha-corrected estimate (acst4.*)
where strands overlap in many layers, what a KernelAC network leaves of it,
and what a fixed correction towards the plain 4-sample estimate would.

Per frame, over the pixels whose ground-truth alpha is 0.9 or more (dense
hair), the mean and the RMS of the premultiplied colour factor's error
(colour x alpha against gt.color x gt.alpha) of:
  acst    the alpha-corrected estimate (Enderton et al. 2010, section 3.3);
  st4     the plain estimate of the 4 samples (mean of colour x covered),
          unbiased: each sample shows the nearest fragment it keeps;
  net     the network's output (`hairfilter infer --weights W`);
  +blurS  net plus the low-pass difference between the two estimates,
          G_S * ((st4 - acst) h) / G_S * h with G_S a Gaussian of
          sigma S pixels and h the hair mask: the bias the alpha-corrected
          estimate has there, measured from the samples themselves.

Usage: acst_bias.py --weights W.safetensors [--hairfilter build/hairfilter]
                    [--sigmas 2,4,8] FRAME.exr ...
Frames need S0..S3, acst4.* and gt.* (hairfilter render frame|dataset).
"""
import argparse
import os
import subprocess
import sys
import tempfile

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import dataset  # noqa: E402


def read(path):
    """The frame's channels by name (dataset.read_exr)."""
    try:
        names, data = dataset.read_exr(path)
    except dataset.DatasetError as e:
        sys.exit(f"acst_bias.py: {e}")
    return {n: data[..., k] for k, n in enumerate(names)}


def gaussian(x, sigma):
    """x (2-D) blurred by a separable Gaussian of sigma pixels, zero outside."""
    r = int(3 * sigma)
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k = torch.tensor(k / k.sum(), dtype=torch.float32)
    t = torch.tensor(np.ascontiguousarray(x), dtype=torch.float32)[None, None]
    t = F.conv2d(F.pad(t, (r, r, 0, 0)), k.view(1, 1, 1, -1))
    t = F.conv2d(F.pad(t, (0, 0, r, r)), k.view(1, 1, -1, 1))
    return t[0, 0].numpy()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--weights", required=True, help="KernelAC weights (safetensors)")
    ap.add_argument("--hairfilter", default="build/hairfilter")
    ap.add_argument("--sigmas", default="2,4,8")
    ap.add_argument("frames", nargs="+")
    a = ap.parse_args()
    sigmas = [float(s) for s in a.sigmas.split(",")]
    print("| frame | dense pixels | truth c*a | acst | st4 | net | "
          + " | ".join(f"net +blur{s:g}" for s in sigmas) + " |")
    print("|---|---:|---:|---:|---:|---:|" + "---:|" * len(sigmas))
    with tempfile.TemporaryDirectory() as tmp:
        for p in a.frames:
            out = os.path.join(tmp, "out.exr")
            subprocess.run([a.hairfilter, "infer", "--weights", a.weights, "--in", p,
                            "--out", out], check=True, capture_output=True)
            f, o = read(p), read(out)
            ga = f["gt.alpha"]
            hair = ga > 0
            dense = hair & (ga >= 0.9)
            if not dense.any():
                continue
            truth = f["gt.color"] * ga
            st4 = sum(f[f"S{k}.color"] * (f[f"S{k}.alpha"] > 0) for k in range(4)) / 4
            acst = f["acst4.color"] * f["acst4.alpha"]
            net = o["color"] * o["alpha"]

            def err(x):
                e = (x - truth)[dense]
                return f"{e.mean():+.4f} / {np.sqrt(np.mean(e * e)):.4f}"

            h = hair.astype(np.float32)
            cols = [err(acst), err(st4), err(net)]
            for s in sigmas:
                d = gaussian((st4 - acst) * h, s) / np.maximum(gaussian(h, s), 1e-6)
                cols.append(err(net + d))
            name = os.path.join(os.path.basename(os.path.dirname(p)), os.path.basename(p))
            print(f"| {name} | {int(dense.sum())} | {truth[dense].mean():.3f} | "
                  + " | ".join(cols) + " |")


if __name__ == "__main__":
    main()
