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
    """(strands, points, default segments, segments or None, points [n][3],
    info bytes) of the .hair file at path, checked as the renderer's reader
    (client/render/hr_hair_io.c) checks it: a file cut short or with a
    damaged header exits with the reason, naming the file, and is not
    rewritten into a file that looks whole."""
    def bad(why):
        sys.exit(f"hair_convert.py: {path}: {why}")
    try:
        with open(path, "rb") as f:
            b = f.read()
    except OSError as e:
        bad(e.strerror)
    if len(b) >= 4 and b[:4] != b"HAIR":
        bad('does not start with "HAIR": not a .hair file (Cem Yuksel\'s format)')
    if len(b) < HEADER:
        bad(f"{len(b)} bytes, shorter than the 128-byte header: cut short, copy the file again")
    strands, points, flags, defseg = struct.unpack_from("<4I", b, 4)
    if not flags & POINTS:
        swapped = int.from_bytes(struct.pack("<I", flags), "big")
        if swapped & POINTS and not swapped & ~31:
            bad(f"the header reads as big-endian (flags 0x{flags:x}): the .hair format is "
                "little-endian")
        bad(f"header flags 0x{flags:x} lack POINTS (0x2): the file has no points")
    if not strands or not points:
        bad(f"the header says {strands} strands and {points} points: an empty model")
    if not flags & SEGMENTS and defseg == 0 and points == strands:
        bad("every strand is a single point (no segments array, a default of 0 segments): "
            "nothing to draw")
    if not flags & SEGMENTS and not 1 <= defseg <= 65535:
        bad(f"no segments array and a default segment count of {defseg}, outside 1..65535: "
            "the header is damaged")
    sizes = {SEGMENTS: 2 * strands, POINTS: 12 * points, THICKNESS: 4 * points,
             TRANSPARENCY: 4 * points, COLORS: 12 * points}
    need = HEADER + sum(n for bit, n in sizes.items() if flags & bit)
    if len(b) < need:
        bad(f"{len(b)} bytes, but the header's {strands} strands and {points} points with "
            f"arrays 0x{flags & 31:x} need {need}: the file is cut short (copy it again) or its "
            "header is damaged")
    o = HEADER
    seg = None
    if flags & SEGMENTS:
        seg = np.frombuffer(b, "<u2", strands, o).copy()
        o += 2 * strands
        total = int(seg.astype(np.int64).sum()) + strands
    else:
        total = strands * (defseg + 1)
    if total != points:
        bad(f"the strands' segment counts make {total} points (a strand of n segments has "
            f"n + 1), the header says {points}: the file is damaged")
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
