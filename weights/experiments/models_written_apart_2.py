#!/usr/bin/python3
"""Four hair models written from the .hair format alone, sharing no code with
client/render/tools/hair_models.py, the renderer's styles or
models_written_apart.py, for evaluating on hair no training frame was made
from (docs/QUALITY.md, "KernelMix on four more models written apart").

Each is built in one frame (centimetres, y up, face towards +z, a head about
15x18x20 cm) and written in its own up axis and unit, into the current
directory:
  bob_yup_cm.hair       shoulder-length A-line bob with bangs; y up, cm; per-point
                        thickness and transparency, 6 to 42 segments a strand
  braids_zup_m.hair     two three-strand braids (pigtails) combed from the scalp;
                        z up, metres; no thickness or transparency arrays (the
                        header's), per-point colours
  buzzbeard_xup_mm.hair buzz cut and curly beard, thick strands; x up, mm;
                        per-point thickness; buzzbeard_head_xup_mm.obj, a head,
                        jaw and neck to draw under it (--occluder)
  wavy_negy_in.hair     long wavy hair in strong clumps, 3000 guides (render with
                        --children); -y up, inches; per-point thickness

usage: models_written_apart_2.py [bob|braids|buzzbeard|wavy|braids-<variant> ...]

One random stream (seed 20261207) runs through the models in the order
given: without arguments (all four, in that order) it writes the files the
evaluation used, byte for byte; a subset gives other models.

braids-flat, braids-unplaited, braids-untwisted and braids-thick-bundles
write braids_<variant>_zup_m.hair: the braids with one thing changed
(listed below); each given alone draws what `braids` given alone draws.
"""
import struct
import sys
import numpy as np

RNG = np.random.default_rng(20261207)
HEAD_R = np.array([7.6, 9.2, 9.8])  # cm, x (ear-ear), y (up), z (front-back)


