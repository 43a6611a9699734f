"""The hairfilter network in PyTorch, and its safetensors weights format.

This module is the Python twin of src/hfcore.h: the same variants (the
paper's Table 1), the same wiring, the same tensor names and layouts, so that
a model trained here exports directly to the C backends and vice versa.

    enc{i}: Conv2d(k=3, s=2, p=1) + ReLU,            H/2^i -> H/2^(i+1)
    dec{i}: ConvTranspose2d(k=4, s=2, p=1) (+ ReLU), H/2^(i+1) -> H/2^i
    dec{i} input: enc{L-1} output for i = L-1, else cat(dec{i+1}, enc{i})
    dec0 has 3 outputs and no ReLU but the output transforms.
"""
import json
import math
import os
import struct

import safetensors_header

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

FEATURES = ["color", "highlight", "alpha", "depth", "tangent.x", "tangent.y"]
OUTPUTS = ["color", "highlight", "alpha"]

VARIANTS = {
    "Base":      dict(spp=4, levels=[32, 64, 128]),
    "Base@1spp": dict(spp=1, levels=[32, 64, 128]),
    "Base@2spp": dict(spp=2, levels=[32, 64, 128]),
    "Large":     dict(spp=4, levels=[64, 128, 256]),
    "Small":     dict(spp=4, levels=[16, 32, 64]),
    "Shallow":   dict(spp=4, levels=[32, 64]),
    "Deep":      dict(spp=4, levels=[32, 64, 128, 256]),
    # Beyond the paper: Base's shape, output = per-pixel stochastic
    # transparency estimate + the network's residual.
    "Residual":  dict(spp=4, levels=[32, 64, 128], arch="residual"),
    # Beyond the paper: Base's shape; dec0 predicts a per-pixel kernel over
    # the (2r+1)^2 pixels around each pixel, applied to their samples, plus
    # a small correction (kernel_finish).
    "Kernel":    dict(spp=4, levels=[32, 64, 128], arch="kernel", kernel_radius=3, kernel_hidden=32),
    # Kernel reading stochastic transparency's alpha-corrected estimate as 3
    # more input channels and filtering it instead of the samples' own
    # estimate (estimate_sums; protocol/FEATURES.md).
    "KernelAC":  dict(spp=4, levels=[32, 64, 128], arch="kernel", kernel_radius=3, kernel_hidden=32,
                      estimate="alpha_corrected"),
    # KernelAC whose kernel weighs the samples' own sums too and mixes the
    # two per pixel by one more output (kernel_finish_mixed): the estimate
    # leaks hidden strands' colour where opaque strands overlap.
    "KernelMix": dict(spp=4, levels=[32, 64, 128], arch="kernel", kernel_radius=3, kernel_hidden=32,
                      estimate="alpha_corrected", kernel_mix=1),
}
# beta = sigmoid(KERNEL_MIX_GAIN m) for the mixing output m (src/hfcore.h
# HF_KERNEL_MIX_GAIN): the gain lets Adam, whose steps are about lr in each
# weight whatever the gradient's scale, move beta as far as the logits.
KERNEL_MIX_GAIN = 16.0
ESTIMATE_CHANNELS = ["acst4.color", "acst4.highlight", "acst4.alpha"]   # in EXR files
TABLE1 = ["Base", "Base@1spp", "Base@2spp", "Large", "Small", "Shallow", "Deep"]


def kernel_taps(radius):
    return (2 * radius + 1) ** 2


def variant_config(name):
    """Metadata dict of a Table 1 variant, as stored in the weights file."""
    for key, v in VARIANTS.items():
        if key.lower() == name.lower():
            cfg = dict(name=key, arch=v.get("arch", "unet"), spp=v["spp"],
                       in_channels=v["spp"] * len(FEATURES),
                       levels=list(v["levels"]), out_channels=len(OUTPUTS),
                       features=list(FEATURES))
            if cfg["arch"] == "kernel":
                cfg["kernel_radius"] = v["kernel_radius"]
                cfg["kernel_hidden"] = v.get("kernel_hidden", 0)
                cfg["out_channels"] = kernel_taps(v["kernel_radius"]) + len(OUTPUTS)
                if v.get("kernel_mix"):
                    cfg["kernel_mix"] = 1
                    cfg["out_channels"] += 1
            if v.get("estimate"):
                cfg["estimate"] = v["estimate"]
                cfg["in_channels"] += len(OUTPUTS)
            return cfg
    raise KeyError(f"unknown variant {name!r}; known: {', '.join(VARIANTS)}")


# hfnet's own variant_config: weights/experiments/patching.py replaces the
# module's while an experiment is installed (check_config looks).
_OWN_VARIANT_CONFIG = variant_config


