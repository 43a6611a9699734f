#!/usr/bin/python3
"""Checks that a weights file gives in hairfilter what it gives in PyTorch,
on a frame of your own: weights/hfnet.py's network (the definition
train.py trains) and `hairfilter infer` with each backend asked for, on the
same feature EXR, compared channel by channel.

    /usr/bin/python3 weights/check_weights.py runs/mine.safetensors frame.exr \\
        --hairfilter build/hairfilter --backend cpu,cpu-ref

The frame is read as `hairfilter infer` reads it (the part holding
S0.color, its data window, the out-of-contract rule of protocol/FEATURES.md
applied to the samples and the estimate), the variant's spp samples and,
for a variant that reads it, the alpha-corrected estimate (acst4.*). Both
sides run in float32. For each backend and output (color, highlight,
alpha) it prints the largest absolute difference and the relative L2 error
||C - PyTorch|| / ||PyTorch||; the check passes when every relative error
is at most --tolerance (default 1e-4, the bound tests/core/test_golden.c
holds the backends to on PyTorch's outputs). Exit status 0 passed, 1 a
difference over the tolerance or a backend that failed, 2 bad arguments or
a file that cannot be read (named).
"""
import argparse
import os
import subprocess
import sys
import tempfile

import numpy as np
import torch

import dataset
import hfnet


def read_inputs(path, cfg):
    """The network's input [h][w][c] (float32) of the frame at path for a
    variant of config cfg, as `hairfilter infer` builds it."""
    names, data = dataset.read_exr(path)
    spp = cfg["spp"]
    have = dataset.count_spp(names)
    if have < spp:
        raise dataset.DatasetError(f"{path}: {have} samples per pixel, the variant "
                                   f"{cfg['name']} reads {spp}")
    feat = dataset.pick_channels(names, data, [f"S{k}.{f}" for k in range(spp)
                                               for f in dataset.FEATURES], path)
    h, w = data.shape[:2]
    feat = dataset.sanitise_samples(path, feat.reshape(h, w, spp, 6)).reshape(h, w, spp * 6)
    parts = [feat.astype(np.float32)]
    if cfg.get("estimate"):
        parts.append(dataset.load_estimate(path, np.float32))
    return np.concatenate(parts, axis=-1)


def relative_l2(c, ref):
    """||c - ref|| / ||ref||, or the absolute norm where ref is all zero."""
    num = float(np.linalg.norm((c - ref).ravel()))
    den = float(np.linalg.norm(ref.ravel()))
    return num / den if den > 0 else num


def refuse(msg):
    """Bad arguments: said, status 2 (as argparse's own refusals)."""
    print(f"check_weights.py: {msg}", file=sys.stderr)
    sys.exit(2)


def main(argv=None):
    ap = argparse.ArgumentParser(
        description="Compares hairfilter's output for a weights file with PyTorch's "
        "(weights/hfnet.py) on one feature EXR.")
    ap.add_argument("weights", help="a weights file (safetensors), e.g. train.py's --export")
    ap.add_argument("frame", help="a feature EXR (S0.color ...; acst4.* for a variant that "
                    "reads the estimate)")
    ap.add_argument("--hairfilter", default="build/hairfilter",
                    help="the hairfilter CLI (default build/hairfilter)")
    ap.add_argument("--backend", default="cpu,cpu-ref",
                    help="backends to check, comma-separated (default cpu,cpu-ref; cudnn "
                    "where the build has it and a GPU is there)")
    ap.add_argument("--tolerance", type=float, default=1e-4,
                    help="largest relative L2 error that passes (default 1e-4)")
    args = ap.parse_args(argv)
    backends = [b for b in args.backend.split(",") if b]
    if not backends or any(b not in ("cpu", "cpu-ref", "cudnn") for b in backends):
        refuse(f"--backend {args.backend!r}: give cpu, cpu-ref or cudnn, comma-separated")
    if not args.tolerance > 0:
        refuse(f"--tolerance {args.tolerance}: give a number above 0")
    if not (os.path.isfile(args.hairfilter) and os.access(args.hairfilter, os.X_OK)):
        refuse(f"--hairfilter {args.hairfilter}: not an executable file; give the CLI of your "
               "build (build/hairfilter)")
    try:
        net = hfnet.load_model(args.weights).eval()
        cfg = net.cfg
        x = read_inputs(args.frame, cfg)
    except (OSError, ValueError, dataset.DatasetError) as e:
        print(f"check_weights.py: {e}", file=sys.stderr)
        return 2
    torch.set_num_threads(os.cpu_count() or 1)
    with torch.no_grad():
        ref = hfnet.nchw_to_nhwc(net(hfnet.nhwc_to_nchw(x[None])))[0]
    h, w = x.shape[:2]
    print(f"{cfg['name']} ({args.weights}) on {args.frame} ({w}x{h}): hairfilter infer "
          f"against weights/hfnet.py in PyTorch {torch.__version__}, float32")
    print(f"  {'backend':8} {'output':10} {'max |diff|':>12} {'relative L2':>12}")
    failed = 0
    with tempfile.TemporaryDirectory(prefix="check_weights.") as tmp:
        for b in backends:
            out = os.path.join(tmp, f"{b}.exr")
            p = subprocess.run([args.hairfilter, "infer", "--weights", args.weights, "--in",
                                args.frame, "--out", out, "--backend", b],
                               capture_output=True, text=True)
            if p.returncode != 0:
                print(f"  {b:8} failed (exit status {p.returncode}): "
                      f"{p.stderr.strip().splitlines()[-1] if p.stderr.strip() else ''}")
                failed = 1
                continue
            names, data = dataset.read_exr(out)
            got = dataset.pick_channels(names, data, hfnet.OUTPUTS, out)
            if got.shape != ref.shape:
                print(f"  {b:8} output of {got.shape[1]}x{got.shape[0]}, PyTorch's "
                      f"{ref.shape[1]}x{ref.shape[0]}")
                failed = 1
                continue
            for k, name in enumerate(hfnet.OUTPUTS):
                diff = float(np.abs(got[..., k] - ref[..., k]).max())
                rel = relative_l2(got[..., k], ref[..., k])
                bad = not rel <= args.tolerance
                failed |= bad
                print(f"  {b:8} {name:10} {diff:12.3e} {rel:12.3e}"
                      f"{'  OVER ' + format(args.tolerance, 'g') if bad else ''}")
    print("check_weights.py: " + ("FAILED" if failed else
                                  f"passed: every output within {args.tolerance:g}"))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