def normalize(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def sample_scalp(n, thresh_fn, radii=HEAD_R, centre=(0, 0, 0)):
    """n roots on an ellipsoid, accepted by a hairline predicate on the unit direction."""
    out = []
    got = 0
    while got < n:
        u = normalize(RNG.normal(size=(4 * n, 3)))
        # area weighting for the ellipsoid (approx): scale acceptance by local stretch
        ok = thresh_fn(u)
        u = u[ok]
        out.append(u)
        got += len(u)
    u = np.concatenate(out)[:n]
    p = u * radii + np.asarray(centre)
    nrm = normalize((p - centre) / radii ** 2)
    return u, p, nrm


def hairline(u):
    ux, uy, uz = u[:, 0], u[:, 1], u[:, 2]
    t = -0.12 + 0.45 * uz  # high at the forehead, low at the nape
    ears = (np.abs(ux) > 0.75) & (uy < 0.05) & (uz > -0.45)
    return (uy > t) & ~ears


def push_out(p, radii, centre, infl):
    q = (p - centre) / (radii * infl[:, None])
    r = np.linalg.norm(q, axis=1)
    inside = r < 1
    p[inside] = centre + (p[inside] - centre) / r[inside, None]
    return p


def grow(roots, d0, nseg, seglen, stiff, grav, infl, frizz=0.0, radii=HEAD_R, centre=np.zeros(3)):
    """Drape strands: direction relaxes towards gravity, points pushed out of the head."""
    n = len(roots)
    pts = np.empty((n, nseg + 1, 3))
    pts[:, 0] = roots
    p = roots.copy()
    d = normalize(d0)
    g = np.array([0, -1.0, 0])
    for i in range(nseg):
        d = normalize(d * stiff + g * grav + frizz * RNG.normal(size=(n, 3)))
        q = p + d * seglen[:, None]
        q = push_out(q, radii, centre, infl)
        d = normalize(q - p)
        p = q
        pts[:, i + 1] = p
    return pts


def cut_strands(pts, keep_fn):
    """Truncate each strand where keep_fn(points) first turns false (interpolated);
    returns list of arrays (variable segment counts)."""
    out = []
    keep = keep_fn(pts)  # (n, k) bool
    for s in range(len(pts)):
        k = keep[s]
        bad = np.nonzero(~k[1:])[0]
        if len(bad) == 0:
            out.append(pts[s])
            continue
        j = bad[0] + 1  # first dropped point index
        a, b = pts[s, j - 1], pts[s, j]
        # bisect the crossing
        lo, hi = 0.0, 1.0
        for _ in range(12):
            m = 0.5 * (lo + hi)
            if keep_fn((a + m * (b - a))[None, None])[0, 0]:
                lo = m
            else:
                hi = m
        tip = a + lo * (b - a)
        st = np.concatenate([pts[s, :j], tip[None]])
        if j < 2:  # a strand shorter than one segment: keep 2 points
            st = np.stack([pts[s, 0], pts[s, 0] + 0.5 * (pts[s, 1] - pts[s, 0])])
        out.append(st)
    return out


# ---------------------------------------------------------------- conversions
def to_file(p, up):
    X, Y, Z = p[..., 0], p[..., 1], p[..., 2]
    if up == "y":
        f = (X, Y, Z)
    elif up == "z":
        f = (X, -Z, Y)
    elif up == "x":
        f = (Y, -X, Z)
    elif up == "-y":
        f = (X, -Y, -Z)
    else:
        raise ValueError(up)
    return np.stack(f, axis=-1)


def write_hair(path, strands, up, scale, thick=None, transp=None, colors=None,
               d_thick=1.0, d_transp=0.0, d_color=(1, 1, 1), text="", d_seg=None):
    """strands: list of (k,3) canonical-cm arrays; scale: file units per cm."""
    segs = np.array([len(s) - 1 for s in strands], dtype=np.uint16)
    pts = np.concatenate(strands)
    pts = to_file(pts, up) * scale
    flags = 2 | 1
    if thick is not None:
        flags |= 4
    if transp is not None:
        flags |= 8
    if colors is not None:
        flags |= 16
    if d_seg is None:
        d_seg = int(np.bincount(segs).argmax())
    hdr = struct.pack("<4sIIIIff3f", b"HAIR", len(strands), len(pts), flags, d_seg,
                      d_thick, d_transp, *d_color)
    t = text.encode()[:87]
    hdr += t + b"\0" * (88 - len(t))
    assert len(hdr) == 128
    with open(path, "wb") as f:
        f.write(hdr)
        f.write(segs.tobytes())
        f.write(pts.astype("<f4").tobytes())
        if thick is not None:
            f.write((np.concatenate(thick) * scale).astype("<f4").tobytes())
        if transp is not None:
            f.write(np.concatenate(transp).astype("<f4").tobytes())
        if colors is not None:
            f.write(np.concatenate(colors).astype("<f4").tobytes())
    print(f"{path}: {len(strands)} strands, {len(pts)} points, flags {flags}, "
          f"segments {segs.min()}..{segs.max()}")


def taper(k, r, t):
    s = np.linspace(0, 1, k)
    w = np.where(s < 0.6, r, r + (t - r) * (s - 0.6) / 0.4)
    return w


# ---------------------------------------------------------------- model 1: bob
def bob(n=26000):
    u, roots, nrm = sample_scalp(n, hairline)
    part_x = 1.6
    side = np.sign(roots[:, 0] - part_x + 1e-3)
    bang = (u[:, 2] > 0.45) & (np.abs(roots[:, 0]) < 4.8) & (u[:, 1] < 0.82)
    comb = np.stack([side * 0.8, -0.3 + 0 * side, -0.35 + 0 * side], 1)
    comb[bang] = np.array([0.0, -0.2, 1.0])
    d0 = normalize(nrm * 0.6 + normalize(comb))
    infl = 1.02 + 0.10 * RNG.random(n) ** 0.7
    seglen = 0.75 * (0.95 + 0.1 * RNG.random(n))
    pts = grow(roots + nrm * 0.05, d0, 42, seglen, stiff=5.0, grav=1.0, infl=infl, frizz=0.12)
    strands = []
    # per-strand cut (loop, cut plane depends on z)
    for s in range(n):
        P = pts[s]
        cy = (-0.6 + 0.25 * RNG.normal()) if bang[s] else (-12.5 + 0.22 * P[:, 2] + 0.35 * RNG.normal())
        below = P[1:, 1] < (cy[1:] if np.ndim(cy) else cy)
        idx = np.nonzero(below)[0]
        if len(idx) == 0:
            strands.append(P)
            continue
        j = idx[0] + 1
        a, b = P[j - 1], P[j]
        ca = cy[j - 1] if np.ndim(cy) else cy
        cb = cy[j] if np.ndim(cy) else cy
        fa, fb = a[1] - ca, b[1] - cb
        t = fa / (fa - fb) if fa != fb else 0.0
        tip = a + np.clip(t, 0.05, 1) * (b - a)
        st = np.concatenate([P[:j], tip[None]])
        strands.append(st)
    # inward turn of the last 3 cm (bob ends curl under)
    for i, st in enumerate(strands):
        if bang[i] or len(st) < 6:
            continue
        L = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(st, axis=0), axis=1))])
        w = np.clip((L - (L[-1] - 3.0)) / 3.0, 0, 1) ** 2
        inward = -normalize(np.array([st[-1, 0], 0, st[-1, 2] + 1.0]))
        st += w[:, None] * inward * 0.9
    thick = [taper(len(s), 0.0085, 0.0030) * (0.85 + 0.3 * RNG.random()) for s in strands]
    transp = [np.clip(np.linspace(0.12, 0.45, len(s)) + 0.05 * RNG.normal(), 0, 0.9) for s in strands]
    write_hair("bob_yup_cm.hair", strands, "y", 1.0, thick=thick, transp=transp,
               d_thick=0.006, d_transp=0.2, text="bob with bangs, y up, cm")