def output_transform(x, clamp=torch.clamp):
    """Per-channel output transforms of the paper (section 3.3.2). clamp:
    torch.clamp, or the straight-through one train.py trains with."""
    color = x[:, 0:1] ** 3 / 32 + x[:, 0:1] / 5 + 1
    highlight = clamp(x[:, 1:2], 0, None)
    alpha = clamp(x[:, 2:3], 0, 1)
    return torch.cat([color, highlight, alpha], dim=1)


RESIDUAL_RADIUS = 2   # HF_RESIDUAL_RADIUS: the base's window is 5x5


def _box_sum(z, r=RESIDUAL_RADIUS):
    """Sum over the (2r+1)^2 window around each pixel, cut to the frame."""
    k = torch.ones(1, 1, 2 * r + 1, 2 * r + 1, dtype=z.dtype, device=z.device)
    n, c, h, w = z.shape
    return F.conv2d(z.reshape(n * c, 1, h, w), k, padding=r).reshape(n, c, h, w)


def residual_base(x, spp, radius=RESIDUAL_RADIUS):
    """Stochastic-transparency estimate over the (2 radius + 1)^2 window
    around each pixel (5x5 by default; radius 0: each pixel's own samples,
    src/net_config.c hf_st_estimate) of NCHW features x (the frame,
    unpadded): covered fraction of the window's samples as alpha, mean
    colour and highlight of the covered ones (colour 1 where none is);
    src/net_config.c hf_residual_base."""
    n, _, h, w = x.shape
    s = x[:, :spp * len(FEATURES)].reshape(n, spp, len(FEATURES), h, w)
    cov = (s[:, :, 2] > 0).to(x.dtype)
    cnt = _box_sum(cov.sum(1, keepdim=True), radius)
    col = _box_sum((s[:, :, 0] * cov).sum(1, keepdim=True), radius)
    hl = _box_sum((s[:, :, 1] * cov).sum(1, keepdim=True), radius)
    samples = _box_sum(x.new_ones(1, 1, h, w), radius) * spp
    safe = torch.clamp(cnt, min=1)
    color = torch.where(cnt > 0, col / safe, torch.ones_like(cnt))
    return torch.cat([color, hl / safe, cnt / samples], dim=1)


def residual_finish(raw, base, clamp=torch.clamp):
    color = base[:, 0:1] + raw[:, 0:1]
    highlight = clamp(base[:, 1:2] + raw[:, 1:2], 0, None)
    alpha = clamp(base[:, 2:3] + raw[:, 2:3], 0, 1)
    return torch.cat([color, highlight, alpha], dim=1)


def pixel_sums(x, spp):
    """Per pixel: covered-sample count n, sum of their colour, sum of their
    highlight, NCHW [n][3][h][w] (the unnormalised stochastic-transparency
    estimate of each pixel)."""
    n, _, h, w = x.shape
    s = x[:, :spp * len(FEATURES)].reshape(n, spp, len(FEATURES), h, w)
    cov = (s[:, :, 2] > 0).to(x.dtype)
    return torch.stack([cov.sum(1), (s[:, :, 0] * cov).sum(1), (s[:, :, 1] * cov).sum(1)], 1)


def estimate_sums(x, spp):
    """pixel_sums' form of the alpha-corrected estimate that follows the spp
    samples in x (channels 6 spp + 0, 1, 2: colour, highlight, alpha): spp
    samples that all show it, n = spp a, then n c and n h
    (src/net_config.c hf_estimate_sums, the products in the same order)."""
    o = spp * len(FEATURES)
    c, h, a = (x[:, o + k:o + k + 1].float() for k in range(3))
    n = spp * a
    return torch.cat([n, n * c, n * h], 1)


def _taps(radius):
    """Offsets (dy, dx) of the taps in row-major order (tap t = (dy + r) *
    (2r + 1) + dx + r), as the C backends number them."""
    return [(dy, dx) for dy in range(-radius, radius + 1) for dx in range(-radius, radius + 1)]


def _shifted(z, radius, dy, dx):
    """z[..., y + dy, x + dx] for every (y, x) of the frame, 0 outside; z is
    zero-padded by radius on each side."""
    h, w = z.shape[-2] - 2 * radius, z.shape[-1] - 2 * radius
    return z[..., radius + dy:radius + dy + h, radius + dx:radius + dx + w]


def kernel_weights(logits, radius):
    """Softmax over the (2r+1)^2 taps of each pixel, taps outside the frame
    left out (the frame is cut, never padded): a list of taps tensors
    [n][h][w]. Computed tap by tap on whole planes (a softmax over dim 1 of
    an NCHW tensor strides through memory and dominates a training step)."""
    n, taps, h, w = logits.shape
    ones = F.pad(logits.new_ones(n, h, w, dtype=torch.float32), (radius,) * 4)
    ls = [l.float() for l in logits.unbind(1)]
    inside = [_shifted(ones, radius, dy, dx) > 0 for dy, dx in _taps(radius)]
    # The maximum over the taps inside the frame (the centre always is), as
    # src/net_config.c: a larger logit outside the frame would otherwise
    # underflow every weight inside it (0 / 0), and an exponent taken
    # outside could overflow (inf * 0).
    low = torch.tensor(float("-inf"), device=logits.device)
    m = None
    for l, i in zip(ls, inside):
        v = torch.where(i, l.detach(), low)
        m = v if m is None else torch.maximum(m, v)
    e = [torch.exp(torch.where(i, l - m, low)) for l, i in zip(ls, inside)]
    den = e[0]
    for et in e[1:]:
        den = den + et
    return [et / den for et in e]


