"""Frames of one rendering with the ground truth (gt.*) of another: the
cheap way to score a set against a finer truth, since a frame's samples and
baselines do not depend on --gt-ss (docs/RENDERING.md, "The ground truth's
sub-pixel grid").

  python3 weights/experiments/swap_truth.py FRAMES_DIR TRUTH_DIR OUT_DIR

FRAMES_DIR holds the frames to score (every baseline); TRUTH_DIR the same
frames rendered with the other truth and nothing else (`render dataset`
with the same arguments, seed included, and `--gt-ss 8
--no-alpha-corrected` without --st; its frames are cheap). Each frame of
FRAMES_DIR is written to OUT_DIR (a new or empty directory other than
the two) with TRUTH_DIR's gt.color, gt.highlight and gt.alpha, after
checking that every sample channel (S0.*, S1.*, ...) is the same to the
bit; then FRAMES_DIR's manifest.json, with each frame's gt_supersample and
gt_shared_positions taken from TRUTH_DIR's (hairfilter eval reads the
frames' full sizes and their truth from it). Every frame is checked
before any is written; exits 1 with a message naming what is wrong (a
missing directory or frame, samples that differ, no truth channels)."""
import json
import os
import sys

import numpy as np
import OpenImageIO as oiio

TRUTH = ("gt.color", "gt.highlight", "gt.alpha")
# The EXR header's record of the truth (hfrender.h HFR_EXR_ATTR_*): the
# output takes the truth file's, or none when it has none.
TRUTH_ATTRS = ("hairfilter:gtSupersample", "hairfilter:gtSharedPositions")


def read(path):
    """(ImageBuf, channel names, [h][w][c] float32 pixels) of an EXR."""
    buf = oiio.ImageBuf(path)
    if buf.has_error:
        fail(f"{path}: {buf.geterror()}")
    return buf, list(buf.spec().channelnames), buf.get_pixels(oiio.FLOAT)


def fail(msg):
    sys.exit(f"swap_truth: {msg}")


def load_manifest(d):
    """d/manifest.json as a dict, or None when d has none."""
    p = os.path.join(d, "manifest.json")
    if not os.path.exists(p):
        return None
    with open(p) as f:
        return json.load(f)


def swap(frames_dir, truth_dir, name):
    """(spec, pixels) of frame name of frames_dir with truth_dir's truth,
    after checking that the samples of the two are the same to the bit."""
    other = os.path.join(truth_dir, name)
    if not os.path.exists(other):
        fail(f"{other} is missing: render TRUTH_DIR with the same arguments")
    buf, ch, px = read(os.path.join(frames_dir, name))
    tbuf, tch, tpx = read(other)
    samples = [c for c in ch if c[:1] == "S" and c[1:2].isdigit()]
    if not samples:
        fail(f"{name}: no sample channels (S0.*) in {frames_dir}")
    for c in samples:
        if c not in tch or not np.array_equal(px[..., ch.index(c)], tpx[..., tch.index(c)]):
            fail(f"{name}: {c} differs between the two renderings")
    for c in TRUTH:
        if c not in ch or c not in tch:
            fail(f"{name}: no {c} in one of the two renderings")
        px[..., ch.index(c)] = tpx[..., tch.index(c)]
    spec = oiio.ImageSpec(buf.spec())
    for a in TRUTH_ATTRS:
        v = tbuf.spec().getattribute(a)
        if v is None:
            spec.erase_attribute(a)
        else:
            spec.attribute(a, int(v))
    return spec, px


def main():
    if sys.argv[1:] in (["-h"], ["--help"]):
        print(__doc__)
        return
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    frames_dir, truth_dir, out_dir = sys.argv[1:]
    for d, what in ((frames_dir, "FRAMES_DIR"), (truth_dir, "TRUTH_DIR")):
        if not os.path.isdir(d):
            fail(f"{what} {d} is not a directory")
    real = {os.path.realpath(frames_dir), os.path.realpath(truth_dir)}
    if os.path.realpath(out_dir) in real:
        fail(f"OUT_DIR {out_dir} is one of the input directories: name a new one")
    if os.path.isdir(out_dir) and os.listdir(out_dir):
        fail(f"OUT_DIR {out_dir} is not empty: name a new or empty one")
    names = sorted(f for f in os.listdir(frames_dir) if f.endswith(".exr"))
    if not names:
        fail(f"no .exr frames in {frames_dir}")
    # Two passes, one frame in memory at a time: every frame is checked
    # before any is written.
    for name in names:
        swap(frames_dir, truth_dir, name)
    os.makedirs(out_dir, exist_ok=True)
    for name in names:
        spec, px = swap(frames_dir, truth_dir, name)
        out = oiio.ImageBuf(spec)
        out.set_pixels(oiio.ROI(), px)
        if not out.write(os.path.join(out_dir, name)):
            fail(f"{out_dir}/{name}: {out.geterror()}")
    manifest, truth = load_manifest(frames_dir), load_manifest(truth_dir)
    if manifest is not None:
        by_file = {f.get("file"): f for f in (truth or {}).get("frames", [])}
        for f in manifest.get("frames", []):
            t = by_file.get(f.get("file"), {})
            for key in ("gt_supersample", "gt_shared_positions"):
                if key in t:
                    f[key] = t[key]
                else:
                    f.pop(key, None)
        with open(os.path.join(out_dir, "manifest.json"), "w") as f:
            json.dump(manifest, f, indent=2)
    print(f"{len(names)} frames written to {out_dir} with the truth of {truth_dir}")


if __name__ == "__main__":
    main()
