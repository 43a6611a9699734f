#!/usr/bin/python3
"""Writes hair models made without the renderer's styles, in the
conventions assets arrive in (docs/QUALITY.md, "Models the styles did not
make"; tied and fur are evaluated held out, and other seeds of all four
are training data, weights/base.md):

    hair_models.py tied OUT.hair [--seed N]
        a long tied style: hair combed back over the scalp to a tie at the
        back of the head and hanging down as a tail; y up, inches, per-point
        thickness tapering from 0.0035 in at the root to 0.0012 in at the
        tip (human hair is about 0.003 in), about 40 points per strand,
        unevenly spaced as a groom tool's resampling leaves them.
    hair_models.py fur OUT.hair [--mesh BODY.obj] [--seed N]
        an animal's fur: short guides over a four-legged body (torso, head,
        legs), combed back and down; z up, millimetres, front towards -y,
        per-point thickness 0.09 mm at the root to 0.03 mm at the tip, 6
        segments per guide (grow children at render time with
        --children); --mesh also writes the body as a triangle mesh, to
        render with --occluder BODY.obj.
    hair_models.py spiky OUT.hair [--seed N]
        a short spiky cut: strands gathered into gelled spikes 1.5 to 6 cm
        long that stand out from the scalp and lean up and back, each
        strand ending at 55 to 100% of its spike (strands about 0.6 to 7
        cm); z up, centimetres, face towards -y, per-point thickness 0.009
        cm at the root to 0.003 cm at the tip, 8 to 13 points per strand.
    hair_models.py coily OUT.hair [--seed N]
        tightly coiled hair standing out from the scalp as an afro: each
        strand a helix of radius 1.5 to 4 mm and pitch 2 to 5 mm around a
        centre line 30 to 90 mm long that rises from the scalp and sags;
        y up, millimetres, face towards +z, per-point thickness 0.09 mm at
        the root to 0.05 mm at the tip, 8 points per turn.

Render the spiky and coily models with --occluder fit (the head fitted
under the roots). The directories of OUT and BODY must exist. Prints
what it wrote.

Numpy only. The format is Cem Yuksel's (docs/RENDERING.md, "Your own
models"): header, segments, points, thickness."""
import argparse
import os
import struct

import numpy as np

HEADER = 128
SEGMENTS, POINTS, THICKNESS = 1, 2, 4


def write_hair(path, strands, info):
    """strands: list of (P x 3 positions, P thicknesses); P >= 2."""
    seg = np.array([len(p) - 1 for p, _ in strands], "<u2")
    pos = np.concatenate([p for p, _ in strands]).astype("<f4")
    thk = np.concatenate([t for _, t in strands]).astype("<f4")
    flags = SEGMENTS | POINTS | THICKNESS
    text = info.encode()[:88].ljust(88, b"\0")
    hdr = struct.pack("<4s4I5f", b"HAIR", len(strands), len(pos), flags, 0,
                      float(thk.mean()), 0.0, 0.3, 0.2, 0.1) + text
    assert len(hdr) == HEADER
    with open(path, "wb") as f:
        f.write(hdr + seg.tobytes() + pos.tobytes() + thk.tobytes())


def taper(n, root, tip):
    return np.linspace(root, tip, n)


