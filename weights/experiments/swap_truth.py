"""Frames of one rendering with the ground truth (gt.*) of another: the
cheap way to score a set against a finer truth, since a frame's samples and
baselines do not depend on --gt-ss (docs/RENDERING.md, "The ground truth's
sub-pixel grid").

  python3 weights/experiments/swap_truth.py FRAMES_DIR TRUTH_DIR OUT_DIR

FRAMES_DIR holds the frames to score (every baseline); TRUTH_DIR the same
frames rendered with the other truth and nothing else (`render dataset`
with the same arguments, seed included, and `--gt-ss 8
--no-alpha-corrected` without --st; its frames are cheap). Each frame of
FRAMES_DIR is written to OUT_DIR with TRUTH_DIR's gt.color, gt.highlight
and gt.alpha, after checking that the samples (S0-S3) are the same to the
bit, and TRUTH_DIR's manifest.json is copied (hairfilter eval reads the
frames' full sizes and their truth from it). Exits 1 naming the frame when
a frame is missing or its samples differ."""
import os
import shutil
import sys

import numpy as np
import OpenImageIO as oiio

TRUTH = ("gt.color", "gt.highlight", "gt.alpha")


def read(path):
    """(ImageBuf, channel names, [h][w][c] float32 pixels) of an EXR."""
    buf = oiio.ImageBuf(path)
    if buf.has_error:
        sys.exit(f"swap_truth: {path}: {buf.geterror()}")
    return buf, list(buf.spec().channelnames), buf.get_pixels(oiio.FLOAT)


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    frames_dir, truth_dir, out_dir = sys.argv[1:]
    os.makedirs(out_dir, exist_ok=True)
    names = sorted(f for f in os.listdir(frames_dir) if f.endswith(".exr"))
    if not names:
        sys.exit(f"swap_truth: no .exr frames in {frames_dir}")
    for name in names:
        other = os.path.join(truth_dir, name)
        if not os.path.exists(other):
            sys.exit(f"swap_truth: {other} is missing: render TRUTH_DIR with the same arguments")
        buf, ch, px = read(os.path.join(frames_dir, name))
        _, tch, tpx = read(other)
        samples = [c for c in ch if c[:1] == "S" and c[1:2].isdigit()]
        for c in samples:
            if c not in tch or not np.array_equal(px[..., ch.index(c)], tpx[..., tch.index(c)]):
                sys.exit(f"swap_truth: {name}: {c} differs between the two renderings")
        for c in TRUTH:
            if c not in ch or c not in tch:
                sys.exit(f"swap_truth: {name}: no {c} in one of the two renderings")
            px[..., ch.index(c)] = tpx[..., tch.index(c)]
        out = oiio.ImageBuf(buf.spec())
        out.set_pixels(oiio.ROI(), px)
        if not out.write(os.path.join(out_dir, name)):
            sys.exit(f"swap_truth: {out_dir}/{name}: {out.geterror()}")
    manifest = os.path.join(truth_dir, "manifest.json")
    if os.path.exists(manifest):
        shutil.copy(manifest, os.path.join(out_dir, "manifest.json"))
    print(f"{len(names)} frames written to {out_dir} with the truth of {truth_dir}")


if __name__ == "__main__":
    main()