def kernel_finish(raw, x, spp, radius, clamp=torch.clamp, estimate=None):
    """Output stage of the kernel architecture. raw: [n][taps + 3][h][w]
    (kernel logits, then colour, highlight and alpha corrections), x the
    unpadded NCHW features. With w the softmax weights of pixel p's taps q and
    (n_q, C_q, H_q) the sums of pixel_sums (of estimate_sums with estimate
    "alpha_corrected"):
        alpha = sum w n_q / spp,  colour = sum w C_q / sum w n_q (1 if 0),
        highlight = sum w H_q / sum w n_q (0 if 0),
    then the corrections are added and the ranges clamped as Residual's."""
    sums = estimate_sums(x, spp) if estimate else pixel_sums(x, spp)
    return kernel_finish_sums(raw, sums, spp, radius, clamp)


def kernel_finish_sums(raw, sums, spp, radius, clamp=torch.clamp):
    """kernel_finish with the per-pixel sums given: sums [n][3][h][w] as
    pixel_sums lays them out (count, colour sum, highlight sum over spp
    samples); weights/experiments give other estimates in this form."""
    taps = kernel_taps(radius)
    return kernel_normalise(kernel_aggregate(raw[:, :taps], sums, radius), raw[:, taps:taps + 3],
                            spp, clamp)


def kernel_finish_mixed(raw, x, spp, radius, clamp=torch.clamp):
    """Output stage of a kernel that mixes (KernelMix): raw [n][taps + 4][h][w]
    (logits, the three corrections, then the mixing output m), x the samples
    then the estimate (NCHW). Pixel p's kernel weighs both its taps'
    pixel_sums S and estimate_sums E and mixes them at p:
        agg = sum w E + beta (sum w S - sum w E),  beta = sigmoid(KERNEL_MIX_GAIN m_p),
    then kernel_normalise (src/net_config.c kernel_pixel, the same order).
    At the output pixel, not at each tap, so that a pixel's result needs no
    other pixel's raw output."""
    taps = kernel_taps(radius)
    sums = torch.cat([pixel_sums(x, spp), estimate_sums(x, spp)], 1)
    agg = kernel_aggregate(raw[:, :taps], sums, radius)
    return kernel_mix_normalise(agg, raw[:, taps + 3:taps + 4], raw[:, taps:taps + 3], spp,
                                clamp)[0]


def kernel_mix_normalise(agg, m, corr, spp, clamp=torch.clamp):
    """KernelMix's last step: agg [n][6][h][w], the kernel-weighted samples'
    sums then the estimate's (kernel_aggregate of both), mixed by the mixing
    output m [n][1][h][w] and normalised with the corrections corr
    (kernel_normalise). Returns (outputs [n][3][h][w], beta [n][1][h][w])."""
    beta = torch.sigmoid(KERNEL_MIX_GAIN * m.float())
    mixed = agg[:, 3:6] + beta * (agg[:, 0:3] - agg[:, 3:6])
    return kernel_normalise(mixed, corr, spp, clamp), beta


def kernel_aggregate(logits, sums, radius):
    """Each pixel's softmax-weighted sum of its taps' sums: logits
    [n][taps][h][w], sums [n][k][h][w] (any k), result [n][k][h][w]."""
    wts = kernel_weights(logits, radius)
    sums = F.pad(sums, (radius,) * 4)
    agg = 0
    for wt, (dy, dx) in zip(wts, _taps(radius)):
        agg = agg + wt[:, None] * _shifted(sums, radius, dy, dx)
    return agg


def kernel_normalise(agg, corr, spp, clamp=torch.clamp):
    """Colour, highlight and alpha [n][3][h][w] of aggregated sums agg
    [n][3][h][w] (count, colour sum, highlight sum) plus the corrections corr
    [n][3][h][w], clamped as Residual's (kernel_finish)."""
    cnt = agg[:, 0:1]
    ok = cnt > 1e-12
    safe = torch.where(ok, cnt, torch.ones_like(cnt))
    color = torch.where(ok, agg[:, 1:2] / safe, torch.ones_like(cnt))
    hl = torch.where(ok, agg[:, 2:3] / safe, torch.zeros_like(cnt))
    return torch.cat([color + corr[:, 0:1], clamp(hl + corr[:, 1:2], 0, None),
                      clamp(cnt / spp + corr[:, 2:3], 0, 1)], dim=1)


