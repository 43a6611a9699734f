#!/usr/bin/python3
"""Feature EXR seeds of the layouts hf_exr_write does not make, for the exr
fuzz target: tiled, uncompressed, RLE, PIZ and B44 scanlines, half and
float, a crop whose data window is not the display window, and two parts
(features and something else). OpenImageIO from Debian (python3-openimageio).

    /usr/bin/python3 tests/fuzz/make_exr_seeds.py tests/fuzz/corpus/exr
"""
import os
import sys

import numpy as np
import OpenImageIO as oiio

FEATURES = ["color", "highlight", "alpha", "depth", "tangent.x", "tangent.y"]


def channels(spp):
    return [f"S{k}.{f}" for k in range(spp) for f in FEATURES]


def frame(w, h, spp):
    x = np.arange(w * h * spp * 6, dtype=np.float32).reshape(h, w, spp * 6)
    return (x % 9) / 9


def write(path, w, h, spp, compression, half=False, tile=None, origin=(0, 0), full=None):
    spec = oiio.ImageSpec(w, h, spp * 6, "half" if half else "float")
    spec.channelnames = tuple(channels(spp))
    spec.attribute("compression", compression)
    spec.x, spec.y = origin
    if full:
        spec.full_width, spec.full_height = full
    if tile:
        spec.tile_width, spec.tile_height = tile
    out = oiio.ImageOutput.create(path)
    if not out or not out.open(path, spec):
        sys.exit(f"cannot write {path}: {oiio.geterror()}")
    out.write_image(frame(w, h, spp))
    out.close()


def main():
    # The folder is the one argument: an option, or none, gets the usage
    # (--help was taken for a folder, and the seeds written into it).
    if len(sys.argv) != 2 or sys.argv[1].startswith("-"):
        help_asked = sys.argv[1:] in (["-h"], ["--help"])
        print("usage: make_exr_seeds.py DIR\n\n" + __doc__.strip(),
              file=sys.stdout if help_asked else sys.stderr)
        sys.exit(0 if help_asked else 2)
    d = sys.argv[1]
    os.makedirs(d, exist_ok=True)
    write(f"{d}/features_tiled.exr", 5, 3, 1, "zip", tile=(2, 2))
    write(f"{d}/features_none.exr", 3, 2, 2, "none")
    write(f"{d}/features_rle_half.exr", 3, 2, 1, "rle", half=True)
    write(f"{d}/features_piz.exr", 4, 4, 1, "piz")
    write(f"{d}/features_b44_half.exr", 4, 4, 1, "b44", half=True)
    write(f"{d}/features_crop.exr", 3, 2, 1, "zips", origin=(5, 7), full=(20, 10))
    # two parts: the features and a beauty image
    path = f"{d}/features_two_parts.exr"
    specs = [oiio.ImageSpec(3, 2, 6, "half"), oiio.ImageSpec(3, 2, 3, "half")]
    specs[0].channelnames = tuple(channels(1))
    specs[1].channelnames = ("R", "G", "B")
    for i, s in enumerate(specs):
        s.attribute("name", ["features", "beauty"][i])
        s.attribute("compression", "zip")
    out = oiio.ImageOutput.create(path)
    if not out.open(path, specs):
        sys.exit(f"cannot write {path}: {oiio.geterror()}")
    out.write_image(frame(3, 2, 1))
    out.open(path, specs[1], "AppendSubimage")
    out.write_image(np.full((2, 3, 3), 0.5, dtype=np.float32))
    out.close()


if __name__ == "__main__":
    main()