def tied(rng, count):
    """Long tied style, y up, inches; head ellipsoid at the origin, face +z."""
    rad = np.array([3.0, 3.6, 3.4])                  # half-widths x, y, z (in)
    tie = np.array([0.0, 1.6, -3.55])                # where the tail is tied
    out = []
    while len(out) < count:
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        root = d * rad
        # hairline: from the forehead (1.8 in above the centre) over the
        # ears (-1.0) to the nape (-2.6)
        if root[1] < -1.0 - 1.6 * max(0.0, -d[2]) + 2.8 * max(0.0, d[2]):
            continue
        lift = rng.uniform(0.02, 0.12)               # layer above the scalp
        end = tie + rng.normal(scale=0.18, size=3) * np.array([1, 1, 0.4])
        pts = []
        n1 = rng.integers(14, 20)
        ts = np.concatenate([[0.0], np.sort(rng.uniform(0, 1, n1 - 2)), [1.0]])
        for t in ts:
            q = (1 - t) * root + t * end
            # over the scalp: q brought out to the head's surface along the
            # ray from its centre, lifted by this strand's layer; joining
            # the tie at the end
            on = q / np.sqrt(np.sum((q / rad) ** 2))
            h = 0.01 + lift * np.sin(np.pi * min(t * 1.3, 1.0))
            w = t ** 4
            pts.append((1 - w) * on * (1 + h / 3.4) + w * q)
        # the tail: out of the tie, back, then down, spreading
        length = rng.uniform(7.0, 15.0)
        phi = rng.uniform(0, 2 * np.pi)
        spread = rng.uniform(0.2, 1.0)
        wave_a, wave_p = rng.uniform(0.05, 0.25), rng.uniform(2.0, 4.5)
        n2 = rng.integers(22, 30)
        ss = np.concatenate([np.sort(rng.uniform(0, 1, n2 - 1)), [1.0]]) * length
        for s in ss:
            r = 0.25 + spread * 0.12 * s
            off = np.array([r * np.cos(phi), 0.0, r * np.sin(phi) * 0.6])
            back = -1.4 * (1 - np.exp(-s / 1.5))
            wave = wave_a * np.sin(2 * np.pi * s / wave_p + phi)
            pts.append(end + off + np.array([wave, -s, back]))
        p = np.array(pts)
        out.append((p, taper(len(p), 0.0035, 0.0012)))
    return out


def scalp_roots(rng, n, rad, keep):
    """n points on the ellipsoid of half-widths rad where keep(unit
    direction) holds; returns (points, outward unit normals)."""
    pts, nrm = [], []
    while len(pts) < n:
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        if not keep(d):
            continue
        q = d * rad
        g = q / rad ** 2
        pts.append(q)
        nrm.append(g / np.linalg.norm(g))
    return np.array(pts), np.array(nrm)