def widen_kernel_hidden(state, hidden, fresh):
    """Kernel weights with kernel_hidden `hidden` (> 0) widened to the shapes of
    fresh (a state_dict of the wider net, randomly initialised), computing the
    same function: the new dec0 channels keep fresh's random weights and the
    head gives them zero weight, so training grows them from there (function-
    preserving widening, Chen, Goodfellow & Shlens, "Net2Net", ICLR 2016)."""
    out = dict(state)
    w, b = fresh["dec0.weight"].clone(), fresh["dec0.bias"].clone()
    w[:, :hidden] = state["dec0.weight"]          # ConvTranspose2d: [cin][cout][k][k]
    b[:hidden] = state["dec0.bias"]
    hw = torch.zeros_like(fresh["head.weight"])   # [out][hidden + in][1][1]
    wide = w.shape[1]
    hw[:, :hidden] = state["head.weight"][:, :hidden]
    hw[:, wide:] = state["head.weight"][:, hidden:]
    out.update({"dec0.weight": w, "dec0.bias": b, "head.weight": hw})
    return out


def grow_kernel_radius(state, old_radius, new_radius, hidden, logit_drop=4.0):
    """Kernel weights of kernel_radius old_radius regrown to new_radius
    (>= old_radius): the head's rows (or dec0's output channels without a
    head) are renumbered from the old taps to the new, and each new tap
    outside the old window gets the row of the old border tap nearest to it
    (offsets clamped to the old radius) with logit_drop taken off its bias,
    so it starts with e^-logit_drop of that tap's weight. The function moves
    by that little (a softmax has no exactly neutral logit) and the new taps
    get gradients from the first step. hidden: kernel_hidden (0: no head).
    Shapes: head [taps + 3][hidden + in_channels][1][1], dec0 without a head
    (ConvTranspose2d) [cin][taps + 3][4][4]. Raises ValueError when
    new_radius < old_radius."""
    if new_radius < old_radius:
        raise ValueError(f"grow_kernel_radius: {old_radius} -> {new_radius}: cannot shrink")
    old_taps, new_taps = _taps(old_radius), _taps(new_radius)
    index = {t: i for i, t in enumerate(old_taps)}
    src = [index[(max(-old_radius, min(old_radius, dy)), max(-old_radius, min(old_radius, dx)))]
           for dy, dx in new_taps]
    inside = [max(abs(dy), abs(dx)) <= old_radius for dy, dx in new_taps]
    ot = len(old_taps)
    rows = src + [ot + k for k in range(len(OUTPUTS))]
    drop = torch.tensor([0.0 if i else logit_drop for i in inside] + [0.0] * len(OUTPUTS))
    out = dict(state)
    if hidden:
        w, b = state["head.weight"], state["head.bias"]
        out["head.weight"] = w[rows].clone()
        out["head.bias"] = b[rows].clone() - drop.to(b.dtype)
    else:
        w, b = state["dec0.weight"], state["dec0.bias"]
        out["dec0.weight"] = w[:, rows].clone()
        out["dec0.bias"] = b[rows].clone() - drop.to(b.dtype)
    return out


def add_kernel_mix(state, hidden, beta0=0.05):
    """KernelAC weights (kernel_hidden `hidden`) with KernelMix's mixing
    output added: zero weights and a bias giving beta = beta0 (0 < beta0 <
    1) everywhere, so the network starts as KernelAC with a twentieth of the
    samples' own sums mixed in (beta0 0.05), and the output's gradient,
    KERNEL_MIX_GAIN beta (1 - beta) times the difference of the two sums, is
    not vanishing. The output is the head's last row, or dec0's last output
    channel without a head."""
    state = dict(state)
    bias = math.log(beta0 / (1 - beta0)) / KERNEL_MIX_GAIN
    key = "head" if hidden else "dec0"
    w, b = state[f"{key}.weight"], state[f"{key}.bias"]
    if hidden:      # Conv2d: [out][in][1][1]
        state["head.weight"] = torch.cat([w, w.new_zeros(1, *w.shape[1:])], 0)
    else:           # ConvTranspose2d: [in][out][k][k]
        state["dec0.weight"] = torch.cat([w, w.new_zeros(w.shape[0], 1, *w.shape[2:])], 1)
    state[f"{key}.bias"] = torch.cat([b, b.new_full((1,), bias)], 0)
    return state


