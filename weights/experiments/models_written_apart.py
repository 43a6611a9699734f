#!/usr/bin/python3
"""Five hair models in Cem Yuksel's .hair format, built from the format
alone (none of the renderer's styles, nor client/render/tools/hair_models.py),
in conventions no training frame used, for docs/QUALITY.md's "Three
models written apart" (A, B, C) and two more unlike them (D, E):

A  wavy_zup_cm.hair    : z up, centimetres, origin offset (152, -87, 104) cm,
                         SEGMENTS|POINTS only, header thickness 0.0075 cm,
                         30000 strands of 16..60 points, wavy/curly, mid length.
B  long_yup_m.hair     : y up, metres, SEGMENTS|POINTS|THICKNESS|COLORS,
                         per-point width 90 um -> 22 um at the tip, long straight
                         hanging hair (35-55 cm) in clumps, 40..90 points.
C  buzz_yup_mm.hair    : y up, millimetres, POINTS|THICKNESS|TRANSPARENCY,
                         header default segments 5 (no segment array),
                         90000 short strands (6-14 mm), widths 70 -> 25 um,
                         transparency 0.0..0.3 per point.
D  coily_xup_in.hair   : x up (the head's up is +x), inches,
                         SEGMENTS|POINTS|THICKNESS|COLORS, per-point width
                         160-200 um -> 75-85% of it at the tip (thick: about
                         0.1 px in a 256 px frame of the whole head, 0.09-0.14
                         p10-p90 at --random-view 101), colours dark
                         brown to near black per strand; 12000 tight coils
                         (radius 3-6 mm, period 6-12 mm, 8-20 cm of arc) around
                         paths grown out to a round afro volume, 40..120 points
                         (about 14 a turn, so the coil survives resampling).
E  spiky_zup_dm.hair   : z up with the face towards -y (as A, which --up z
                         turns to the renderer's +z front), decimetres, origin
                         at the head's centre, SEGMENTS|POINTS|THICKNESS|
                         TRANSPARENCY, header default colour (light brown, no
                         colour array), per-point width 110-150 um -> 20-40%
                         of it at the tip (0.1 px at the root in a 256 px
                         frame of the whole head; 0.034/0.069/0.097 px
                         p10/p50/p90 at --random-view 101), transparency
                         0 at the root -> 0.2-0.5 at the tip; 25000 strands
                         of 8..24 points in
                         320 clumps, a gelled spiky short cut: pointed spikes
                         of 4-9 cm standing up and back on top (a fifth of
                         them splayed), 2-4 cm combed flat at the sides and
                         back, a 4-7 cm fringe forward and down; each strand
                         runs to its clump's tip, cut at 60-100% of the way.
Internally everything is built y up, metres, face towards +z; roots over an
ellipsoid scalp above a hairline, strands grown along the normal, bent by
gravity and kept outside the head (E's are not grown: each is a curve from
its root to its clump's tip, no gravity, gel holds it).

Usage: models_written_apart.py [--seed N] [a] [b] [c] [d] [e]   (default a,
b and c, the evaluation's three; d and e by name; written to the current directory;
each model from its own seed, the same files every run; --seed N draws other
models of the same kinds, for training: the evaluation's are those without it)
"""
import struct
import sys
import numpy as np

SEGMENTS, POINTS, THICKNESS, TRANSPARENCY, COLORS = 1, 2, 4, 8, 16
HEAD = np.array([0.078, 0.100, 0.098])  # ellipsoid semi-axes x, y, z (m)


def write_hair(path, segs, pts, flags, d_seg=0, d_thick=1.0, d_transp=0.0,
               d_color=(1.0, 1.0, 1.0), thick=None, transp=None, color=None, info=""):
    n_strands = len(segs)
    n_points = int(np.sum(np.asarray(segs, np.int64) + 1))
    assert pts.shape == (n_points, 3), (pts.shape, n_points)
    hdr = b"HAIR" + struct.pack("<IIII", n_strands, n_points, flags, d_seg)
    hdr += struct.pack("<fffff", d_thick, d_transp, *d_color)
    hdr += info.encode()[:87].ljust(88, b"\0")
    assert len(hdr) == 128
    with open(path, "wb") as f:
        f.write(hdr)
        if flags & SEGMENTS:
            f.write(np.asarray(segs, "<u2").tobytes())
        f.write(np.asarray(pts, "<f4").tobytes())
        if flags & THICKNESS:
            f.write(np.asarray(thick, "<f4").tobytes())
        if flags & TRANSPARENCY:
            f.write(np.asarray(transp, "<f4").tobytes())
        if flags & COLORS:
            f.write(np.asarray(color, "<f4").tobytes())
    print(f"{path}: {n_strands} strands, {n_points} points, flags {flags}, "
          f"bbox {pts.min(0).round(4)} .. {pts.max(0).round(4)}")