# ---------------------------------------------------------------- model 2: braids
# Variants of the braids, each changing one thing (docs/QUALITY.md, "What
# makes the braids hard"): the random draws are the same, only what is made
# of them differs.
BRAIDS_VARIANTS = {
    "flat": "every strand at its own constant layer over the scalp (the braids "
            "pinch every layer to 1% at the root and at the gathering point)",
    "unplaited": "the bundles not woven: each hangs straight down the braid's line",
    "untwisted": "a strand keeps its place in its bundle (no twist along the braid)",
    "thick-bundles": "bundles 1.3 times as wide (0.715 against 0.55 cm)",
}


def braids(n=16000, variant=None):
    u, roots, nrm = sample_scalp(n, hairline)
    left = roots[:, 0] < 0
    G = np.where(left[:, None], np.array([-7.0, -4.5, -5.0]), np.array([7.0, -4.5, -5.0]))
    off = 0.1 + 0.25 * RNG.random(n)
    nsc = 16
    t = np.linspace(0, 1, nsc + 1)[None, :, None]
    gdir = normalize(G / HEAD_R)
    # slerp of directions root -> gather point
    cosw = np.clip(np.sum(u * gdir, 1), -1, 1)[:, None, None]
    w = np.arccos(cosw)
    sw = np.sin(w) + 1e-6
    dirs = (np.sin((1 - t) * w) / sw) * u[:, None] + (np.sin(t * w) / sw) * gdir[:, None]
    dirs = normalize(dirs)
    layer = np.ones_like(t) if variant == "flat" else np.sin(np.pi * t)
    scalp = dirs * HEAD_R * (1.0 + off[:, None, None] * layer * 0.05 + 0.01)
    # bundles: three per braid by root position front/middle/back & top
    key = roots[:, 2] + 0.4 * roots[:, 1]
    k = np.zeros(n, int)
    for side in (left, ~left):
        q = np.quantile(key[side], [1 / 3, 2 / 3])
        k[side] = np.digitize(key[side], q)
    nb = 64
    L = 28.0
    s = np.linspace(0, 1, nb + 1)[1:][None, :]
    ph = 2 * np.pi * k[:, None] / 3
    om = 2 * np.pi * 5.0  # five crossings periods
    a, b = 1.3, 0.55
    tie = 0.82
    taper_r = np.where(s < tie, 1.0 - 0.45 * s, 0.55 * (1 - (s - tie) / (1 - tie)) + 0.2)
    amp = np.where(s < tie, 0.0 if variant == "unplaited" else 1.0, 0.0)
    down = normalize(np.array([0.0, -1.0, -0.25]))
    lat = np.array([1.0, 0, 0])
    fwd = normalize(np.cross(lat, down))
    cen = (G[:, None, :] + s[..., None] * L * down
           + (amp * a * taper_r * np.sin(om * s + ph))[..., None] * lat
           + (amp * b * taper_r * np.sin(2 * (om * s + ph)))[..., None] * fwd)
    rr = (0.715 if variant == "thick-bundles" else 0.55) * np.sqrt(RNG.random(n))
    th = RNG.random(n) * 2 * np.pi
    twist = th[:, None] + (0.0 if variant == "untwisted" else 3.0) * s
    spread = np.where(s < tie, 1.0, 1.0 + 5.0 * (s - tie) / (1 - tie))
    o = (rr[:, None] * taper_r * spread)[..., None] * (np.cos(twist)[..., None] * lat + np.sin(twist)[..., None] * fwd)
    braid = cen + o
    # blend scalp end to braid start
    join = scalp[:, -1]
    tail = braid
    tail = tail + (join - braid[:, 0])[:, None, :] * np.exp(-s * 40)[..., None]
    pts = np.concatenate([scalp, tail], 1)
    # strands end at 88-100% of the braid length
    strands = []
    for i in range(n):
        m = nsc + 1 + int(nb * (0.88 + 0.12 * RNG.random()))
        strands.append(pts[i, :m] + 0.02 * RNG.normal(size=(m, 3)) * np.linspace(0, 1, m)[:, None])
    cols = [np.tile([0.25, 0.15, 0.08], (len(s_), 1)) for s_ in strands]
    write_hair("braids_%szup_m.hair" % (variant + "_" if variant else ""), strands, "z", 0.01, colors=cols,
               d_thick=7e-5, d_transp=0.0, d_color=(0.25, 0.15, 0.08),
               text="two three-strand braids, z up, metres")