def widen_levels(state, old_levels, fresh):
    """U-Net weights with body widths old_levels widened to the shapes of
    fresh (a state_dict of the same architecture with as many levels, each
    at least as wide, randomly initialised), computing the same function.

    Every layer keeps its old weights in the first rows and columns; the new
    output channels of a layer keep fresh's random weights, and every layer
    that reads a new channel (the next encoder, and the decoder that takes
    it through the skip concatenation [upsampled, encoder]) gives it zero
    weight, so the output is unchanged and training grows the new channels
    from there (Net2Net's function-preserving widening with zero outgoing
    weights: Chen, Goodfellow & Shlens, ICLR 2016). Shapes: Conv2d
    [cout][cin][3][3], ConvTranspose2d [cin][cout][4][4]. Raises ValueError
    when the level counts differ or a level would narrow."""
    L = len(old_levels)
    new_levels = [fresh[f"enc{i}.weight"].shape[0] for i in range(L)]
    if f"enc{L}.weight" in fresh or any(n < o for n, o in zip(new_levels, old_levels)):
        raise ValueError(f"widen_levels: {old_levels} -> {new_levels}: the same number of "
                         f"levels, none narrower, is needed")
    out = dict(state)
    for i in range(L):
        lo, cin_o = old_levels[i], state[f"enc{i}.weight"].shape[1]
        w, b = fresh[f"enc{i}.weight"].clone(), fresh[f"enc{i}.bias"].clone()
        w[:, cin_o:] = 0                                  # new input channels unread
        w[:lo, :cin_o] = state[f"enc{i}.weight"]
        b[:lo] = state[f"enc{i}.bias"]
        out[f"enc{i}.weight"], out[f"enc{i}.bias"] = w, b
    for i in range(L):
        old_w = state[f"dec{i}.weight"]
        cout_o = old_w.shape[1]
        w, b = fresh[f"dec{i}.weight"].clone(), fresh[f"dec{i}.bias"].clone()
        w[:, :cout_o].zero_()                             # new outputs (dec>0) stay random
        lo, ln = old_levels[i], new_levels[i]
        w[:lo, :cout_o] = old_w[:lo]                      # the upsampled path (or, at the
        if i < L - 1:                                     # bottom, the encoder)
            w[ln:ln + lo, :cout_o] = old_w[lo:2 * lo]     # the skip from enc{i}
        b[:cout_o] = state[f"dec{i}.bias"]
        out[f"dec{i}.weight"], out[f"dec{i}.bias"] = w, b
    return out


def equalise_phase_sums_(net):
    """Projects every transposed convolution of net, in place, onto kernels
    whose four output phases have equal tap sums.

    A ConvTranspose2d(k=4, s=2, p=1) computes output pixel 2i+a (a = 0, 1)
    from taps 1 and 3 (a = 0) or 0 and 2 (a = 1) of its kernel in each
    direction, so its [cin][cout][4][4] kernel splits into four 2x2 phase
    kernels. Where they sum to different values, a flat input comes out as
    a pattern of period 2 (period 2^L after L levels): the lattice of
    transposed convolutions (Odena, Dumoulin & Olah, "Deconvolution and
    Checkerboard Artifacts", Distill 2016; Aitken et al., "Checkerboard
    artifact free sub-pixel convolution", arXiv:1707.02937, 2017, make the
    phases equal at initialisation). With equal sums for every (cin, cout)
    pair a spatially constant input gives a constant output through the
    whole U-Net away from the zero-padded borders (its encoders are
    ordinary convolutions, its ReLUs act per pixel), so no lattice can form
    where the input is flat, while each phase keeps its own 2x2 shape (13
    of 16 degrees of freedom). This is the smallest change in the L2 sense:
    each phase's four taps move by the same amount, a quarter of that
    phase's sum minus the mean of the four. Returns the largest change made
    to any tap (0 for a kernel already equalised). The architecture and the
    weights format are unchanged. Called after every training step, so it
    works on whole kernels and reads one number back from the device."""
    moved = []
    with torch.no_grad():
        for m in net.modules():
            if not isinstance(m, nn.ConvTranspose2d):
                continue
            w = m.weight
            if tuple(w.shape[-2:]) != (4, 4) or m.stride != (2, 2) or m.padding != (1, 1):
                raise ValueError(f"equalise_phase_sums_: a ConvTranspose2d of kernel "
                                 f"{tuple(w.shape[-2:])}, stride {m.stride}, padding "
                                 f"{m.padding}; only k=4, s=2, p=1 is the network's")
            # Tap t = 2 j + a: [cin][cout][jy][ay][jx][ax], phase (ay, ax).
            taps = w.view(*w.shape[:2], 2, 2, 2, 2)
            sums = taps.sum((2, 4))                                   # [cin][cout][ay][ax]
            d = (sums - sums.mean((2, 3), keepdim=True)) / 4
            taps -= d[:, :, None, :, None, :]
            moved.append(d.abs().max())
    return float(torch.stack(moved).max()) if moved else 0.0


