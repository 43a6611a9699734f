#!/usr/bin/python3
"""Writes the golden fixtures of tests/core: for each variant, random
weights, a random feature EXR and PyTorch's output EXR.

    /usr/bin/python3 weights/make_golden.py tests/data/golden

The C tests (tests/core/test_golden.c) check that every CPU backend
reproduces PyTorch's result within 1e-4 relative L2 error.
"""
import argparse
import os

import numpy as np
import OpenImageIO as oiio
import torch

import hfnet

CASES = [  # variant, width, height: odd sizes exercise pad-and-crop
    ("Base", 64, 48), ("Base", 37, 23),
    ("Shallow", 64, 48), ("Shallow", 29, 17),
    ("Deep", 64, 48), ("Deep", 45, 31),
    ("Base@1spp", 64, 48), ("Base@1spp", 19, 41),
    ("Residual", 64, 48), ("Residual", 27, 35),
    ("Kernel", 64, 48), ("Kernel", 37, 23),
    ("Kernel_r2h0", 64, 48), ("Kernel_r2h0", 37, 23),
    ("KernelAC", 64, 48), ("KernelAC", 37, 23),
    ("KernelMix", 64, 48), ("KernelMix", 37, 23),
]

# Configurations that are not presets: a name, the preset it varies, and
# what it changes. Kernel_r2h0: a 5x5 kernel given by dec0 directly (no head).
CONFIGS = {
    "Kernel_r2h0": ("Kernel", dict(kernel_radius=2, kernel_hidden=0,
                                   out_channels=hfnet.kernel_taps(2) + len(hfnet.OUTPUTS))),
}


def case_config(name):
    if name not in CONFIGS:
        return hfnet.variant_config(name)
    preset, changes = CONFIGS[name]
    cfg = hfnet.variant_config(preset)
    cfg.update(changes, name=name)
    return cfg


def write_exr(path, names, nhwc):
    h, w, c = nhwc.shape
    spec = oiio.ImageSpec(w, h, c, oiio.FLOAT)
    spec.channelnames = tuple(names)
    spec.attribute("compression", "zip")
    out = oiio.ImageOutput.create(path)
    if not out or not out.open(path, spec):
        raise RuntimeError(f"cannot write {path}: {oiio.geterror()}")
    out.write_image(np.ascontiguousarray(nhwc, dtype=np.float32))
    out.close()


def random_features(rng, h, w, spp, covered=0.7):
    """Plausible feature ranges (protocol/FEATURES.md), not just noise in
    [0, 1): about 30% of samples uncovered (all features 0), alpha in
    (0, 1], tangents in [-1, 1]."""
    f = np.zeros((h, w, spp, 6), np.float32)
    f[..., 0] = rng.uniform(0, 2, (h, w, spp))
    f[..., 1] = rng.exponential(0.2, (h, w, spp))
    f[..., 2] = rng.uniform(0.01, 1, (h, w, spp))
    f[..., 3] = rng.uniform(0, 1, (h, w, spp))
    f[..., 4:6] = rng.uniform(-1, 1, (h, w, spp, 2))
    f *= (rng.uniform(size=(h, w, spp, 1)) < covered)
    return f.reshape(h, w, spp * 6)


def kernel_features(rng, h, w, spp):
    """random_features with hair-free regions the kernel architecture has to
    handle: a band along the left edge wider than any kernel (pixels whose
    every tap is empty: colour 1, highlight 0 before the corrections), an
    empty block inside the frame, and a fully covered one."""
    f = random_features(rng, h, w, spp).reshape(h, w, spp, 6)
    f[:, :5] = 0
    f[h // 3:h // 3 + 9, w // 2:w // 2 + 9] = 0
    y, x = 2 * h // 3, w // 4
    f[y:y + 4, x:x + 4] = random_features(rng, 4, 4, spp, covered=1.1).reshape(4, 4, spp, 6)
    return f.reshape(h, w, spp * 6)


def estimate_features(rng, feat, spp):
    """An alpha-corrected estimate [h][w][3] (colour, highlight, alpha) for
    features feat: zero where the pixel has no covered sample and in a
    tenth of the others (the estimate may see no hair where a sample did),
    else alpha in (0, 1] and the colours' ranges."""
    h, w = feat.shape[:2]
    hair = (feat.reshape(h, w, spp, 6)[..., 2] > 0).any(-1) & (rng.uniform(size=(h, w)) < 0.9)
    e = np.stack([rng.uniform(0, 2, (h, w)), rng.exponential(0.2, (h, w)),
                  rng.uniform(0.005, 1, (h, w))], -1).astype(np.float32)
    return e * hair[..., None]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--seed", type=int, default=2022)
    args = ap.parse_args()
    torch.set_num_threads(os.cpu_count() or 1)
    os.makedirs(args.out, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    nets = {}
    for k, (variant, w, h) in enumerate(CASES):
        cfg = case_config(variant)
        vstem = variant.replace("@", "_")
        if variant not in nets:
            # One weights file per variant, stored as F16 to keep the
            # fixtures small (and to test the F16 path of the loader);
            # PyTorch runs on the same F16-rounded values in float32.
            torch.manual_seed(args.seed + k)
            net = hfnet.HairNet(cfg).eval()
            with torch.no_grad():
                for p in net.parameters():
                    p.copy_(p.half().float())
            hfnet.save_safetensors(os.path.join(args.out, vstem + ".safetensors"), cfg,
                                   net.state_dict(), dtype="F16")
            nets[variant] = net
        net = nets[variant]
        stem = f"{vstem}_{w}x{h}"
        spp = cfg["spp"]
        feat = (kernel_features if cfg["arch"] == "kernel" else random_features)(rng, h, w, spp)
        names = [f"S{s}.{n}" for s in range(spp) for n in hfnet.FEATURES]
        if cfg.get("estimate"):
            feat = np.concatenate([feat, estimate_features(rng, feat, spp)], 2)
            names += hfnet.ESTIMATE_CHANNELS
        write_exr(os.path.join(args.out, stem + ".features.exr"), names, feat)
        with torch.no_grad():
            y = net(hfnet.nhwc_to_nchw(feat[None]))
        write_exr(os.path.join(args.out, stem + ".expected.exr"), hfnet.OUTPUTS,
                  hfnet.nchw_to_nhwc(y)[0])
        print(f"{stem}: {sum(p.numel() for p in net.parameters())} parameters")


if __name__ == "__main__":
    main()