# ---------------------------------------------------------------- model 3: buzz + beard
JAW_C = np.array([0.0, -5.5, 2.2])
JAW_R = np.array([6.4, 6.0, 7.4])


def ellipsoid_mesh(c, r, nu=48, nv=24):
    th = np.linspace(0, np.pi, nv + 1)
    ph = np.linspace(0, 2 * np.pi, nu, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    v = np.stack([np.sin(T) * np.cos(P), np.cos(T), np.sin(T) * np.sin(P)], -1).reshape(-1, 3)
    v = v * r + c
    f = []
    for i in range(nv):
        for j in range(nu):
            a = i * nu + j
            b = i * nu + (j + 1) % nu
            c_ = (i + 1) * nu + j
            d = (i + 1) * nu + (j + 1) % nu
            f.append((a, c_, d))
            f.append((a, d, b))
    return v, np.array(f)


def buzzbeard(nbuzz=42000, nbeard=22000):
    u, roots, nrm = sample_scalp(nbuzz, hairline)
    d0 = normalize(nrm + np.array([0, -0.25, -0.35]) + 0.25 * RNG.normal(size=(nbuzz, 3)))
    ln = 0.35 + 0.3 * RNG.random(nbuzz)  # 3.5-6.5 mm
    t = np.linspace(0, 1, 5)[None, :, None]
    bend = np.array([0, -1.0, -0.5])
    buzz = roots[:, None] + d0[:, None] * ln[:, None, None] * t + bend * 0.25 * (ln[:, None, None] * t) ** 2
    # beard on the jaw ellipsoid (lower front) and sideburns
    def beardline(v):
        return ((v[:, 1] < -0.05) & (v[:, 2] > -0.35)) | ((np.abs(v[:, 0]) > 0.8) & (v[:, 2] > -0.2) & (v[:, 2] < 0.25) & (v[:, 1] < 0.6))
    uj, rj, nj = sample_scalp(nbeard, beardline, radii=JAW_R, centre=JAW_C)
    # drop roots inside the head ellipsoid region above the jaw (cheeks ok)
    nseg = 9
    ln = 1.0 + 1.2 * RNG.random(nbeard)  # 10-22 mm
    dirs = normalize(nj + np.array([0, -0.9, 0.25]))
    s = np.linspace(0, 1, nseg + 1)[None, :]
    axis = rj[:, None] + dirs[:, None] * (ln[:, None] * s)[..., None]
    a1 = normalize(np.cross(dirs, np.array([0.3, 0.2, 1.0])))
    a2 = np.cross(dirs, a1)
    rad = 0.12 + 0.12 * RNG.random(nbeard)
    per = 0.45 + 0.3 * RNG.random(nbeard)
    ph0 = RNG.random(nbeard) * 2 * np.pi
    ang = ph0[:, None] + 2 * np.pi * ln[:, None] * s / per[:, None]
    grow_r = (rad[:, None] * np.minimum(1, s * 3))[..., None]
    beard = axis + grow_r * (np.cos(ang)[..., None] * a1[:, None] + np.sin(ang)[..., None] * a2[:, None])
    beard = beard - grow_r[:, :1] * 0  # root stays at the skin (grow_r 0 at s=0)
    strands = list(buzz) + list(beard)
    thick = [taper(5, 0.012, 0.007)] * nbuzz + [taper(nseg + 1, 0.015, 0.008)] * nbeard
    write_hair("buzzbeard_xup_mm.hair", strands, "x", 10.0, thick=thick,
               d_thick=0.1, text="buzz cut and curly beard, x up, mm")
    # OBJ occluder: head, jaw, neck, in the same conventions (x up, mm)
    verts, faces = [], []
    for c, r in [((0, 0, 0), HEAD_R * 0.995), (JAW_C, JAW_R * 0.99), ((0, -12, -1.5), np.array([5.2, 6.0, 5.2]))]:
        v, f = ellipsoid_mesh(np.array(c, float), np.asarray(r, float))
        faces.append(f + sum(len(x) for x in verts))
        verts.append(v)
    V = to_file(np.concatenate(verts), "x") * 10.0
    F = np.concatenate(faces)
    with open("buzzbeard_head_xup_mm.obj", "w") as fo:
        fo.write("# head+jaw+neck, x up, mm\n")
        for v in V:
            fo.write(f"v {v[0]:.4f} {v[1]:.4f} {v[2]:.4f}\n")
        for f in F:
            fo.write(f"f {f[0]+1} {f[1]+1} {f[2]+1}\n")
    print(f"buzzbeard_head_xup_mm.obj: {len(V)} vertices, {len(F)} triangles")


# ---------------------------------------------------------------- model 4: long wavy, clumped guides
def wavy(n=3000, nclump=110):
    u, roots, nrm = sample_scalp(n, hairline)
    side = np.sign(roots[:, 0] + 1e-3)
    comb = np.stack([side * 0.9, -0.2 + 0 * side, -0.45 + 0 * side], 1)
    d0 = normalize(nrm * 0.5 + normalize(comb))
    infl = 1.02 + 0.12 * RNG.random(n)
    nseg = 56
    seglen = (50.0 / nseg) * (0.85 + 0.15 * RNG.random(n))
    pts = grow(roots + nrm * 0.05, d0, nseg, seglen, stiff=6.0, grav=1.0, infl=infl, frizz=0.05)
    # clumps: nearest of nclump chosen roots
    ci = RNG.choice(n, nclump, replace=False)
    dd = np.linalg.norm(roots[:, None] - roots[ci][None], axis=2)
    cl = np.argmin(dd, 1)
    centre = pts[ci][cl]
    s = np.linspace(0, 1, nseg + 1)[None, :, None]
    cf = 0.85 * np.clip((s - 0.15) / 0.5, 0, 1) ** 1.2
    pts = pts * (1 - cf) + centre * cf
    # waves per clump, perpendicular to the hanging direction, growing along the strand
    L = np.concatenate([np.zeros((n, 1)), np.cumsum(np.linalg.norm(np.diff(pts, axis=1), axis=2), 1)], 1)
    period = (5.0 + 2.0 * RNG.random(nclump))[cl]
    ph = (RNG.random(nclump) * 2 * np.pi)[cl] + 0.3 * RNG.random(n)
    amp = (1.0 + 0.8 * RNG.random(nclump))[cl][:, None] * np.clip((L - 8) / 12, 0, 1)
    tang = normalize(np.gradient(pts, axis=1))
    outw = normalize(np.stack([pts[..., 0], 0 * pts[..., 0], pts[..., 2] + 2.0], -1))
    side_v = normalize(np.cross(tang, outw))
    wave = amp[..., None] * (np.sin(2 * np.pi * L / period[:, None] + ph[:, None])[..., None] * side_v
                             + 0.5 * np.cos(2 * np.pi * L / period[:, None] + ph[:, None])[..., None] * outw)
    pts = pts + wave
    # uneven ends: each strand 80-100% long (points dropped)
    strands = []
    for i in range(n):
        m = int((nseg + 1) * (0.8 + 0.2 * RNG.random()))
        strands.append(pts[i, :m])
    thick = [taper(len(st), 0.0082, 0.0030) for st in strands]
    write_hair("wavy_negy_in.hair", strands, "-y", 1 / 2.54, thick=thick,
               d_thick=0.003, text="long wavy clumped guides, -y up, inches")


MODELS = {"bob": bob, "braids": braids, "buzzbeard": buzzbeard, "wavy": wavy}
VARIANTS = {"braids-" + v: (lambda v=v: braids(variant=v)) for v in BRAIDS_VARIANTS}

if __name__ == "__main__":
    if any(a in ("-h", "--help") for a in sys.argv[1:]):
        print(__doc__.strip())
        print("\nThe braids' variants:")
        for v, what in BRAIDS_VARIANTS.items():
            print("  braids-%-14s %s" % (v, what))
        sys.exit(0)
    which = sys.argv[1:] or list(MODELS)
    unknown = [w for w in which if w not in MODELS and w not in VARIANTS]
    if unknown:
        print("models_written_apart_2.py: no model %s; the models: %s; the braids' variants: %s"
              % (", ".join(repr(w) for w in unknown), " ".join(MODELS), " ".join(VARIANTS)),
              file=sys.stderr)
        sys.exit(2)
    for w in which:
        (MODELS.get(w) or VARIANTS[w])()