class HairNet(nn.Module):
    def __init__(self, cfg):
        super().__init__()
        self.cfg = dict(cfg)
        self.arch = cfg.get("arch", "unet")
        if self.arch not in ("unet", "residual", "kernel"):
            raise ValueError(f"unknown arch {self.arch!r}")
        lv = cfg["levels"]
        L = len(lv)
        self.levels = L
        for i in range(L):
            cin = cfg["in_channels"] if i == 0 else lv[i - 1]
            self.add_module(f"enc{i}", nn.Conv2d(cin, lv[i], 3, stride=2, padding=1))
        # kernel_hidden > 0: dec0 gives that many channels (ReLU) and a 1x1
        # convolution "head" over them and the input features gives the
        # output channels, so every pixel's kernel also sees its own samples.
        self.hidden = cfg.get("kernel_hidden", 0) if self.arch == "kernel" else 0
        for i in range(L):
            cin = lv[i] if i == L - 1 else 2 * lv[i]
            cout = (self.hidden or cfg["out_channels"]) if i == 0 else lv[i - 1]
            self.add_module(f"dec{i}", nn.ConvTranspose2d(cin, cout, 4, stride=2, padding=1))
        if self.hidden:
            self.head = nn.Conv2d(self.hidden + cfg["in_channels"], cfg["out_channels"], 1)

    @property
    def align(self):
        return 1 << self.levels

    def raw(self, x):
        """The network without output transforms; x is NCHW, sides multiples
        of 2^L."""
        return self.apply_head(self.decoded(x), x)

    def decoded(self, x):
        """dec0's output (before the head, if any) of NCHW x, sides multiples
        of 2^L."""
        enc = []
        for i in range(self.levels):
            x = F.relu(getattr(self, f"enc{i}")(x))
            enc.append(x)
        y = enc[-1]
        for i in reversed(range(self.levels)):
            if i < self.levels - 1:
                y = torch.cat([y, enc[i]], dim=1)
            y = getattr(self, f"dec{i}")(y)
            if i > 0:
                y = F.relu(y)
        return y

    def head_input(self, y, inp):
        """What the kernel architecture's 1x1 head reads: ReLU(dec0's output
        y) and the input features inp, [n][kernel_hidden + in_channels][h][w]."""
        return torch.cat([F.relu(y), inp.to(y.dtype)], dim=1)

    def apply_head(self, y, inp):
        """The kernel architecture's 1x1 head on ReLU(dec0) and the input."""
        if not self.hidden:
            return y
        return self.head(self.head_input(y, inp))

    def forward(self, x):
        """NCHW input of any size: zero-padded right/bottom to a multiple of
        2^L, output cropped back, output transforms applied."""
        return self.finish(self.raw_any_size(x), x)

    def raw_any_size(self, x):
        """raw() of NCHW input of any size: zero-padded right/bottom to a
        multiple of 2^L, cropped back to x's size."""
        h, w = x.shape[-2:]
        a = self.align
        ph, pw = (-h) % a, (-w) % a
        return self.raw(F.pad(x, (0, pw, 0, ph)) if ph or pw else x)[..., :h, :w]

    def finish(self, raw, x, clamp=torch.clamp):
        """The architecture's output stage on raw output raw of the unpadded
        input x (same size)."""
        if self.arch == "residual":
            return residual_finish(raw, residual_base(x, self.cfg["spp"]), clamp)
        if self.arch == "kernel":
            if self.cfg.get("kernel_mix"):
                return kernel_finish_mixed(raw, x, self.cfg["spp"], self.cfg["kernel_radius"],
                                           clamp)
            if self.cfg.get("estimate"):
                return kernel_finish(raw, x, self.cfg["spp"], self.cfg["kernel_radius"], clamp,
                                     self.cfg["estimate"])
            return kernel_finish(raw, x, self.cfg["spp"], self.cfg["kernel_radius"], clamp)
        return output_transform(raw, clamp)


# ---- safetensors ----------------------------------------------------------

_DTYPES = {"F32": (np.float32, 4), "F16": (np.float16, 2)}


def save_safetensors(path, cfg, state_dict, dtype="F32", metadata=None):
    """Writes state_dict with the hairfilter metadata (weights/FORMAT.md);
    metadata: more string entries, e.g. {"input_range": json_text}.

    Whole or not at all, as train.py's checkpoint and stamp_range.py's
    stamp: written beside path and renamed onto it, so a run stopped
    mid-export leaves the previous file as it was, and a reader of path (a
    server reloading it) never meets half a file."""
    np_dtype, size = _DTYPES[dtype]
    header = {"__metadata__": {"hairfilter": json.dumps(cfg), **(metadata or {})}}
    blobs, off = [], 0
    for name, t in state_dict.items():
        a = t.detach().cpu().numpy().astype(np_dtype)
        b = a.tobytes()
        header[name] = {"dtype": dtype, "shape": list(a.shape),
                        "data_offsets": [off, off + len(b)]}
        blobs.append(b)
        off += len(b)
    h = json.dumps(header, separators=(",", ":")).encode()
    h += b" " * ((-len(h)) % 8)
    tmp = path + ".tmp"
    f = open(tmp, "wb")
    try:
        with f:
            f.write(struct.pack("<Q", len(h)))
            f.write(h)
            for b in blobs:
                f.write(b)
        os.replace(tmp, path)
    except BaseException:
        # Nothing half-written left behind (a full disk, an interrupt).
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def load_metadata(path):
    """The header's __metadata__ map (strings) of a safetensors file, checked
    as safetensors_header.read_header checks it."""
    return safetensors_header.read_header(path)[0].get("__metadata__", {})


