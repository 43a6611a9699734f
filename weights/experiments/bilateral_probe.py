"""Kernel weights with a joint-bilateral term on their taps, measured at fixed
strengths without training and not part of any backend (weights/kernel.md
says what it scored).

Where Kernel is below 16 samples (dense hair, strands from a third of a
pixel wide) its result is a blur with no direction. A bilateral term keeps
a tap from averaging across an edge whatever the network predicted:

  logit_t -= beta * |g(p + d_t) - g(p)|^2

for pixel p and tap offset d_t, with g a guide of three planes: the
premultiplied estimate (colour x alpha, highlight x alpha, alpha) either of
the pixel's own samples (`raw`: their sums over spp) or of the Kernel's
result itself (`y0`: a second pass guided by the first). The probe runs
Kernel weights at each fixed beta and prints, per frame, the PSNR and SSIM
of the composite (train.EVAL_LOOK) against the truth's on the pixels with
hair in the truth or a covered sample (probe_frames.py, as aniso_kernel.py's
probe; not `hairfilter eval`'s figures: compare within a row).

  python3 weights/experiments/bilateral_probe.py KERNEL.safetensors BETAS raw|y0 FRAME.exr..."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import numpy as np  # noqa: E402
import torch  # noqa: E402
import torch.nn.functional as F  # noqa: E402

import hfnet  # noqa: E402
import probe_frames  # noqa: E402


def guide(raw, x, spp, radius, mode):
    """The guide planes [n][3][h][w] (see the module's docstring)."""
    if mode == "raw":
        return hfnet.pixel_sums(x, spp) / spp
    y0 = hfnet.kernel_finish(raw, x, spp, radius)
    return torch.cat([y0[:, 0:1] * y0[:, 2:3], y0[:, 1:2] * y0[:, 2:3], y0[:, 2:3]], 1)


def finish(raw, x, spp, radius, beta, g):
    """hfnet.kernel_finish with beta times each tap's guide distance taken
    off its logit."""
    taps = hfnet.kernel_taps(radius)
    logits = raw[:, :taps].clone()
    if beta > 0:
        gp = F.pad(g, (radius,) * 4)
        for t, (dy, dx) in enumerate(hfnet._taps(radius)):
            logits[:, t] -= beta * ((hfnet._shifted(gp, radius, dy, dx) - g) ** 2).sum(1)
    return hfnet.kernel_finish(torch.cat([logits, raw[:, taps:taps + 3]], 1), x, spp, radius)


def main(argv):
    if len(argv) < 4 or argv[2] not in ("raw", "y0"):
        sys.exit(__doc__)
    torch.set_num_threads(1)
    betas = [float(b) for b in argv[1].split(",")]
    net = hfnet.load_model(argv[0]).eval()
    spp, radius = net.cfg["spp"], net.cfg["kernel_radius"]
    total = np.zeros((len(betas), 2))
    print("| frame | " + " | ".join(f"beta {b:g}" for b in betas) + " |")
    print("|---|" + "---:|" * len(betas))
    for path in argv[3:]:
        x, truth, hair, name = probe_frames.load(path, spp)
        cells = []
        with torch.no_grad():
            raw = net.raw_any_size(x)
            g = guide(raw, x, spp, radius, argv[2])
            for i, beta in enumerate(betas):
                psnr, ssim = probe_frames.score(finish(raw, x, spp, radius, beta, g)[0].numpy(),
                                                truth, hair)
                total[i] += (psnr, ssim)
                cells.append(f"{psnr:.2f} / {ssim:.3f}")
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
    n = len(argv) - 3
    print("| mean | " + " | ".join(f"{p / n:.2f} / {s / n:.3f}" for p, s in total) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
