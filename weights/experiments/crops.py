"""A PNG of the same crop of several results, side by side, one row per
frame: the composite `hairfilter eval` scores (train.EVAL_LOOK), display
gamma 2.2, each pixel repeated --zoom times.

  python3 weights/experiments/crops.py [--results gt,st2,st16,st4] [--size 96] [--zoom 2]
      OUT.png FRAME.exr...

Results are channel prefixes of the frames (gt: the truth; st4, st16, st64:
stochastic transparency; st1, st2: the networks eval_rows.py added). Each
crop is centred on the median position of the frame's hair pixels (truth
alpha > 0.05), moved inside the frame."""
import argparse
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import numpy as np  # noqa: E402
import OpenImageIO as oiio  # noqa: E402

import dataset  # noqa: E402
import thick_pixels  # noqa: E402


def crop_row(path, results, size):
    """[size][size * len(results)][3] composites of one frame's crop."""
    names, data = dataset.read_exr(path)
    alpha = thick_pixels.planes(names, data, "gt")[2]
    ys, xs = np.nonzero(alpha > 0.05)
    if not len(ys):
        sys.exit(f"crops.py: {path}: no hair pixels")
    h, w = alpha.shape
    y0 = min(max(0, int(np.median(ys)) - size // 2), max(0, h - size))
    x0 = min(max(0, int(np.median(xs)) - size // 2), max(0, w - size))
    return np.concatenate([thick_pixels.composite(*thick_pixels.planes(names, data, r))
                           [y0:y0 + size, x0:x0 + size]
                           for r in results], 1)


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--results", default="gt,st2,st16,st4")
    ap.add_argument("--size", type=int, default=96)
    ap.add_argument("--zoom", type=int, default=2)
    ap.add_argument("out")
    ap.add_argument("frames", nargs="+")
    args = ap.parse_args(argv)
    results = args.results.split(",")
    img = np.concatenate([crop_row(f, results, args.size) for f in args.frames], 0)
    img = np.clip(img, 0, 1) ** (1 / 2.2)
    img = np.repeat(np.repeat(img, args.zoom, 0), args.zoom, 1)
    out = oiio.ImageOutput.create(args.out)
    if not out or not out.open(args.out, oiio.ImageSpec(img.shape[1], img.shape[0], 3, oiio.UINT8)):
        sys.exit(f"crops.py: cannot write {args.out}: {oiio.geterror()}")
    out.write_image(np.round(img * 255).astype(np.uint8))
    out.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
