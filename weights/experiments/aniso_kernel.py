"""Kernel weights stretched along the strand, measured against the Kernel and
not part of any backend (weights/kernel.md says what it scored).

On dense hair, where it is below 16 samples, the Kernel's result is a
blur with no direction (weights/kernel.md): the network can, but does not, give its
kernel a support along the strand. This stage gives the head one more
output, kappa >= 0 per pixel, and subtracts from the logit of every tap
kappa times the tap's squared distance from the strand through the pixel:

  logit_t -= kappa * (|d|^2 - (dx^2 A + 2 dx dy B + dy^2 C))

for the tap's offset d = (dx, dy) in pixels (x right, y down), with (A, B,
C) the orientation tensor of the pixel's covered samples: the means of ux^2,
ux uy and uy^2 over them, each weighted by the square of its tangent's
length on screen, u = (tangent.x, -tangent.y) (protocol/FEATURES.md: view
space has y up, image rows go down). For samples along one direction the
bracket is the tap's squared distance from the line through the pixel
along it; for samples in every direction it is half of |d|^2, so kappa then
narrows the kernel evenly; a pixel without covered samples gets |d|^2. The
idea is the tangent-guided reconstruction of seed 004 and the strand-
following filters of Huang et al. (Computer Graphics Forum 2025). kappa =
softplus(GAIN x raw): GAIN lets Adam move it over a fine-tune (its steps
are about lr in each weight whatever the gradient's scale).

Weights start from Kernel weights with kappa's head row at zero and its
bias at softplus^-1(kappa0) / GAIN (start_from_kernel; kappa0 = 0.0067, a
shift of at most 0.12 in a logit at radius 3). Usage, from the repository
root:

  python3 weights/experiments/aniso_kernel.py init OUT.safetensors [KERNEL.safetensors]
  python3 weights/experiments/aniso_kernel.py train <weights/train.py arguments>
  python3 weights/experiments/aniso_kernel.py probe KERNEL.safetensors KAPPAS FRAME.exr...

`probe` runs plain Kernel weights with the stage at each fixed kappa of
KAPPAS (comma-separated, 0: the Kernel itself) and prints, per frame, the
PSNR and SSIM of the composite (train.EVAL_LOOK) against the truth's on
the pixels with hair in the truth or a covered sample (SSIM: train.ssim_map,
windows inside the frame; not `hairfilter eval`'s figures: compare
within a row).

`train` runs weights/train.py with the stage installed (--variant Kernel,
--init the file of `init`); weights/experiments/eval_rows.py --stage aniso
scores the result with `hairfilter eval`. The C backends refuse these files
(their out_channels do not match the kernel's taps)."""
import math
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import torch  # noqa: E402
import torch.nn.functional as F  # noqa: E402

import hfnet  # noqa: E402
import patching  # noqa: E402

GAIN = 16.0
KAPPA0 = math.log1p(math.exp(-5.0))      # softplus(-5)

_kernel_finish = patching.ORIGINAL["kernel_finish"]


def orientation(x, spp):
    """(A, B, C) planes [n][h][w] of the covered samples' screen tangents
    u = (tangent.x, -tangent.y): sums of ux^2, ux uy, uy^2 over the samples
    divided by the sum of |u|^2 (zero where it is zero)."""
    n, _, h, w = x.shape
    s = x.view(n, spp, len(hfnet.FEATURES), h, w).float()
    cov = (s[:, :, 2] > 0).float()
    ux, uy = s[:, :, 4] * cov, -s[:, :, 5] * cov
    a, b, c = (ux * ux).sum(1), (ux * uy).sum(1), (uy * uy).sum(1)
    tot = a + c
    ok = tot > 1e-12
    safe = torch.where(ok, tot, torch.ones_like(tot))
    return [torch.where(ok, v / safe, torch.zeros_like(v)) for v in (a, b, c)]


