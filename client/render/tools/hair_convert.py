#!/usr/bin/python3
"""Rewrites a .hair file in another convention, the way assets arrive from
other tools: z up (Blender, 3ds Max, Unreal) instead of y up, in other units,
and written as Cem Yuksel's reference writer leaves a file whose author set no
thickness (points and segments only, header thickness 1.0, transparency 0).

    hair_convert.py IN.hair OUT.hair --up z --scale 10   # y-up decimetres -> z-up cm

Rendered back with `hairfilter render ... --hair OUT.hair --up z --units cm`,
the model is framed and lit as the original; its strand width is then the
renderer's documented fallback (1/2000 of the bounding radius) unless
--thickness is given. Numpy only; the format is described in
docs/RENDERING.md ("Your own models")."""
import argparse
import struct
import sys

import numpy as np

HEADER = 128
SEGMENTS, POINTS, THICKNESS, TRANSPARENCY, COLORS = 1, 2, 4, 8, 16


def read_hair(path):
    b = open(path, "rb").read()
    if len(b) < HEADER or b[:4] != b"HAIR":
        sys.exit(f"{path}: not a .hair file")
    strands, points, flags, defseg = struct.unpack_from("<4I", b, 4)
    o = HEADER
    seg = None
    if flags & SEGMENTS:
        seg = np.frombuffer(b, "<u2", strands, o).copy()
        o += 2 * strands
    pos = np.frombuffer(b, "<f4", 3 * points, o).reshape(points, 3).copy()
    return strands, points, defseg, seg, pos, b[40:128]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("src")
    ap.add_argument("dst")
    ap.add_argument("--up", choices=["y", "z"], default="z", help="up axis of the output")
    ap.add_argument("--scale", type=float, default=1.0, help="output units per input unit")
    a = ap.parse_args()
    strands, points, defseg, seg, pos, info = read_hair(a.src)
    if a.up == "z":
        # y-up (x, y, z) -> z-up (x, -z, y): the face (+z) becomes -y, Blender's front.
        pos = np.stack([pos[:, 0], -pos[:, 2], pos[:, 1]], axis=1)
    pos = (pos * a.scale).astype("<f4")
    flags = POINTS | (SEGMENTS if seg is not None else 0)
    hdr = struct.pack("<4s4I5f", b"HAIR", strands, points, flags, defseg, 1.0, 0.0, 1.0, 1.0,
                      1.0) + info
    assert len(hdr) == HEADER
    with open(a.dst, "wb") as f:
        f.write(hdr)
        if seg is not None:
            f.write(seg.astype("<u2").tobytes())
        f.write(pos.tobytes())


if __name__ == "__main__":
    main()
