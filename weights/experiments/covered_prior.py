"""How often a pixel whose 4 samples are all covered by semi-transparent
strands is opaque in the ground truth: the prior a 4-sample network learns
for such pixels, printed per data set for weights/base.md, "Five more runs
from run 10".

  python3 weights/experiments/covered_prior.py DIR_OR_FRAME.exr ...

For each argument (a frame, or a directory whose *.exr frames are taken
together), over the pixels whose first 4 samples are all covered
(S0-S3.alpha > 0) by strands of alpha below 0.999 with a median of at
least 0.3 (wide, semi-transparent strands: the dense frames where Base
loses SSIM), prints the number of such pixels and the share whose truth
alpha (gt.alpha) is below 0.99, then the same split by how many distinct
depths (S0-S3.depth, to 4 decimals) the 4 samples hit: whether the
samples tell one layer of strands (truth alpha about the strands' alpha)
from many (truth alpha 1). Frames with fewer than 4 samples are
skipped."""
import glob
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import numpy as np  # noqa: E402

from dark_hair import channels  # noqa: E402

SPP = 4
STRAND_ALPHA_MEDIAN_MIN = 0.3
STRAND_ALPHA_MAX = 0.999
TRUTH_OPAQUE = 0.99


def covered_pixels(path):
    """[SPP][2] array of one frame: per number of distinct sample depths
    (1..SPP), the pixels counted and of them those with truth alpha <
    TRUTH_OPAQUE; None when the frame has fewer than SPP samples."""
    ch = channels(path)
    if any(f"S{k}.alpha" not in ch for k in range(SPP)):
        return None
    sa = np.stack([ch[f"S{k}.alpha"] for k in range(SPP)])
    m = (sa > 0).all(0) & (np.median(sa, 0) >= STRAND_ALPHA_MEDIAN_MIN) & \
        (sa.max(0) < STRAND_ALPHA_MAX)
    depths = np.sort(np.round(np.stack([ch[f"S{k}.depth"] for k in range(SPP)])[:, m], 4), 0)
    distinct = 1 + (np.diff(depths, axis=0) != 0).sum(0)
    below = ch["gt.alpha"][m] < TRUTH_OPAQUE
    out = np.zeros((SPP, 2), np.int64)
    for k in range(1, SPP + 1):
        out[k - 1] = (distinct == k).sum(), (below & (distinct == k)).sum()
    return out


def main(argv):
    if not argv:
        sys.exit("usage: covered_prior.py DIR_OR_FRAME.exr ...")
    for arg in argv:
        files = sorted(glob.glob(os.path.join(arg, "*.exr"))) if os.path.isdir(arg) else [arg]
        if not files:
            sys.exit(f"{arg}: no .exr frames there; give a frame or a dataset directory")
        frames, counts = 0, np.zeros((SPP, 2), np.int64)
        for f in files:
            r = covered_pixels(f)
            if r is not None:
                frames += 1
                counts += r

        def share(c):
            return f"{100.0 * c[1] / c[0]:5.1f}%" if c[0] else "    -"
        split = "  ".join(f"{k + 1} depths {counts[k, 0]} px {share(counts[k])}" for k in range(SPP))
        print(f"{arg:40s} frames {frames:3d}  pixels {counts[:, 0].sum():8d}  "
              f"truth alpha < {TRUTH_OPAQUE}: {share(counts.sum(0))}  ({split})")


if __name__ == "__main__":
    main(sys.argv[1:])
