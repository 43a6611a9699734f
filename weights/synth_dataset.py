#!/usr/bin/python3
"""A small synthetic hair dataset in the format of `hairfilter render
dataset` (weights/dataset.py describes it), so that the training recipe and
its tests do not depend on the OpenGL renderer.

    /usr/bin/python3 weights/synth_dataset.py --out DIR --styles straight,wavy \
        --count 12 --size 128x128 --spp 4 --seed 1

Hair is a set of 2D strands (polylines in pixel units) with a depth, a strand
width below a pixel and an opacity. The world is the same as the renderer's:

  features   strands drawn 1 pixel wide into spp MSAA samples (the 4x D3D
             pattern); each sample's coverage bit survives with probability
             alpha = opacity * width, and the sample keeps the nearest
             surviving fragment's color, highlight, alpha, depth, tangent.
  gt.*       a 4x4-supersampled A-buffer: every fragment of every subsample,
             sorted by depth and blended exactly, then averaged per pixel
             (color and highlight un-premultiplied).
  st{N}.*    stochastic transparency averaged over N samples: alpha is the
             covered fraction, color/highlight the mean over covered samples.
  opaque.*   16x MSAA without transparency (every sample covered).
  acst4.*    stochastic transparency's alpha-corrected estimate over the
             first 4 samples (with spp >= 4): per sample, every fragment's
             colour and highlight weighted by alpha times its visibility
             (1 where the sample's kept depth is at or behind it, or nothing
             was kept), alpha 1 - prod(1 - alpha); the samples averaged
             premultiplied (protocol/FEATURES.md, "The alpha-corrected
             estimate").

Shading is the paper's Fig. 3 with a 3D tangent (screen tangent plus a
per-strand z) and one directional light per frame, plus an ambient term and
a depth-dependent self-shadowing factor on the color.
"""
import argparse
import json
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import dataset  # noqa: E402

STYLES = ("straight", "wavy", "curly", "coily")
MSAA = {  # sample offsets from the pixel centre, in pixels
    1: [(0.0, 0.0)],
    2: [(0.25, 0.25), (-0.25, -0.25)],
    4: [(-0.125, -0.375), (0.375, -0.125), (-0.375, 0.125), (0.125, 0.375)],
}
GT_SS = 4
AMBIENT = 0.1