def sample_scalp(rng, n, front_line=0.42, back_line=0.05):
    """Roots uniform-ish over the ellipsoid above a hairline (higher at the face)."""
    out = np.zeros((0, 3))
    while len(out) < n:
        v = rng.normal(size=(4 * n, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        p = v * HEAD
        # area weighting of the ellipsoid (approximately): accept by the local scale
        nrm = p / HEAD**2
        w = np.linalg.norm(nrm * HEAD.prod(), axis=1)
        keep = rng.random(len(p)) < w / w.max()
        p = p[keep]
        az = np.arctan2(p[:, 0], p[:, 2])            # 0 = face (+z)
        face = np.clip(np.cos(az), 0, 1) ** 2         # 1 at the face, 0 at the sides/back
        line = back_line + (front_line - back_line) * face
        p = p[p[:, 1] / HEAD[1] > line]
        out = np.vstack([out, p])
    return out[:n]


def normals(p):
    nn = p / HEAD**2
    return nn / np.linalg.norm(nn, axis=1, keepdims=True)


def grow(rng, roots, lengths, steps, gravity, stiff, layer, comb):
    """Strands as `steps` segments: start along the normal tilted by `comb`,
    bend under gravity, kept outside the head grown by a per-strand layer."""
    n = len(roots)
    nrm = normals(roots)
    d = nrm + comb
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    path = np.zeros((n, steps + 1, 3))
    path[:, 0] = roots
    step = (lengths / steps)[:, None]
    p = roots.copy()
    g = np.array([0.0, -1.0, 0.0])
    for k in range(steps):
        t = k / steps
        d = d + gravity * (1 - stiff * (1 - t)) * g * (1.0 / steps) * 6
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        p = p + d * step
        # collision with the head grown by the strand's layer offset
        grown = HEAD * (1 + layer)[:, None]
        r = np.linalg.norm(p / grown, axis=1)
        inside = r < 1
        if inside.any():
            p[inside] /= r[inside, None]
            # slide the direction along the surface
            nn = normals(p[inside] / (1 + layer[inside, None]))
            dn = np.sum(d[inside] * nn, axis=1, keepdims=True)
            d[inside] = d[inside] - np.minimum(dn, 0) * nn
            d[inside] /= np.linalg.norm(d[inside], axis=1, keepdims=True)
        path[:, k + 1] = p
    return path


def frames_along(path):
    tan = np.gradient(path, axis=1)
    tan /= np.linalg.norm(tan, axis=2, keepdims=True) + 1e-12
    ref = np.broadcast_to(np.array([0.0, 0.0, 1.0]), tan.shape).copy()
    ref[np.abs(tan[..., 2]) > 0.9] = [1.0, 0.0, 0.0]
    b1 = np.cross(tan, ref)
    b1 /= np.linalg.norm(b1, axis=2, keepdims=True)
    b2 = np.cross(tan, b1)
    return tan, b1, b2


def resample(path, npts):
    """Each strand's fixed-resolution path resampled at npts[i] points (list)."""
    steps = path.shape[1] - 1
    out = []
    for i in range(len(path)):
        t = np.linspace(0, steps, npts[i])
        j = np.minimum(np.floor(t).astype(int), steps - 1)
        f = (t - j)[:, None]
        out.append(path[i, j] * (1 - f) + path[i, j + 1] * f)
    return out


def model_a(rng):
    n, steps = 30000, 64
    roots = sample_scalp(rng, n)
    az = np.arctan2(roots[:, 0], roots[:, 2])
    face = np.clip(np.cos(az), 0, 1)
    lengths = rng.uniform(0.10, 0.30, n) * (1 - 0.45 * face)   # shorter at the face
    comb = np.stack([np.sign(roots[:, 0]) * 0.4, np.full(n, 0.2), np.full(n, -0.3)], 1)
    layer = rng.uniform(0.02, 0.20, n)
    path = grow(rng, roots, lengths, steps, gravity=0.9, stiff=0.6, layer=layer, comb=comb)
    # waves/curls: a helix growing in radius from the root, per strand period & phase
    tan, b1, b2 = frames_along(path)
    s = np.linspace(0, 1, steps + 1)[None, :] * lengths[:, None]   # arc length
    period = rng.uniform(0.022, 0.04, n)[:, None]
    radius = rng.uniform(0.003, 0.008, n)[:, None] * np.clip(s / 0.03, 0, 1)
    ph = 2 * np.pi * s / period + rng.uniform(0, 2 * np.pi, n)[:, None]
    ell = rng.uniform(0.4, 1.0, n)[:, None]           # flattened helix = wave
    path = path + radius[..., None] * (np.cos(ph)[..., None] * b1 + ell[..., None] * np.sin(ph)[..., None] * b2)
    # frizz
    fr = np.cumsum(rng.normal(0, 0.0004, path.shape), axis=1)
    fr[:, 0] = 0
    path += fr * np.linspace(0, 1, steps + 1)[None, :, None]
    npts = np.clip(np.round(16 + 44 * (lengths - lengths.min()) / np.ptp(lengths)
                            + rng.integers(-3, 4, n)), 16, 60).astype(int)
    strands = resample(path, npts)
    pts = np.concatenate(strands)                    # y up, metres
    # z up, centimetres, offset origin: y-up (X,Y,Z) -> z-up (X, -Z, Y)
    pz = np.stack([pts[:, 0], -pts[:, 2], pts[:, 1]], 1) * 100.0 + np.array([152.0, -87.0, 104.0])
    write_hair("wavy_zup_cm.hair", npts - 1, pz, SEGMENTS | POINTS,
               d_seg=0, d_thick=0.0075, d_transp=0.0, d_color=(0.3, 0.18, 0.1),
               info="wavy, z up, cm, origin offset; header thickness only")


def model_b(rng):
    n, steps, ng = 24000, 96, 300
    roots = sample_scalp(rng, n, front_line=0.38, back_line=-0.05)
    lengths = rng.uniform(0.35, 0.55, n)
    # side parting: comb away from x = 0.01
    side = np.sign(roots[:, 0] - 0.01)
    comb = np.stack([side * 0.6, np.full(n, 0.1), np.full(n, -0.5)], 1)
    layer = rng.uniform(0.01, 0.12, n)
    path = grow(rng, roots, lengths, steps, gravity=1.6, stiff=0.3, layer=layer, comb=comb)
    # clumps: pull each strand towards the nearest clump guide (by root), more at the tip
    gidx = rng.choice(n, ng, replace=False)
    d2 = ((roots[:, None, :] - roots[None, gidx, :]) ** 2).sum(-1)
    near = gidx[np.argmin(d2, axis=1)]
    t = np.linspace(0, 1, steps + 1)[None, :, None]
    c = rng.uniform(0.4, 0.8, n)[:, None, None]
    w = c * t ** 0.8
    # guide's shape offset to this strand's root, then blended
    gpath = path[near] - path[near][:, :1] + path[:, :1]
    path = path * (1 - w) + (gpath * (1 - 0.6) + path[near] * 0.6) * w
    # slight straight-hair noise
    fr = np.cumsum(rng.normal(0, 0.00025, path.shape), axis=1)
    fr[:, 0] = 0
    path += fr * t
    npts = np.clip(np.round(40 + 50 * (lengths - 0.35) / 0.2 + rng.integers(-4, 5, n)), 40, 90).astype(int)
    strands = resample(path, npts)
    pts = np.concatenate(strands)
    thick = np.concatenate([90e-6 + (22e-6 - 90e-6) * np.linspace(0, 1, k) ** 1.5 for k in npts])
    base = np.array([0.55, 0.38, 0.2])
    col = np.concatenate([np.tile(base * rng.uniform(0.8, 1.1), (k, 1)) for k in npts])
    write_hair("long_yup_m.hair", npts - 1, pts, SEGMENTS | POINTS | THICKNESS | COLORS,
               d_seg=0, d_thick=1.0, d_transp=0.0, d_color=(1, 1, 1),
               thick=thick, color=col, info="long straight clumped, y up, metres")


def model_c(rng):
    n, seg = 90000, 5
    roots = sample_scalp(rng, n, front_line=0.40, back_line=-0.1)
    lengths = rng.uniform(0.006, 0.014, n)
    comb = np.stack([np.zeros(n), np.zeros(n), np.full(n, -0.35)], 1) + rng.normal(0, 0.15, (n, 3))
    layer = np.zeros(n)
    path = grow(rng, roots, lengths, seg, gravity=0.15, stiff=0.9, layer=layer, comb=comb)
    pts = path.reshape(-1, 3) * 1000.0               # mm, y up
    tt = np.linspace(0, 1, seg + 1)
    thick = np.tile(70e-3 + (25e-3 - 70e-3) * tt, n)
    transp = np.tile(0.3 * tt, n)
    write_hair("buzz_yup_mm.hair", np.full(n, seg), pts, POINTS | THICKNESS | TRANSPARENCY,
               d_seg=seg, d_thick=1.0, d_transp=0.0, d_color=(1, 1, 1),
               thick=thick, transp=transp, info="buzz cut, y up, mm, default segments")


def transport_frames(path):
    """Rotation-minimising frames along each path (parallel transport): a coil
    wound in frames_along's would jump where its reference axis is swapped,
    and a tight helix shows that kink at once."""
    tan = np.gradient(path, axis=1)
    tan /= np.linalg.norm(tan, axis=2, keepdims=True) + 1e-12
    t0 = tan[:, 0]
    ref = np.eye(3)[np.argmin(np.abs(t0), axis=1)]  # the axis least along t0
    b1 = np.zeros_like(tan)
    b = np.cross(t0, ref)
    for k in range(path.shape[1]):
        b = b - np.sum(b * tan[:, k], axis=1, keepdims=True) * tan[:, k]
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        b1[:, k] = b
    return tan, b1, np.cross(tan, b1)


def model_d(rng):
    n, steps, nmax = 12000, 48, 120
    roots = sample_scalp(rng, n, front_line=0.40, back_line=-0.3)   # down to the nape
    nrm = normals(roots)
    # A round volume: each path reaches out along its normal to a sphere-like
    # envelope around the head (raised, set back from the face), +-12%.
    centre, env = np.array([0.0, 0.03, -0.012]), np.array([0.135, 0.135, 0.14])
    q, v = (roots - centre) / env, nrm / env
    a, b, c = np.sum(v * v, 1), 2 * np.sum(q * v, 1), np.sum(q * q, 1) - 1
    reach = (-b + np.sqrt(b * b - 4 * a * c)) / (2 * a) * rng.uniform(0.88, 1.12, n)
    reach = np.clip(reach, 0.083 / 6.2, 0.195 / 1.9)  # so that an arc below fits
    # Then coils that fit it: a helix of radius r and period P spends
    # sqrt(P^2 + (2 pi r)^2) of hair per turn, 1.9-6.2 times P in these
    # ranges, so an arc of 8-20 cm is drawn from what that allows over the
    # reach, and the coil's shape (2 pi r / P) follows; had the arc been drawn
    # first and clipped, a clipped strand would stop short of the envelope and
    # the volume would be the clip's, not round. (Drawn in 8.3-19.5 cm: the
    # coil's opening at the root and its breathing move it a few percent.)
    arc = rng.uniform(np.maximum(0.083, 1.9 * reach), np.minimum(0.195, 6.2 * reach))
    slope = np.sqrt((arc / reach) ** 2 - 1)           # 2 pi r / P
    period = rng.uniform(np.maximum(0.006, 2 * np.pi * 0.003 / slope),
                         np.minimum(0.012, 2 * np.pi * 0.006 / slope))
    radius = slope * period / (2 * np.pi)
    lengths = reach                                   # the path's length
    # Springy: little gravity, a stiff start, a little scatter in direction.
    comb = rng.normal(0, 0.2, (n, 3)) + np.array([0.0, 0.15, -0.1])
    layer = rng.uniform(0.0, 0.04, n)
    path = grow(rng, roots, lengths, steps, gravity=0.25, stiff=0.8, layer=layer, comb=comb)
    # A slow wander, then every step put back to its length: the arc length is
    # what the coil is wound by, and a wander (or a slide over the scalp in
    # grow) that stretched the path would stretch the strand with it.
    wander = np.cumsum(np.cumsum(rng.normal(0, 2e-5, path.shape), axis=1), axis=1)
    dp = np.diff(path + wander, axis=1)
    dp *= (lengths / steps)[:, None, None] / np.linalg.norm(dp, axis=2, keepdims=True)
    path = np.concatenate([roots[:, None], roots[:, None] + np.cumsum(dp, axis=1)], 1)
    tan, b1, b2 = transport_frames(path)
    # Arc length of the path, for the coil phase.
    sp = np.concatenate([np.zeros((n, 1)), np.cumsum(
        np.linalg.norm(np.diff(path, axis=1), axis=2), axis=1)], 1)
    # Points by turns, about 14 a turn so the coil stays a coil, 40..120.
    turns = lengths / period
    npts = np.clip(np.round(14 * turns) + 1 + rng.integers(-2, 3, n), 40, nmax).astype(int)
    # The path and its frames at each strand's points (padded to nmax with the tip).
    j = np.arange(nmax)[None, :]
    u = np.minimum(j, npts[:, None] - 1) / (npts[:, None] - 1) * steps
    k = np.minimum(np.floor(u).astype(int), steps - 1)
    f = (u - k)[..., None]
    rows = np.arange(n)[:, None]

    def at(x):
        return x[rows, k] * (1 - f) + x[rows, k + 1] * f

    cp, e1, e2 = at(path), at(b1), at(b2)
    e1 /= np.linalg.norm(e1, axis=2, keepdims=True)
    e2 /= np.linalg.norm(e2, axis=2, keepdims=True)
    s = at(sp[..., None])[..., 0]
    # Coils are irregular: the phase drifts, the radius breathes a little
    # (within 3-6 mm), and it opens out over the first 3 mm from the root.
    drift = np.cumsum(rng.normal(0, 0.12, (n, steps + 1)), axis=1)
    ph = (2 * np.pi * s / period[:, None] + rng.uniform(0, 2 * np.pi, n)[:, None]
          + at(drift[..., None])[..., 0])
    r = radius[:, None] * (1 + 0.1 * np.sin(2 * np.pi * s / rng.uniform(0.02, 0.04, n)[:, None]
                                            + rng.uniform(0, 2 * np.pi, n)[:, None]))
    r = np.clip(r, 0.003, 0.006) * np.sqrt(np.clip(s / 0.003, 0, 1))
    pts = cp + r[..., None] * (np.cos(ph)[..., None] * e1 + np.sin(ph)[..., None] * e2)
    # A coil near the root may dip under the scalp: back onto it.
    rr = np.linalg.norm(pts / HEAD, axis=2)
    pts[rr < 1] /= rr[rr < 1, None]
    keep = (j < npts[:, None]).ravel()
    pts = pts.reshape(-1, 3)[keep]                   # y up, metres
    # Thick strands, 160-200 um at the root, 75-85% of it at the tip (>= 120 um).
    w0 = rng.uniform(160e-6, 200e-6, n)
    tip = rng.uniform(0.75, 0.85, n)
    thick = np.concatenate([w0[i] * (1 - (1 - tip[i]) * np.linspace(0, 1, npts[i]))
                            for i in range(n)])
    # Dark brown to near black per strand, the ends a touch lighter.
    brown, black = np.array([0.16, 0.095, 0.055]), np.array([0.035, 0.028, 0.024])
    mix = rng.random(n) ** 0.7
    base = (brown * (1 - mix[:, None]) + black * mix[:, None]) * rng.uniform(0.85, 1.1, n)[:, None]
    col = np.concatenate([base[i] * (1 + 0.12 * np.linspace(0, 1, npts[i]) ** 2)[:, None]
                          for i in range(n)])
    # x up, inches: y-up (X, Y, Z) -> x-up (Y, -X, Z), a rotation about z that
    # keeps the face towards +z.
    px = np.stack([pts[:, 1], -pts[:, 0], pts[:, 2]], 1) / 0.0254
    write_hair("coily_xup_in.hair", npts - 1, px, SEGMENTS | POINTS | THICKNESS | COLORS,
               d_seg=0, d_thick=1.0, d_transp=0.0, d_color=(1, 1, 1),
               thick=thick / 0.0254, color=col, info="coily afro, x up, inches")


def model_e(rng):
    n, steps, nc = 25000, 32, 320
    roots = sample_scalp(rng, n, front_line=0.42, back_line=-0.15)
    nrm = normals(roots)
    # Clumps: a few hundred centres among the roots, each strand in its
    # nearest's (by root), so a clump is a patch of scalp, as gel gathers it.
    cidx = rng.choice(n, nc, replace=False)
    d2 = ((roots[:, None, :] - roots[None, cidx, :]) ** 2).sum(-1)
    clump = np.argmin(d2, axis=1)
    R, N = roots[cidx], nrm[cidx]
    # Where a clump sits: top (crown and top of the head: long, standing),
    # the sides and back below it (short, combed flat), and the fringe (the
    # front hairline: forward and down over the forehead).
    hy = R[:, 1] / HEAD[1]
    top = np.clip((hy - 0.35) / 0.4, 0, 1) ** 1.5
    cz = R[:, 2] / np.linalg.norm(R[:, [0, 2]], axis=1)     # cos of the azimuth, 1 at the face
    fringe = np.clip((cz - 0.55) / 0.3, 0, 1) * np.clip((0.8 - hy) / 0.2, 0, 1)

    def tangent(v):
        """v's part in the scalp's tangent plane at each clump, unit."""
        t = v - np.sum(v * N, axis=1, keepdims=True) * N
        return t / np.linalg.norm(t, axis=1, keepdims=True)

    # Spikes at the top stand up and lean back; 20% splay out anywhere above
    # the scalp; the sides and back lie down and back along the scalp; the
    # fringe points forward and down.
    splay = rng.random(nc) < 0.2
    d_top = N + np.array([0.0, 0.35, -0.6]) + rng.normal(0, 0.25, (nc, 3))
    d_top[splay] += rng.normal(0, 0.7, (splay.sum(), 3))
    d_top /= np.linalg.norm(d_top, axis=1, keepdims=True)
    d_top += np.maximum(0.35 - np.sum(d_top * N, 1), 0)[:, None] * N    # never into the head
    d_side = 0.15 * N + tangent(np.array([0.0, -0.7, -1.0]) + rng.normal(0, 0.25, (nc, 3)))
    d_fringe = 0.2 * N + tangent(np.array([0.0, -1.0, 0.1]) + rng.normal(0, 0.35, (nc, 3)))
    dirs = top[:, None] * d_top + (1 - top[:, None]) * d_side
    dirs = (1 - fringe[:, None]) * dirs / np.linalg.norm(dirs, axis=1, keepdims=True) + fringe[:, None] * d_fringe
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    # Clump lengths: 4-9 cm at the top, 2-4 cm at the sides and back, 4-7 cm
    # in the fringe; the tip is where the clump's strands meet.
    L = (1 - top) * rng.uniform(0.02, 0.04, nc) + top * rng.uniform(0.04, 0.09, nc)
    L = (1 - fringe) * L + fringe * rng.uniform(0.04, 0.07, nc)
    tipc = R + L[:, None] * dirs
    # Each strand: a quadratic Bezier out of its root (first along the
    # clump's direction, lifted off the scalp) to the clump's tip, or most of
    # the way there in a splayed clump (convergence 0.35-0.7, else 0.9-1),
    # with a millimetre or two of scatter where the gel did not hold; cut at
    # 60-100% of it, so fewer strands reach the tip and the spike is pointed.
    conv = np.where(splay, rng.uniform(0.35, 0.7, nc), rng.uniform(0.9, 1.0, nc))[clump]
    c = clump
    p0 = roots
    lift = np.where(top[c] > 0.5, 0.6, 0.15)[:, None]
    p1 = p0 + 0.4 * L[c, None] * (dirs[c] + lift * nrm) / np.linalg.norm(dirs[c] + lift * nrm, axis=1, keepdims=True)
    p2 = p0 + (tipc[c] - R[c]) + conv[:, None] * (R[c] - p0) + rng.normal(0, 0.0012, (n, 3))
    cut = 1 - 0.4 * rng.random(n) ** 1.5
    t = cut[:, None, None] * np.linspace(0, 1, steps + 1)[None, :, None]
    path = (1 - t) ** 2 * p0[:, None] + 2 * t * (1 - t) * p1[:, None] + t ** 2 * p2[:, None]
    # A little unevenness along the strand, none at the root.
    wob = np.cumsum(rng.normal(0, 0.00015, path.shape), axis=1)
    path += (wob - wob[:, :1]) * np.linspace(0, 1, steps + 1)[None, :, None]
    # Kept outside the head, grown by a per-strand layer that opens over the
    # first centimetre (a flat strand at the side would cut the ellipsoid's
    # curve between its root and its tip).
    layer = rng.uniform(0.005, 0.035, n)
    seg = np.linalg.norm(np.diff(path, axis=1), axis=2)
    s = np.concatenate([np.zeros((n, 1)), np.cumsum(seg, axis=1)], 1)
    grown = 1 + layer[:, None] * np.clip(s / 0.01, 0, 1)
    rr = np.linalg.norm(path / HEAD, axis=2) / grown
    path[rr < 1] /= rr[rr < 1, None]
    # Slicked down below the top: a straight spike at the sides, back or
    # fringe would stand off the curved scalp by centimetres at its tip, so
    # its height over the layer is cut by up to 60% (none at the top).
    flat = 0.6 * np.maximum(1 - top, fringe)[c][:, None]
    rr = np.maximum(np.linalg.norm(path / HEAD, axis=2), grown)
    path *= ((grown + (rr - grown) * (1 - flat)) / rr)[..., None]
    # Points by length: 8 for the shortest, 24 for the longest, +-2.
    length = s[:, -1]
    npts = np.clip(np.round(8 + 16 * (length - length.min()) / np.ptp(length)
                            + rng.integers(-2, 3, n)), 8, 24).astype(int)
    strands = resample(path, npts)
    pts = np.concatenate(strands)                    # y up, metres
    # Medium strands tapering hard: 110-150 um at the root, 20-40% of it at
    # the tip, most of the loss in the outer half; transparency from 0 at the
    # root to 0.2-0.5 at the tip (the thin, gel-coated ends).
    w0 = rng.uniform(110e-6, 150e-6, n)
    wt = rng.uniform(0.2, 0.4, n)
    tmax = rng.uniform(0.2, 0.5, n)
    u = [np.linspace(0, 1, k) for k in npts]
    thick = np.concatenate([w0[i] * (1 - (1 - wt[i]) * u[i] ** 1.6) for i in range(n)])
    transp = np.concatenate([tmax[i] * u[i] ** 1.5 for i in range(n)])
    # z up, decimetres, origin at the head's centre: y-up (X, Y, Z) -> z-up
    # (X, -Z, Y), the face towards -y.
    pe = np.stack([pts[:, 0], -pts[:, 2], pts[:, 1]], 1) * 10.0
    write_hair("spiky_zup_dm.hair", npts - 1, pe, SEGMENTS | POINTS | THICKNESS | TRANSPARENCY,
               d_seg=0, d_thick=0.0013, d_transp=0.0, d_color=(0.42, 0.3, 0.17),
               thick=thick * 10.0, transp=transp, info="gelled spiky short cut, z up, dm")


if __name__ == "__main__":
    args = sys.argv[1:]
    if args[:1] in (["-h"], ["--help"]):
        print(__doc__[__doc__.index("Usage:"):].rstrip())
        sys.exit(0)
    seed = 0
    if args[:1] == ["--seed"]:
        if len(args) < 2 or not args[1].isdigit() or int(args[1]) < 1:
            sys.exit("models_written_apart.py: --seed takes a whole number from 1")
        seed, args = int(args[1]), args[2:]
    models = {"a": model_a, "b": model_b, "c": model_c, "d": model_d, "e": model_e}
    which = args or ["a", "b", "c"]   # d and e only by name: the evaluation's three
    for w in which:
        if w not in models:
            sys.exit(f"models_written_apart.py: {w!r}: the models are a, b, c, d and e "
                     "(--help says more)")
        # Without --seed, the seeds of docs/QUALITY.md's evaluation frames.
        models[w](np.random.default_rng(ord(w) + 11 if not seed else [seed, ord(w)]))