def spiky(rng, count):
    """Short spiky cut, z up, cm; head ellipsoid at the origin, face -y."""
    rad = np.array([7.6, 9.4, 9.8])                   # half-widths x, y, z (cm)
    # hairline: high over the forehead (-y), low at the nape (+y)
    keep = lambda d: d[2] > 0.05 + 0.45 * max(0.0, -d[1]) - 0.35 * max(0.0, d[1])
    nclump = max(1, count // rng.integers(20, 45))
    centres, normals = scalp_roots(rng, nclump, rad, keep)
    up_back = np.array([0.0, 0.45, 0.9])
    tips = []
    for c, n in zip(centres, normals):
        lean = rng.uniform(0.2, 0.6)
        d = (1 - lean) * n + lean * up_back + rng.normal(scale=0.15, size=3)
        d /= np.linalg.norm(d)
        length = rng.uniform(1.5, 6.0)
        tips.append(c + d * length)
    tips = np.array(tips)
    out = []
    roots, rnorm = scalp_roots(rng, count, rad, keep)
    for root, n in zip(roots, rnorm):
        k = int(np.argmin(np.sum((centres - root) ** 2, axis=1)))
        short = rng.uniform(0.55, 1.0)               # strands end short of the tip
        tip = root + short * (tips[k] - root) + rng.normal(scale=0.12, size=3)
        npts = rng.integers(8, 14)
        ts = np.linspace(0.0, 1.0, npts) ** 1.2
        lift = 0.25 * np.linalg.norm(tip - root)
        pts = [(1 - t) * root + t * tip + n * lift * np.sin(np.pi * t) * (1 - t)
               for t in ts]
        out.append((np.array(pts), taper(npts, 0.009, 0.003)))
    return out


def coily(rng, count):
    """Coiled hair as an afro, y up, mm; head ellipsoid at the origin,
    face +z."""
    rad = np.array([76.0, 92.0, 96.0])                # half-widths x, y, z (mm)
    keep = lambda d: d[1] > -0.05 + 0.5 * max(0.0, d[2]) - 0.45 * max(0.0, -d[2])
    roots, normals = scalp_roots(rng, count, rad, keep)
    up = np.array([0.0, 1.0, 0.0])
    out = []
    for root, n in zip(roots, normals):
        length = rng.uniform(30.0, 90.0)
        radius = rng.uniform(1.5, 4.0)
        pitch = rng.uniform(2.0, 5.0)
        turns = length / pitch
        npts = max(8, int(turns * 8))
        sag = rng.uniform(0.0, 0.35)
        phase = rng.uniform(0, 2 * np.pi)
        s = np.linspace(0.0, 1.0, npts)
        # centre line: out along the normal, then bending down a little
        dirs = n[None, :] - sag * s[:, None] ** 2 * up[None, :]
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        centre = root + np.cumsum(dirs, axis=0) * (length / npts)
        centre -= centre[0] - root
        # a frame around the normal for the helix
        a = np.cross(n, up if abs(n[1]) < 0.9 else np.array([1.0, 0.0, 0.0]))
        a /= np.linalg.norm(a)
        b = np.cross(n, a)
        ang = phase + 2 * np.pi * turns * s
        grow = np.minimum(1.0, s * 8.0)                # the coil opens off the root
        p = centre + radius * grow[:, None] * (np.cos(ang)[:, None] * a + np.sin(ang)[:, None] * b)
        out.append((p, taper(npts, 0.09, 0.05)))
    return out


# body parts of the animal, z up, mm, front -y: ("ellipsoid", centre, radii)
# and ("cylinder", base centre, radius, height)
BODY = [
    ("ellipsoid", (0.0, 0.0, 360.0), (120.0, 270.0, 125.0)),
    ("ellipsoid", (0.0, -320.0, 460.0), (75.0, 95.0, 75.0)),
    ("cylinder", (70.0, -170.0, 0.0), 34.0, 330.0),
    ("cylinder", (-70.0, -170.0, 0.0), 34.0, 330.0),
    ("cylinder", (70.0, 170.0, 0.0), 38.0, 330.0),
    ("cylinder", (-70.0, 170.0, 0.0), 38.0, 330.0),
]


def body_samples(rng, n):
    """n points on the body's surface with outward normals, by area."""
    areas = []
    for part in BODY:
        if part[0] == "ellipsoid":
            a, b, c = part[2]
            p = 1.6075
            areas.append(4 * np.pi * (((a * b) ** p + (a * c) ** p + (b * c) ** p) / 3) ** (1 / p))
        else:
            areas.append(2 * np.pi * part[2] * part[3])
    areas = np.array(areas) / np.sum(areas)
    pts, nrm = [], []
    for k in rng.choice(len(BODY), size=n, p=areas):
        part = BODY[k]
        if part[0] == "ellipsoid":
            c, r = np.array(part[1]), np.array(part[2])
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            q = c + d * r
            g = d / r
            pts.append(q)
            nrm.append(g / np.linalg.norm(g))
        else:
            c, r, h = np.array(part[1]), part[2], part[3]
            a = rng.uniform(0, 2 * np.pi)
            q = c + np.array([r * np.cos(a), r * np.sin(a), rng.uniform(0, h)])
            pts.append(q)
            nrm.append(np.array([np.cos(a), np.sin(a), 0.0]))
    return np.array(pts), np.array(nrm)


def inside_body(q):
    for part in BODY:
        if part[0] == "ellipsoid":
            if np.sum(((q - np.array(part[1])) / np.array(part[2])) ** 2) < 0.98:
                return True
        else:
            c, r, h = np.array(part[1]), part[2], part[3]
            if np.hypot(*(q[:2] - c[:2])) < 0.98 * r and c[2] <= q[2] <= c[2] + h:
                return True
    return False


def fur(rng, count):
    """Fur guides on BODY: short, combed back (+y) and down (-z)."""
    out = []
    roots, normals = body_samples(rng, 4 * count)
    comb = np.array([0.0, 0.75, -0.65])
    comb /= np.linalg.norm(comb)
    for root, n in zip(roots, normals):
        if len(out) == count:
            break
        if inside_body(root + 2.0 * n):             # root hidden where parts meet
            continue
        length = rng.uniform(14.0, 34.0)
        t = comb - np.dot(comb, n) * n
        t = t / (np.linalg.norm(t) + 1e-9)
        lift = rng.uniform(0.25, 0.6)
        curl = rng.normal(scale=0.25, size=3)
        p = [root]
        d = lift * n + (1 - lift) * t
        for i in range(6):
            d = d + 0.18 * (t - d) + 0.1 * curl * np.sin(i)
            d /= np.linalg.norm(d)
            p.append(p[-1] + d * length / 6)
        p = np.array(p)
        out.append((p, taper(len(p), 0.09, 0.03)))
    return out


def write_body_obj(path, rings=24, sectors=48):
    """BODY as a triangulated OBJ (z up, mm): the occluder to render with."""
    v, f = [], []
    for part in BODY:
        base = len(v)
        if part[0] == "ellipsoid":
            c, r = np.array(part[1]), np.array(part[2])
            for i in range(rings + 1):
                th = np.pi * i / rings
                for j in range(sectors):
                    ph = 2 * np.pi * j / sectors
                    v.append(c + r * np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph),
                                               np.cos(th)]))
            for i in range(rings):
                for j in range(sectors):
                    a = base + i * sectors + j
                    b = base + i * sectors + (j + 1) % sectors
                    f += [(a, a + sectors, b), (b, a + sectors, b + sectors)]
        else:
            c, r, h = np.array(part[1]), part[2], part[3]
            for z in (0.0, h):
                for j in range(sectors):
                    ph = 2 * np.pi * j / sectors
                    v.append(c + np.array([r * np.cos(ph), r * np.sin(ph), z]))
            for j in range(sectors):
                a, b = base + j, base + (j + 1) % sectors
                f += [(a, b, a + sectors), (b, b + sectors, a + sectors)]
    with open(path, "w") as o:
        for q in v:
            o.write(f"v {q[0]:.3f} {q[1]:.3f} {q[2]:.3f}\n")
        for t in f:
            o.write(f"f {t[0] + 1} {t[1] + 1} {t[2] + 1}\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("model", choices=["tied", "fur", "spiky", "coily"], help="which model")
    ap.add_argument("out", help="the .hair file to write")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--strands", type=int, help="strands (tied: 6000, spiky: 20000, coily: 8000) or guides (fur: 4000)")
    ap.add_argument("--mesh", help="fur: also write the body as this OBJ")
    a = ap.parse_args()
    if a.mesh and a.model != "fur":
        ap.error("--mesh: only the fur model has a body mesh")
    if a.strands is not None and not 1 <= a.strands <= 1000000:
        ap.error("--strands: 1 to 1000000")
    for path in (a.out, a.mesh):
        d = os.path.dirname(path) if path else ""
        if d and not os.path.isdir(d):
            ap.error(f"{path}: the directory {d} does not exist; create it first (mkdir -p {d})")
    rng = np.random.default_rng(a.seed)
    if a.model == "tied":
        strands = tied(rng, a.strands or 6000)
        write_hair(a.out, strands, "tied style, y up, inches")
        how = "y up, inches: render with --units in"
    elif a.model == "spiky":
        strands = spiky(rng, a.strands or 20000)
        write_hair(a.out, strands, "spiky cut, z up, cm, face -y")
        how = "z up, centimetres: render with --up z --units cm --occluder fit"
    elif a.model == "coily":
        strands = coily(rng, a.strands or 8000)
        write_hair(a.out, strands, "coily afro, y up, mm, face +z")
        how = "y up, millimetres: render with --units mm --occluder fit"
    else:
        strands = fur(rng, a.strands or 4000)
        write_hair(a.out, strands, "fur guides, z up, mm, front -y")
        how = "z up, millimetres: render with --up z --units mm"
        if a.mesh:
            write_body_obj(a.mesh)
            print(f"{a.mesh}: the body, for --occluder")
    points = sum(len(p) for p, _ in strands)
    print(f"{a.out}: {len(strands)} strands, {points} points; {how}")


if __name__ == "__main__":
    main()
