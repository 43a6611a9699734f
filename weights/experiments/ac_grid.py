"""A figure of frames that eval_rows.py wrote (the trained network as
st1.*): one row per frame, a square crop each of stochastic transparency at
4 and 16 spp, the alpha-corrected estimate (acst4.*), the network (st1.*)
and the ground truth, composited as `hairfilter eval`'s images are (the
CLI's default hair colour, light and background, over the frame's
background layer where it has one; hfr_composite_result), then sRGB.

  python3 weights/experiments/ac_grid.py OUT.png FRAME.exr:X,Y,SIZE ...

No backend runs the networks eval_rows.py scores, so `hairfilter eval
--grid` cannot show them; this is that grid's layout for them."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import numpy as np  # noqa: E402
import OpenImageIO as oiio  # noqa: E402

import dataset  # noqa: E402

# client/cli/cli_common.c: CLI_HAIR_DEFAULT, CLI_LIGHT_DEFAULT, CLI_BG_DEFAULT.
HAIR = np.array([0.45, 0.25, 0.12], np.float32)
LIGHT = np.array([1.0, 1.0, 1.0], np.float32)
BG = np.array([0.18, 0.2, 0.24], np.float32)
COLUMNS = ("st4", "st16", "acst4", "st1", "gt")
GAP = 4


def composite(names, data, prefix):
    """Linear rgb [h][w][3] of the result channels prefix.* (hf_composite's
    formula, over the background layer when the frame has one)."""
    c, h, a = (data[..., names.index(f"{prefix}.{k}")][..., None]
               for k in ("color", "highlight", "alpha"))
    under = BG
    if "background.A" in names:
        layer = np.stack([data[..., names.index(f"background.{k}")] for k in "RGB"], -1)
        under = layer + (1 - data[..., names.index("background.A")][..., None]) * BG
    return np.clip(a * LIGHT * (HAIR * c + h) + (1 - a) * under, 0, 1)


def srgb(x):
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def main(argv):
    if argv in (["-h"], ["--help"]):
        print(__doc__)
        return 0
    if len(argv) < 2:
        sys.exit(__doc__)
    rows = []
    for spec in argv[1:]:
        path, _, box = spec.rpartition(":")
        x, y, s = (int(v) for v in box.split(","))
        names, data = dataset.read_exr(path)
        missing = [p for p in COLUMNS if f"{p}.alpha" not in names]
        if missing:
            sys.exit(f"ac_grid.py: {path} has no {', '.join(missing)} channels")
        tiles = [composite(names, data, p)[y:y + s, x:x + s] for p in COLUMNS]
        if any(t.shape[:2] != (s, s) for t in tiles):
            sys.exit(f"ac_grid.py: {spec}: the crop leaves the frame")
        gap = np.ones((s, GAP, 3), np.float32)
        rows.append(np.concatenate(sum(([t, gap] for t in tiles), [])[:-1], 1))
    width = rows[0].shape[1]
    if any(r.shape[1] != width for r in rows):
        sys.exit("ac_grid.py: every crop needs the same SIZE")
    gap = np.ones((GAP, width, 3), np.float32)
    img = srgb(np.concatenate(sum(([r, gap] for r in rows), [])[:-1], 0)).astype(np.float32)
    out = oiio.ImageBuf(oiio.ImageSpec(img.shape[1], img.shape[0], 3, oiio.UINT8))
    out.set_pixels(oiio.ROI(), img)
    if not out.write(argv[0]):
        sys.exit(f"ac_grid.py: {argv[0]}: {out.geterror()}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