def sample_offsets(n, rng):
    """MSAA pattern for n in 1, 2, 4, else stratified jittered positions."""
    if n in MSAA:
        return MSAA[n]
    g = int(math.ceil(math.sqrt(n)))
    cells = rng.permutation(g * g)[:n]
    return [((c % g + rng.random()) / g - 0.5, (c // g + rng.random()) / g - 0.5) for c in cells]


# ---- geometry ----------------------------------------------------------------

def make_strands(style, w, h, rng):
    """List of dicts: pts [n][2] (x right, y down, pixels), depth [n],
    tz (tangent z), width (pixels), opacity."""
    strands = []
    spin = rng.uniform(-0.5, 0.5)                     # overall flow direction
    n_clumps = int(rng.integers(12, 30))
    for _ in range(n_clumps):
        per = int(rng.integers(10, 30))
        if style == "coily":
            cx, cy = w * rng.uniform(0.3, 0.7), h * rng.uniform(0.3, 0.7)
            ang = rng.uniform(0, 2 * math.pi)
            root = np.array([cx, cy]) + rng.uniform(0, 0.15 * min(w, h)) * np.array(
                [math.cos(ang), math.sin(ang)])
            theta = ang + rng.uniform(-0.4, 0.4)
            length = rng.uniform(0.2, 0.45) * h
            radius, period = rng.uniform(1.5, 3.5), rng.uniform(4, 9)
        else:
            root = np.array([rng.uniform(-0.1, 1.1) * w, rng.uniform(-0.1, 0.3) * h])
            theta = math.pi / 2 + spin + rng.uniform(-0.25, 0.25)
            length = rng.uniform(0.5, 1.2) * h
            if style == "straight":
                radius, period = 0.0, 1.0
            elif style == "wavy":
                radius, period = rng.uniform(1.5, 5), rng.uniform(18, 40)
            else:  # curly: loops, the radius large against the pitch
                radius, period = rng.uniform(3, 7), rng.uniform(10, 22)
        bend = rng.uniform(-1, 1) * 0.3 / max(length, 1)
        phase = rng.uniform(0, 2 * math.pi)
        depth0 = rng.uniform(0.1, 0.9)
        for _ in range(per):
            r0 = root + rng.normal(0, 2.5 if style != "coily" else 1.5, 2)
            th = theta + rng.normal(0, 0.04)
            ln = length * rng.uniform(0.8, 1.1)
            t = np.arange(0, ln, 0.2)
            d = np.array([math.cos(th), math.sin(th)])
            p = np.array([-d[1], d[0]])
            base = r0[None] + t[:, None] * d[None] + (bend * t ** 2)[:, None] * p[None]
            ph = phase + rng.normal(0, 0.3)
            if style == "wavy":
                off = radius * np.sin(2 * math.pi * t / period + ph)[:, None] * p[None]
            elif style in ("curly", "coily"):
                a = 2 * math.pi * t / period + ph
                off = radius * (np.cos(a) - math.cos(ph))[:, None] * p[None] + \
                    radius * (np.sin(a) - math.sin(ph))[:, None] * d[None]
            else:
                off = 0
            pts = base + off + np.cumsum(rng.normal(0, 0.01, (len(t), 2)), axis=0)
            dep = np.clip(depth0 + rng.normal(0, 0.05) + 0.1 * t / max(ln, 1), 0.02, 0.98)
            strands.append(dict(pts=pts, depth=dep, tz=rng.uniform(-0.6, 0.6),
                                width=rng.uniform(0.08, 0.25), opacity=rng.uniform(0.5, 0.95)))
    return strands


def shade(strands, light, alpha_r):
    """Per-point color factor, highlight, view tangent (x, y) of every
    strand (Fig. 3 of the paper), appended to the dicts."""
    alpha_trt = -1.5 * alpha_r
    for s in strands:
        d = np.gradient(s["pts"], axis=0)
        t3 = np.stack([d[:, 0], -d[:, 1], np.full(len(d), s["tz"]) * np.hypot(d[:, 0], d[:, 1])], 1)
        t3 /= np.linalg.norm(t3, axis=1, keepdims=True) + 1e-12
        cos = np.clip(t3 @ light, -1, 1)
        a = np.arccos(cos)
        fd = np.sin(a)
        fr = np.clip(np.sin(a + alpha_r), 0, 1) ** 250
        ftrt = np.clip(np.sin(a + alpha_trt), 0, 1) ** 80
        shadow = 1.0 - 0.6 * s["depth"]                 # deeper strands are darker
        s["color"] = (fd + ftrt) * shadow + AMBIENT
        s["highlight"] = fr * shadow
        s["tx"], s["ty"] = t3[:, 0], t3[:, 1]


def fragments(strands, w, h, scale, offset):
    """Rasterises every strand at a lattice of w*scale x h*scale samples,
    each at its cell's centre plus offset (in cells). One fragment per strand
    and sample: (flat sample index, strand id, point id)."""
    W, H = w * scale, h * scale
    idx_all, sid_all, pid_all = [], [], []
    for i, s in enumerate(strands):
        q = s["pts"] * scale - 0.5 - np.array(offset)
        j = np.rint(q).astype(np.int64)
        ok = (j[:, 0] >= 0) & (j[:, 0] < W) & (j[:, 1] >= 0) & (j[:, 1] < H)
        flat = j[ok, 1] * W + j[ok, 0]
        u, first = np.unique(flat, return_index=True)
        idx_all.append(u)
        sid_all.append(np.full(len(u), i))
        pid_all.append(np.nonzero(ok)[0][first])
    if not idx_all:
        return (np.zeros(0, np.int64),) * 3
    return np.concatenate(idx_all), np.concatenate(sid_all), np.concatenate(pid_all)


def attr(strands, key, sid, pid):
    out = np.empty(len(sid), np.float32)
    for i in np.unique(sid):
        m = sid == i
        v = strands[i][key]
        out[m] = v[pid[m]] if isinstance(v, np.ndarray) else v
    return out


def nearest_surviving(strands, w, h, offset, rng, opaque=False):
    """One MSAA sample plane: per pixel the nearest fragment whose coverage
    bit survived; returns [h*w][6] features (zeros where none)."""
    idx, sid, pid = fragments(strands, w, h, 1, offset)
    alpha = attr(strands, "opacity", sid, pid) * np.minimum(1, attr(strands, "width", sid, pid))
    keep = np.ones(len(idx), bool) if opaque else rng.random(len(idx)) < alpha
    idx, sid, pid, alpha = idx[keep], sid[keep], pid[keep], alpha[keep]
    depth = attr(strands, "depth", sid, pid)
    order = np.lexsort((depth, idx))                   # by pixel, then depth
    idx, sid, pid, alpha, depth = idx[order], sid[order], pid[order], alpha[order], depth[order]
    first = np.ones(len(idx), bool)
    first[1:] = idx[1:] != idx[:-1]
    f = np.zeros((h * w, 6), np.float32)
    s_, p_ = sid[first], pid[first]
    f[idx[first]] = np.stack([attr(strands, "color", s_, p_), attr(strands, "highlight", s_, p_),
                              alpha[first], depth[first], attr(strands, "tx", s_, p_),
                              attr(strands, "ty", s_, p_)], 1)
    return f


def ground_truth(strands, w, h):
    """[h][w][3] color, highlight, alpha from the exactly blended
    supersampled A-buffer."""
    idx, sid, pid = fragments(strands, w, h, GT_SS, (0.0, 0.0))
    a = np.minimum(0.999, attr(strands, "opacity", sid, pid) *
                   np.minimum(1, attr(strands, "width", sid, pid) * GT_SS))
    depth = attr(strands, "depth", sid, pid)
    order = np.lexsort((depth, idx))
    idx, sid, pid, a = idx[order], sid[order], pid[order], a[order]
    la = np.log1p(-a).astype(np.float64)
    cum = np.cumsum(la)
    start = np.ones(len(idx), bool)
    start[1:] = idx[1:] != idx[:-1]
    grp = np.cumsum(start) - 1
    base = (cum - la)[start]                           # sum before each group
    trans = np.exp(cum - la - base[grp])              # transmittance in front
    wgt = trans * a
    n = w * GT_SS * h * GT_SS
    A = np.bincount(idx, wgt, n)
    C = np.bincount(idx, wgt * attr(strands, "color", sid, pid), n)
    Hl = np.bincount(idx, wgt * attr(strands, "highlight", sid, pid), n)

    def down(x):
        return x.reshape(h, GT_SS, w, GT_SS).mean(axis=(1, 3))
    A, C, Hl = down(A), down(C), down(Hl)
    safe = np.where(A > 0, A, 1)
    return np.stack([np.where(A > 0, C / safe, 0), np.where(A > 0, Hl / safe, 0), A], -1)


def alpha_corrected(strands, w, h, offsets, planes):
    """[h][w][3] colour, highlight, alpha of the alpha-corrected estimate
    over the samples at offsets whose kept fragments are planes ([h*w][6]
    each)."""
    pre = np.zeros((h * w, 3))
    for off, f in zip(offsets, planes):
        idx, sid, pid = fragments(strands, w, h, 1, off)
        alpha = attr(strands, "opacity", sid, pid) * np.minimum(1, attr(strands, "width", sid, pid))
        depth = attr(strands, "depth", sid, pid)
        kept = f[idx, 3]
        vis = ((f[idx, 2] <= 0) | (kept >= depth)).astype(np.float64)
        wgt = alpha * vis
        W = np.bincount(idx, wgt, h * w)
        C = np.bincount(idx, wgt * attr(strands, "color", sid, pid), h * w)
        Hl = np.bincount(idx, wgt * attr(strands, "highlight", sid, pid), h * w)
        A = 1 - np.exp(np.bincount(idx, np.log1p(-np.minimum(alpha, 0.999)), h * w))
        safe = np.where(W > 0, W, 1)
        pre += np.stack([A * C / safe, A * Hl / safe, A], -1)
    pre /= len(offsets)
    a = pre[:, 2]
    safe = np.where(a > 0, a, 1)
    return np.stack([np.where(a > 0, pre[:, 0] / safe, 0), np.where(a > 0, pre[:, 1] / safe, 0),
                     a], -1).reshape(h, w, 3)


def baseline(strands, w, h, n, rng, opaque=False):
    """Average of n stochastic (or opaque) samples as color/highlight/alpha."""
    cov = np.zeros(h * w)
    col = np.zeros(h * w)
    hl = np.zeros(h * w)
    for off in sample_offsets(n, rng):
        f = nearest_surviving(strands, w, h, off, rng, opaque)
        hit = f[:, 2] > 0
        cov += hit
        col += f[:, 0] * hit
        hl += f[:, 1] * hit
    safe = np.where(cov > 0, cov, 1)
    return np.stack([np.where(cov > 0, col / safe, 0), np.where(cov > 0, hl / safe, 0),
                     cov / n], -1).reshape(h, w, 3)


def render_frame(style, w, h, spp, st_list, seed):
    rng = np.random.default_rng(seed)
    strands = make_strands(style, w, h, rng)
    el, az = rng.uniform(-0.6, 0.9), rng.uniform(0, 2 * math.pi)
    light = np.array([math.cos(el) * math.cos(az), math.sin(el), math.cos(el) * math.sin(az)])
    shade(strands, light, math.radians(rng.uniform(-10, -5)))
    names, planes = [], []
    offsets = sample_offsets(spp, rng)
    for k, off in enumerate(offsets):
        planes.append(nearest_surviving(strands, w, h, off, rng).reshape(h, w, 6))
        names += [f"S{k}.{f}" for f in dataset.FEATURES]
    if spp >= 4:
        planes.append(alpha_corrected(strands, w, h, offsets[:4],
                                      [p.reshape(h * w, 6) for p in planes[:4]]))
        names += [f"acst4.{t}" for t in dataset.TARGETS]
    planes.append(ground_truth(strands, w, h))
    names += [f"gt.{t}" for t in dataset.TARGETS]
    for n in st_list:
        planes.append(baseline(strands, w, h, n, rng))
        names += [f"st{n}.{t}" for t in dataset.TARGETS]
    planes.append(baseline(strands, w, h, 16, rng, opaque=True))
    names += [f"opaque.{t}" for t in dataset.TARGETS]
    return names, np.concatenate(planes, -1).astype(np.float32)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--styles", default="straight,wavy")
    ap.add_argument("--count", type=int, default=8, help="frames per style")
    ap.add_argument("--size", default="128x128")
    ap.add_argument("--spp", type=int, default=4, choices=[1, 2, 4])
    ap.add_argument("--st", default="1,2,4,8,16,64", help="stochastic baselines")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.lower().split("x"))
    st_list = [int(v) for v in args.st.split(",") if v]
    styles = dataset.parse_styles(args.styles)
    for s in styles:
        if s not in STYLES:
            ap.error(f"unknown style {s!r}; known: {', '.join(STYLES)}")
    os.makedirs(args.out, exist_ok=True)
    frames = []
    for si, style in enumerate(styles):
        for i in range(args.count):
            seed = args.seed * 1000003 + si * 10007 + i
            fname = f"{style}_{i:04d}.exr"
            names, img = render_frame(style, w, h, args.spp, st_list, seed)
            dataset.write_exr(os.path.join(args.out, fname), names, img)
            frames.append(dict(file=fname, style=style, spp=args.spp, width=w, height=h,
                               seed=seed))
            print(f"\r{len(frames)}/{len(styles) * args.count} {fname}", end="",
                  file=sys.stderr, flush=True)
    print(file=sys.stderr)
    with open(os.path.join(args.out, "manifest.json"), "w") as f:
        json.dump(dict(format="hairfilter-dataset", version=1, generator="synth_dataset.py",
                       spp=args.spp, st=st_list, frames=frames), f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