def aniso_logits(raw, x, spp, radius):
    """The taps' logits of raw [n][taps + 4][h][w] with kappa's penalty,
    [n][taps][h][w] (whole-tensor operations: a slice of raw per tap would
    cost a raw-sized gradient per tap in the backward pass)."""
    taps = hfnet.kernel_taps(radius)
    kappa = F.softplus(GAIN * raw[:, taps + 3:taps + 4].float())
    a, b, c = (v[:, None] for v in orientation(x, spp))
    d = torch.tensor(hfnet._taps(radius), dtype=torch.float32, device=raw.device)
    dy, dx = (v.view(1, taps, 1, 1) for v in d.unbind(1))
    off = dx * dx + dy * dy - (dx * dx * a + 2 * dx * dy * b + dy * dy * c)
    return raw[:, :taps].float() - kappa * off


def aniso_finish(raw, x, spp, radius, clamp=torch.clamp):
    """The stage on raw [n][taps + 4][h][w] (hfnet.kernel_finish's
    conventions, kappa's raw output last)."""
    taps = hfnet.kernel_taps(radius)
    logits = aniso_logits(raw, x, spp, radius)
    return _kernel_finish(torch.cat([logits, raw[:, taps:taps + 3].float()], 1), x, spp, radius,
                          clamp)


def install():
    """Makes hfnet build and finish Kernel networks with the stage (weights
    with taps + 4 outputs); plain Kernel weights keep theirs."""
    def finish(raw, x, spp, radius, clamp=torch.clamp):
        if raw.shape[1] == hfnet.kernel_taps(radius) + 3:
            return _kernel_finish(raw, x, spp, radius, clamp)
        return aniso_finish(raw, x, spp, radius, clamp)

    patching.install(lambda cfg: {"out_channels": hfnet.kernel_taps(cfg["kernel_radius"]) + 4},
                     kernel_finish=finish)


uninstall = patching.uninstall


def start_from_kernel(cfg, state, kappa0=KAPPA0):
    """(cfg, state) of Kernel weights with kappa's output added: head row
    zero, bias giving kappa = kappa0 (> 0) everywhere."""
    w, b = state["head.weight"], state["head.bias"]
    state = dict(state)
    state["head.weight"] = torch.cat([w, w.new_zeros(1, *w.shape[1:])], 0)
    bias = math.log(math.expm1(kappa0)) / GAIN            # softplus^-1(kappa0) / GAIN
    state["head.bias"] = torch.cat([b, b.new_full((1,), bias)], 0)
    return dict(cfg, out_channels=cfg["out_channels"] + 1), state


def probe(weights, kappas, frames):
    """Prints the probe's table (see the module's docstring)."""
    import probe_frames
    net = hfnet.load_model(weights).eval()
    taps = hfnet.kernel_taps(net.cfg["kernel_radius"])
    print("| frame | " + " | ".join(f"kappa {k:g}" for k in kappas) + " |")
    print("|---|" + "---:|" * len(kappas))
    for path in frames:
        x, truth, hair, name = probe_frames.load(path, net.cfg["spp"])
        h, w = hair.shape
        with torch.no_grad():
            raw = net.raw_any_size(x)
        cells = []
        for k in kappas:
            with torch.no_grad():
                if k > 0:
                    kr = torch.full((1, 1, h, w), math.log(math.expm1(k)) / GAIN)
                    y = aniso_finish(torch.cat([raw, kr], 1), x, net.cfg["spp"], net.cfg["kernel_radius"])
                else:
                    y = _kernel_finish(raw[:, :taps + 3], x, net.cfg["spp"], net.cfg["kernel_radius"])
            psnr, ssim = probe_frames.score(y[0].numpy(), truth, hair)
            cells.append(f"{psnr:.2f} / {ssim:.3f}")
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)


def main(argv):
    if len(argv) < 2 or argv[0] not in ("init", "train", "probe"):
        sys.exit(__doc__)
    if argv[0] == "probe":
        if len(argv) < 4:
            sys.exit(__doc__)
        torch.set_num_threads(1)
        probe(argv[1], [float(k) for k in argv[2].split(",")], argv[3:])
        return 0
    install()
    return patching.init_or_train(argv[0], argv[1:], start_from_kernel)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