def load_safetensors(path):
    """Returns (cfg, state_dict of float32 tensors)."""
    header, data, base = safetensors_header.read_header(path)
    if "hairfilter" not in header.get("__metadata__", {}):
        raise ValueError(f"{path}: no '__metadata__.hairfilter' entry")
    meta = header.pop("__metadata__")
    safetensors_header.check_text(path, "metadata 'hairfilter'", meta["hairfilter"])
    try:
        cfg = safetensors_header.loads(meta["hairfilter"])
    except (ValueError, RecursionError) as e:   # RecursionError: nested thousands deep
        raise ValueError(f"{path}: metadata 'hairfilter': {e}") from None
    # Checked as the C loader checks it, though only hairfilterd and the
    # CLI read it: one JSON object, nothing after it.
    if "input_range" in meta:
        safetensors_header.check_text(path, "metadata 'input_range'", meta["input_range"])
        try:
            rng = safetensors_header.loads(meta["input_range"])
        except (ValueError, RecursionError) as e:
            raise ValueError(f"{path}: metadata 'input_range': {e}") from None
        if not isinstance(rng, dict):
            raise ValueError(f"{path}: metadata 'input_range' is not a JSON object")
    check_config(path, cfg)
    if "input_range" in meta:
        check_input_range(path, rng, cfg["spp"])
    # The tensors the configuration makes, as the C loader checks them: a
    # file with one missing, extra or of another shape was accepted here
    # and failed later in load_state_dict (or not at all).
    want = {k: tuple(v.shape) for k, v in HairNet(cfg).state_dict().items()}
    missing = [k for k in want if k not in header]
    extra = [k for k in header if k not in want]
    if missing or extra:
        raise ValueError(f"{path}: file has {len(header)} tensors, the configuration needs "
                         f"{len(want)}" + (f"; missing {', '.join(missing)}" if missing else "")
                         + (f"; not of this network: {', '.join(extra)}" if extra else ""))
    sd = {}
    for name, t in header.items():
        if not isinstance(t, dict) or not isinstance(t.get("dtype"), str) or \
                t["dtype"] not in _DTYPES:
            raise ValueError(f"{path}: tensor '{name}': dtype "
                             f"{t.get('dtype') if isinstance(t, dict) else t!r} is not F32 or F16")
        np_dtype, size = _DTYPES[t["dtype"]]
        if not isinstance(t.get("shape"), list):
            raise ValueError(f"{path}: tensor '{name}': shape {t.get('shape')!r} is not a list "
                             f"of integers; the configuration needs {list(want[name])}")
        shape = tuple(t["shape"])
        if shape != want[name]:
            raise ValueError(f"{path}: tensor '{name}': shape {list(shape)}, the configuration "
                             f"needs {list(want[name])}")
        offs = t.get("data_offsets")
        if not isinstance(offs, list) or len(offs) != 2 or any(type(o) is not int for o in offs):
            raise ValueError(f"{path}: tensor '{name}': data_offsets {offs!r} are not two "
                             "integers [begin, end)")
        b, e = offs
        if e - b != int(np.prod(shape)) * size:
            raise ValueError(f"{path}: tensor '{name}': data_offsets [{b}, {e}) hold {e - b} "
                             f"bytes, its shape and dtype need {int(np.prod(shape)) * size}")
        a = np.frombuffer(data[base + b:base + e], dtype=np_dtype).reshape(shape)
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            raise ValueError(f"{path}: tensor '{name}': value {int(bad[0])} of {a.size} is not "
                             "finite (NaN or infinite): the weights are damaged (a training run "
                             "that diverged?); export them again from a good checkpoint")
        sd[name] = torch.from_numpy(a.astype(np.float32))
    return cfg, sd


def check_input_range(path, rng, spp):
    """The 'input_range' metadata as src/input_range.c checks it (one-line
    ValueError in its words): a 'definition' number, and for this
    definition the variant's spp, a count of frames and finite [low, high]
    ranges, at least one. A range of another definition is left unused."""
    import input_stats

    def bad(what):
        raise ValueError(f"{path}: metadata: input_range: {what}")

    def number(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool)

    if not number(rng.get("definition")):
        bad("no 'definition' number")
    if rng["definition"] != input_stats.DEFINITION:
        return
    if not number(rng.get("spp")) or rng["spp"] != spp:
        bad(f"'spp' must be the variant's {spp}")
    f = rng.get("frames")
    if not number(f) or not 1 <= f <= 1e9 or f != int(f):
        bad("'frames' must be a count >= 1")
    seen = 0
    for k in input_stats.STATS:
        if k not in rng:
            continue
        r = rng[k]
        if not isinstance(r, list) or len(r) != 2 or not all(number(v) for v in r) or \
                not all(math.isfinite(v) for v in r) or r[0] > r[1]:
            bad(f"'{k}' must be [low, high] with low <= high")
        seen += 1
    if not seen:
        bad("no statistic has a range")


