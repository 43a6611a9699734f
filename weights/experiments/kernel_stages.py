"""Two output stages for the Kernel architecture, measured against it and not
part of any backend (weights/kernel.md says what each scored). Each gives the
head 49 more outputs, a second softmax over the same taps:

  split       the first kernel reads alpha (N / spp), the second colour and
              highlight (C / N, H / N);
  frontback   a covered sample is "front" when it shows its pixel's nearest
              fragment (the colour, highlight and alpha of the covered sample
              of least depth); the first kernel reads alpha and the front
              samples' share, colour and highlight, the second the colour and
              highlight of the other samples.

Weights start from Kernel weights with the second set of logits a copy of the
first, which computes the same function (start_from_kernel). Usage, from the
repository root:

  python3 weights/experiments/kernel_stages.py init STAGE OUT.safetensors [KERNEL.safetensors]
  python3 weights/experiments/kernel_stages.py train STAGE <weights/train.py arguments>

`train` runs weights/train.py with the stage installed (--variant Kernel,
--init the file of `init`); weights/experiments/eval_rows.py scores the
result with `hairfilter eval`. The C backends refuse these files (their
out_channels do not match the kernel's taps)."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import torch  # noqa: E402
import torch.nn.functional as F  # noqa: E402

import hfnet  # noqa: E402
import patching  # noqa: E402

STAGES = ("split", "frontback")
# Weight of the front samples' colour where no back sample lies under the
# second kernel: the back colour falls back to the front one.
EPS = 1e-6

_kernel_finish = patching.ORIGINAL["kernel_finish"]


def front_back_sums(x, spp):
    """NCHW [n][6][h][w] from features x [n][spp*6][h][w]: count, colour sum
    and highlight sum of the covered samples, then of the front ones."""
    n, _, h, w = x.shape
    s = x.view(n, spp, len(hfnet.FEATURES), h, w).float()
    cov = s[:, :, 2] > 0
    depth = torch.where(cov, s[:, :, 3], torch.full_like(s[:, :, 3], float("inf")))
    near = depth.argmin(1, keepdim=True)
    ref = torch.gather(s[:, :, :3], 1, near[:, :, None].expand(n, 1, 3, h, w))
    front = cov & (s[:, :, :3] == ref).all(2)
    c, f = cov.float(), front.float()
    return torch.stack([c.sum(1), (s[:, :, 0] * c).sum(1), (s[:, :, 1] * c).sum(1),
                        f.sum(1), (s[:, :, 0] * f).sum(1), (s[:, :, 1] * f).sum(1)], 1)


def _two_kernels(raw, radius, a_planes, b_planes):
    """sum over taps of w1 * a_planes and of w2 * b_planes (both NCHW,
    unpadded), w1 and w2 the softmax of raw's first and second taps logits."""
    taps, n = hfnet.kernel_taps(radius), raw.shape[0]
    w = hfnet.kernel_weights(torch.cat([raw[:, :taps], raw[:, taps:2 * taps]], 0), radius)
    a_planes, b_planes = F.pad(a_planes, (radius,) * 4), F.pad(b_planes, (radius,) * 4)
    a, b = 0, 0
    for wt, (dy, dx) in zip(w, hfnet._taps(radius)):
        a = a + wt[:n, None] * hfnet._shifted(a_planes, radius, dy, dx)
        b = b + wt[n:, None] * hfnet._shifted(b_planes, radius, dy, dx)
    return a, b


def _finish(colour, highlight, cnt, raw, spp, taps, clamp):
    corr = raw[:, 2 * taps:2 * taps + 3]
    return torch.cat([colour + corr[:, 0:1], clamp(highlight + corr[:, 1:2], 0, None),
                      clamp(cnt / spp + corr[:, 2:3], 0, 1)], dim=1)


def split_finish(raw, x, spp, radius, clamp=torch.clamp):
    """The split stage on raw [n][2 taps + 3][h][w] (hfnet.kernel_finish's
    conventions)."""
    taps = hfnet.kernel_taps(radius)
    sums = hfnet.pixel_sums(x, spp)
    a, b = _two_kernels(raw, radius, sums[:, 0:1], sums)
    cnt = b[:, 0:1]
    ok = cnt > 1e-12
    safe = torch.where(ok, cnt, torch.ones_like(cnt))
    colour = torch.where(ok, b[:, 1:2] / safe, torch.ones_like(cnt))
    highlight = torch.where(ok, b[:, 2:3] / safe, torch.zeros_like(cnt))
    return _finish(colour, highlight, a, raw, spp, taps, clamp)


def frontback_finish(raw, x, spp, radius, clamp=torch.clamp):
    """The frontback stage on raw [n][2 taps + 3][h][w]."""
    taps = hfnet.kernel_taps(radius)
    sums = front_back_sums(x, spp)
    a, b = _two_kernels(raw, radius, sums, sums[:, 0:3] - sums[:, 3:6])
    cnt, nf = a[:, 0:1], a[:, 3:4]
    ok = cnt > 1e-12
    safe = torch.where(ok, cnt, torch.ones_like(cnt))
    nfs = torch.where(nf > 1e-12, nf, torch.ones_like(nf))
    out = []
    for k, empty in ((1, 1.0), (2, 0.0)):
        front = a[:, 3 + k:4 + k]
        back = (b[:, k:k + 1] + EPS * front / nfs) / (b[:, 0:1] + EPS)
        v = front / safe + (1 - nf / safe) * back
        out.append(torch.where(ok, v, torch.full_like(cnt, empty)))
    return _finish(out[0], out[1], cnt, raw, spp, taps, clamp)


def install(stage):
    """Makes hfnet build and finish Kernel networks with the given stage
    (weights with 2 taps + 3 outputs); plain Kernel weights keep theirs."""
    if stage not in STAGES:
        raise ValueError(f"unknown stage {stage!r}; known: {', '.join(STAGES)}")
    stage_finish = split_finish if stage == "split" else frontback_finish

    def finish(raw, x, spp, radius, clamp=torch.clamp):
        if raw.shape[1] == hfnet.kernel_taps(radius) + 3:
            return _kernel_finish(raw, x, spp, radius, clamp)
        return stage_finish(raw, x, spp, radius, clamp)

    patching.install(lambda cfg: {"out_channels": 2 * hfnet.kernel_taps(cfg["kernel_radius"]) + 3},
                     kernel_finish=finish)


uninstall = patching.uninstall


def start_from_kernel(cfg, state):
    """(cfg, state) of Kernel weights widened to two sets of logits, the
    second a copy of the first: the same function under either stage."""
    taps = hfnet.kernel_taps(cfg["kernel_radius"])
    w, b = state["head.weight"], state["head.bias"]
    state = dict(state)
    state["head.weight"] = torch.cat([w[:taps], w[:taps], w[taps:]], 0)
    state["head.bias"] = torch.cat([b[:taps], b[:taps], b[taps:]], 0)
    return dict(cfg, out_channels=2 * taps + 3), state


def main(argv):
    if len(argv) < 3 or argv[0] not in ("init", "train"):
        sys.exit(__doc__)
    stage = argv[1]
    install(stage)
    return patching.init_or_train(argv[0], argv[2:], start_from_kernel)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
