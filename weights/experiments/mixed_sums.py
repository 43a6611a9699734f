"""KernelAC whose kernel filters, per pixel, a mix of the samples' own sums and
the alpha-corrected estimate's, measured against KernelAC and not part of any
backend (weights/kernel_ac.md says what it scored).

On opaque strands a pixel wide and more the alpha-corrected estimate's colour
is below the samples' plain mean on about half the frames (weights/kernel_ac.md,
"Where the estimate is below the samples' own mean"): it weighs each
fragment's colour by its visibility over the whole pixel, so a hidden
strand's colour leaks into the visible one's. KernelAC filters the estimate
only; Kernel filters the samples only and is ahead on those frames, behind
on the others. This stage gives the head one more output, m per pixel, and
has pixel p's kernel weigh both its taps' sums (count, colour sum,
highlight sum; hfnet.pixel_sums' form) and mix the two at p:

  agg_p = beta_p sum_q w_pq samples_q + (1 - beta_p) sum_q w_pq estimate_q,
  beta_p = sigmoid(GAIN m_p)

then colour, highlight and alpha of agg_p as Kernel's (hfnet.kernel_normalise).
Both are sums over spp samples, so the mix is one too. The mix is at the
output pixel, not at each tap, so that a pixel's result needs no other
pixel's raw output (a backend's per-pixel finish stays one). GAIN lets Adam
move beta over a fine-tune (its steps are about lr in each weight whatever
the gradient's scale).

Weights start from KernelAC weights with m's head row at zero and its bias
at logit(BETA0) / GAIN (start_from_kernel; BETA0 = 0.05: KernelAC but for a
twentieth of the samples' sums). Usage, from the repository root:

  python3 weights/experiments/mixed_sums.py init OUT.safetensors [KERNEL_AC.safetensors]
  python3 weights/experiments/mixed_sums.py train <weights/train.py arguments>

`train` runs weights/train.py with the stage installed (--variant KernelAC,
--init the file of `init`); weights/experiments/eval_rows.py --stage mixed
scores the result with `hairfilter eval`. The C backends refuse these files
(their out_channels do not match the kernel's taps)."""
import math
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import torch  # noqa: E402

import hfnet  # noqa: E402
import patching  # noqa: E402

GAIN = 16.0
BETA0 = 0.05

_kernel_finish = patching.ORIGINAL["kernel_finish"]


def mixed_finish(raw, x, spp, radius, clamp=torch.clamp):
    """The stage on raw [n][taps + 4][h][w] (hfnet.kernel_finish's
    conventions, m's raw output last) and x, the samples then the estimate
    (NCHW, as KernelAC reads them)."""
    taps = hfnet.kernel_taps(radius)
    sums = torch.cat([hfnet.pixel_sums(x, spp), hfnet.estimate_sums(x, spp)], 1)
    agg = hfnet.kernel_aggregate(raw[:, :taps], sums, radius)
    beta = torch.sigmoid(GAIN * raw[:, taps + 3:taps + 4].float())
    mixed = agg[:, 3:6] + beta * (agg[:, 0:3] - agg[:, 3:6])
    return hfnet.kernel_normalise(mixed, raw[:, taps:taps + 3], spp, clamp)


def install():
    """Makes hfnet build and finish Kernel networks with the stage (weights
    with taps + 4 outputs); weights with taps + 3 keep theirs."""
    def finish(raw, x, spp, radius, clamp=torch.clamp, estimate=None):
        if raw.shape[1] == hfnet.kernel_taps(radius) + 3:
            return _kernel_finish(raw, x, spp, radius, clamp, estimate)
        if not estimate:
            raise ValueError("mixed_sums: the stage needs a network with the estimate (KernelAC)")
        return mixed_finish(raw, x, spp, radius, clamp)

    patching.install(lambda cfg: {"out_channels": hfnet.kernel_taps(cfg["kernel_radius"]) + 4},
                     kernel_finish=finish)


uninstall = patching.uninstall


def start_from_kernel(cfg, state, beta0=BETA0):
    """(cfg, state) of KernelAC weights with m's output added: head row zero,
    bias giving beta = beta0 (0 < beta0 < 1) everywhere."""
    if not cfg.get("estimate"):
        raise ValueError("mixed_sums: start from KernelAC weights (a Kernel with the estimate)")
    w, b = state["head.weight"], state["head.bias"]
    state = dict(state)
    state["head.weight"] = torch.cat([w, w.new_zeros(1, *w.shape[1:])], 0)
    state["head.bias"] = torch.cat([b, b.new_full((1,), math.log(beta0 / (1 - beta0)) / GAIN)], 0)
    return dict(cfg, out_channels=cfg["out_channels"] + 1), state


def main(argv):
    if len(argv) < 2 or argv[0] not in ("init", "train"):
        sys.exit(__doc__)
    install()
    if argv[0] == "init" and len(argv) == 2:
        argv = argv + [os.path.join(os.path.dirname(os.path.abspath(__file__)), "..",
                                    "kernel_ac.safetensors")]
    return patching.init_or_train(argv[0], argv[1:], start_from_kernel)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