def check_config(path, cfg):
    """The 'hairfilter' metadata as src/weights_load.c checks it (one-line
    ValueError naming the field): the features, the inputs that spp and
    the estimate make, levels, the architecture and its output channels."""
    def bad(what):
        raise ValueError(f"{path}: metadata: {what}")

    def count(v, lo, hi):
        return isinstance(v, int) and not isinstance(v, bool) and lo <= v <= hi

    if not isinstance(cfg, dict):
        bad("'hairfilter' is not a JSON object")
    # The C loader's bound (HF_NAME_MAX - 1 bytes, src/hfcore.h): a longer
    # name was taken here, by train.py --init, and refused by hairfilterd.
    if not isinstance(cfg.get("name"), str) or not cfg["name"] or \
            len(cfg["name"].encode()) > 63:
        bad("'name' missing or longer than 63 bytes")
    arch = cfg.get("arch", "unet")
    if arch not in ("unet", "residual", "kernel"):
        bad(f"unsupported 'arch' {arch!r} (want unet, residual or kernel)")
    if cfg.get("features") != FEATURES:
        bad(f"'features' is {cfg.get('features')!r}, not {FEATURES}")
    if not count(cfg.get("spp"), 1, 16):
        bad("'spp' missing or not a count in 1..16")
    est = cfg.get("estimate", "none")
    if est not in ("none", "alpha_corrected") or (est != "none" and arch != "kernel"):
        bad(f"'estimate' {est!r}: none, or alpha_corrected on arch kernel")
    cin = cfg["spp"] * len(FEATURES) + (len(OUTPUTS) if est == "alpha_corrected" else 0)
    if cfg.get("in_channels") != cin:
        bad(f"in_channels {cfg.get('in_channels')!r}, but spp {cfg['spp']} x "
            f"{len(FEATURES)} features{' and the estimate' if cin % len(FEATURES) else ''} "
            f"make {cin}")
    lv = cfg.get("levels")
    if not isinstance(lv, list) or not 1 <= len(lv) <= 8 or not all(count(c, 1, 4096) for c in lv):
        bad("'levels' must be a list of 1..8 channel counts in 1..4096")
    kernel_keys = [k for k in ("kernel_radius", "kernel_hidden", "kernel_mix") if k in cfg]
    if arch == "kernel":
        if not count(cfg.get("kernel_radius"), 1, 4):
            bad("'kernel_radius' missing or not an integer in 1..4 (arch kernel)")
        if not count(cfg.get("kernel_hidden", 0), 0, 64):
            bad("'kernel_hidden' not an integer in 0..64")
        if not count(cfg.get("kernel_mix", 0), 0, 1):
            bad("'kernel_mix' is not 0 or 1")
        if cfg.get("kernel_mix") and est == "none":
            bad("'kernel_mix' 1 mixes the samples' sums with the estimate's: it needs "
                "'estimate' \"alpha_corrected\"")
        out = kernel_taps(cfg["kernel_radius"]) + len(OUTPUTS) + cfg.get("kernel_mix", 0)
    else:
        if kernel_keys:
            bad(f"'{kernel_keys[0]}' is for arch kernel only, not {arch}")
        out = len(OUTPUTS)
    # An experiment installed (weights/experiments/patching.py) builds Kernel
    # networks of other outputs (aniso_kernel: taps + 4, kernel_stages:
    # 2 taps + 3), and its init and train commands load such files: their
    # tensors are still checked against the network the file makes.
    experiment = variant_config is not _OWN_VARIANT_CONFIG
    if cfg.get("out_channels") != out and not (experiment and arch == "kernel"
                                               and count(cfg.get("out_channels"), 1, 4096)):
        bad(f"out_channels {cfg.get('out_channels')!r}, but arch {arch} makes {out}")


def load_model(path):
    cfg, sd = load_safetensors(path)
    net = HairNet(cfg)
    net.load_state_dict(sd)
    return net


def bundled(name):
    """The path of a bundled weights file (weights/NAME), for a script's
    default --weights."""
    return os.path.join(os.path.dirname(os.path.abspath(__file__)), name)


def load_model_or_exit(path, prog):
    """load_model(path), or the script prog exits with one line naming the
    file and why it cannot be read (missing, unreadable, not safetensors,
    not hairfilter's), instead of a traceback."""
    try:
        return load_model(path)
    except (OSError, ValueError) as e:
        raise SystemExit(f"{prog}: --weights {path}: "
                         f"{e.strerror if isinstance(e, OSError) and e.strerror else e}")


# ---- layouts --------------------------------------------------------------

def nhwc_to_nchw(a):
    return torch.from_numpy(np.ascontiguousarray(a)).permute(0, 3, 1, 2).contiguous()


def nchw_to_nhwc(t):
    return t.permute(0, 2, 3, 1).contiguous().numpy()
