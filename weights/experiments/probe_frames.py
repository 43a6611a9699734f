"""What the fixed-strength probes of the Kernel's output stage share
(aniso_kernel.py, bilateral_probe.py): a frame's network input, its
composited truth and its hair pixels, and the PSNR and SSIM of a result
composited with train.EVAL_LOOK against that truth on those pixels (SSIM:
train.ssim_map, windows inside the frame). Not `hairfilter eval`'s figures:
compare within a probe's row."""
import math
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import numpy as np  # noqa: E402
import torch  # noqa: E402

import dataset  # noqa: E402
import hfnet  # noqa: E402
import thick_pixels  # noqa: E402
import train  # noqa: E402


def load(path, spp):
    """(x [1][6 spp][h][w] features, truth [h][w][3] composite, hair [h][w]:
    pixels with hair in the truth or a covered sample, label DIR/FILE)."""
    names, data = dataset.read_exr(path)
    feat, _ = dataset.load_frame(path, spp=spp, dtype=np.float32)
    h, w = feat.shape[:2]
    x = hfnet.nhwc_to_nchw(feat.reshape(1, h, w, -1))
    gt = thick_pixels.planes(names, data, "gt")
    hair = (gt[2] > 0) | (feat[..., 2].max(-1) > 0)
    label = os.path.join(os.path.basename(os.path.dirname(os.path.abspath(path))),
                         os.path.basename(path))
    return x, thick_pixels.composite(*gt), hair, label


def score(y, truth, hair):
    """(PSNR dB, SSIM) of result y [3][h][w] (colour, highlight, alpha),
    composited, against truth on the hair pixels."""
    c = thick_pixels.composite(y[0], y[1], y[2])
    psnr = 10 * math.log10(1 / float(((c - truth) ** 2)[hair].mean()))
    ssim = train.ssim_map(torch.from_numpy(c).permute(2, 0, 1)[None].float(),
                          torch.from_numpy(truth).permute(2, 0, 1)[None].float())[0].numpy()
    r = train.SSIM_RADIUS
    return psnr, float(ssim[hair[r:-r, r:-r]].mean())
