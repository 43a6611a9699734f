#!/usr/bin/python3
"""Trains a hairfilter variant on a dataset directory and exports its weights.

    /usr/bin/python3 weights/train.py --data DATASET --variant Base \
        --out runs/base --steps 20000 --export weights/base.safetensors
    /usr/bin/python3 weights/train.py --out runs/base --resume --steps 40000 \
        --export weights/base.safetensors

DATASET is a directory written by `hairfilter render dataset` or
weights/synth_dataset.py (format: weights/dataset.py). Frames of the styles
given by --styles are used; 10% of them (chosen by a hash of the file name,
so the split never changes) are held out for validation.

Recipe (Currius, Assarsson & Sintorn 2022, section 3.3): random crops with
flips, 90-degree rotations (tangents rotated with the image) and sample-slot
permutation; loss = MSE of the alpha-premultiplied outputs (color*alpha,
highlight*alpha, alpha) + grad_weight * MSE of their finite differences in x
and y; Adam. Everything random derives from --seed, and the checkpoint
(RUN/checkpoint.pt: model, optimizer, step, every RNG state) lets a run stop
and resume with the same result as an uninterrupted one.

--device auto trains on CUDA when PyTorch sees a GPU (bf16 autocast and the
same conv + pixel-shuffle form there), else on the CPU; a checkpoint resumes
on either.
"""
import argparse
import atexit
import json
import math
import os
import random
import sys
import time

import numpy as np
import torch
import torch.nn.functional as F

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import dataset  # noqa: E402
import hfnet  # noqa: E402
import input_stats  # noqa: E402
import stamp_range  # noqa: E402

CKPT = "checkpoint.pt"


# ---- loss ----------------------------------------------------------------------

def premultiply(y):
    """(color*alpha, highlight*alpha, alpha): color and highlight only matter
    where the hair is visible."""
    a = y[:, 2:3]
    return torch.cat([y[:, 0:1] * a, y[:, 1:2] * a, a], 1)


def hair_loss(pred, target, grad_weight=1.0):
    """The paper's loss on NCHW (color, highlight, alpha) tensors."""
    return mse_and_gradients(premultiply(pred), premultiply(target), grad_weight)


def mse_and_gradients(p, q, grad_weight):
    """MSE of NCHW p against q plus grad_weight times the MSE of their x and
    y finite differences."""
    loss = F.mse_loss(p, q)
    if grad_weight:
        dxp, dxq = p[..., :, 1:] - p[..., :, :-1], q[..., :, 1:] - q[..., :, :-1]
        dyp, dyq = p[..., 1:, :] - p[..., :-1, :], q[..., 1:, :] - q[..., :-1, :]
        loss = loss + grad_weight * (F.mse_loss(dxp, dxq) + F.mse_loss(dyp, dyq))
    return loss


def l1_and_gradients(p, q, grad_weight, eps=1e-3):
    """mse_and_gradients with the mean of sqrt(d^2 + eps^2) - eps in place
    of the MSE (Charbonnier's smooth L1): its minimiser over an ambiguous
    input is the median of the targets, not their mean, so where a few
    training pixels disagree with most (4 covered samples over one layer
    of strands, among many over several), the output takes the common
    answer instead of a hedge between them."""
    def cl1(a, b):
        return (torch.sqrt((a - b) ** 2 + eps * eps) - eps).mean()
    loss = cl1(p, q)
    if grad_weight:
        dxp, dxq = p[..., :, 1:] - p[..., :, :-1], q[..., :, 1:] - q[..., :, :-1]
        dyp, dyq = p[..., 1:, :] - p[..., :-1, :], q[..., 1:, :] - q[..., :-1, :]
        loss = loss + grad_weight * (cl1(dxp, dxq) + cl1(dyp, dyq))
    return loss


# The look `hairfilter eval` scores with (client/cli/cmd_eval.c): brown hair,
# white light, a grey-blue background.
EVAL_LOOK = ((0.45, 0.25, 0.12), (1.0, 1.0, 1.0), (0.18, 0.20, 0.24))


def composite(y, hair, light, bg, clamp=torch.clamp):
    """What a viewer sees of NCHW (color, highlight, alpha) y: the paper's
    composite (Fig. 3), rgb = alpha light (hair color + highlight) + (1 -
    alpha) bg, clamped to [0, 1] as a display shows it (hf_composite, and
    `hairfilter eval`'s images). hair, light, bg: [n][3][1][1]. clamp:
    torch.clamp, or clamp_st (the same values; a gradient also where the
    composite is out of [0, 1])."""
    col, hl, a = y[:, 0:1], y[:, 1:2], y[:, 2:3]
    return clamp(a * light * (hair * col + hl) + (1 - a) * bg, 0, 1)


def srgb_encode(x):
    """The sRGB transfer function (IEC 61966-2-1) of linear values x in [0,
    1]: what a display's 8-bit code values are proportional to. Its slope
    is 12.92 below 0.0031308 and falls as x^(-7/12) above, so an error in
    dark tones weighs about as much as a viewer sees it (the linear MSE
    weighs it by the square of the value's scale)."""
    lo = 12.92 * x
    hi = 1.055 * x.clamp(min=0.0031308) ** (1 / 2.4) - 0.055
    return torch.where(x <= 0.0031308, lo, hi)


def random_looks(n, gen):
    """n looks an engine might composite with, as [n][3][1][1] tensors
    (hair, light, bg): hair colours from near-black through brown and red to
    blonde and grey (a random point between two of seven tones, as albedo),
    light of intensity 0.6-1.4 slightly tinted, background a random dark to
    mid colour."""
    tones = torch.tensor([[0.05, 0.04, 0.03], [0.20, 0.10, 0.05], [0.45, 0.25, 0.12],
                          [0.55, 0.20, 0.08], [0.85, 0.65, 0.40], [0.95, 0.88, 0.70],
                          [0.70, 0.70, 0.72]])
    i = torch.randint(0, len(tones), (n,), generator=gen)
    j = torch.randint(0, len(tones), (n,), generator=gen)
    t = torch.rand(n, 1, generator=gen)
    hair = tones[i] * (1 - t) + tones[j] * t
    light = (0.6 + 0.8 * torch.rand(n, 1, generator=gen)) * (0.9 + 0.2 * torch.rand(n, 3, generator=gen))
    bg = 0.5 * torch.rand(n, 3, generator=gen)
    return tuple(v[:, :, None, None] for v in (hair, light, bg))


# The SSIM `hairfilter eval` scores with (client/cli/eval_metrics.h): a
# Gaussian window of radius 5 and sigma 1.5, C1 = 0.01^2, C2 = 0.03^2.
SSIM_RADIUS, SSIM_SIGMA, SSIM_C1, SSIM_C2 = 5, 1.5, 0.01 ** 2, 0.03 ** 2


def ssim_map(p, q):
    """SSIM map of NCHW images p and q (values in [0, 1]), the mean over
    channels: [n][h - 10][w - 10], the pixels whose whole window lies inside
    (the evaluation renormalises the window at the border instead; a crop's
    border pixels are left out here). The moments in float32."""
    p, q = p.float(), q.float()
    r = SSIM_RADIUS
    k = torch.exp(-torch.arange(-r, r + 1, dtype=torch.float32, device=p.device) ** 2
                  / (2 * SSIM_SIGMA ** 2))
    k = k / k.sum()
    g = 5 * p.shape[1]   # the five moments' planes blurred in one separable pass
    kx, ky = k.view(1, 1, 1, -1).repeat(g, 1, 1, 1), k.view(1, 1, -1, 1).repeat(g, 1, 1, 1)
    planes = torch.cat([p, q, p * p, q * q, p * q], 1)
    mp, mq, pp, qq, pq = F.conv2d(F.conv2d(planes, kx, groups=g), ky, groups=g).chunk(5, 1)
    vp, vq, cov = pp - mp * mp, qq - mq * mq, pq - mp * mq
    s = ((2 * mp * mq + SSIM_C1) * (2 * cov + SSIM_C2)
         / ((mp * mp + mq * mq + SSIM_C1) * (vp + vq + SSIM_C2)))
    return s.mean(1)


def hair_ssim_loss(p, q, alpha):
    """1 - the mean SSIM of images p and q (NCHW) over the hair pixels (alpha
    [n][1][h][w] of the target > 0) whose window lies inside, as `hairfilter
    eval` scores SSIM on hair pixels; 0 for a crop without such pixels."""
    r = SSIM_RADIUS
    m = (alpha[:, 0, r:-r, r:-r] > 0).float()
    return ((1 - ssim_map(p, q)) * m).sum() / m.sum().clamp(min=1)


# Periods of the lattice a window of lattice_loss spans, on each side, at
# most: an error that does not repeat keeps 1/N^2 of its energy in the
# average of N x N periods, a lattice all of it.
LATTICE_WINDOW = 16


def lattice_loss(p, q, period):
    """The mean square of the part of the error p - q (NCHW) that repeats
    with the given period in x and y (the dot lattice a U-Net's stride-2
    transposed convolutions print, period 2^levels), measured in square
    windows of N x N periods (N: LATTICE_WINDOW, or fewer when the image is
    smaller): in each window the error at each of the period x period
    phases is averaged over the window's periods, less the window's mean
    error (a uniform offset is no lattice). Rows and columns beyond whole
    windows are left out; 0 for an image smaller than one period."""
    r = (p - q).float()
    n, c, h, w = r.shape
    k = min(LATTICE_WINDOW, h // period, w // period)
    if k < 1:
        return r.new_zeros(())
    side = period * k
    hh, ww = h // side * side, w // side * side
    r = r[:, :, :hh, :ww].reshape(n, c, hh // side, k, period, ww // side, k, period)
    m = r.mean(dim=(3, 6))
    m = m - m.mean(dim=(3, 5), keepdim=True)
    return (m * m).mean()


def lowpass_loss(p, q, size):
    """The mean square of the error p - q (NCHW) averaged over size x size
    blocks: what is left of the error once a box of that size has averaged
    the noise away, its bias. An estimate that is biased where many layers
    of strands overlap (stochastic transparency's alpha-corrected estimate
    over-weighs the front strands there) costs the same in the MSE as noise
    of the same energy, which a blur trades away; this weighs the part no
    blur removes. Rows and columns beyond whole blocks are left out; 0 for
    an image smaller than one block."""
    r = (p - q).float()
    if r.shape[-2] < size or r.shape[-1] < size:
        return r.new_zeros(())
    m = F.avg_pool2d(r, size)
    return (m * m).mean()


def st_estimate(x, spp):
    """The stochastic-transparency estimate of each pixel's own samples, NCHW
    [n][3][h][w] from features x [n][spp*6][h][w] (hfnet.residual_base with
    a window of one pixel): the `input` row of `hairfilter eval`."""
    return hfnet.residual_base(x.float(), spp, radius=0)


def training_target(x, y, target, spp):
    """What a run trains towards (--target): "truth", the frames' gt.*
    channels y, or "input", the stochastic-transparency estimate of the
    crop's own samples x (st_estimate), in y's dtype: a probe of how much
    of its input a variant can pass through, for the bar "never below its
    own input" (docs/QUALITY.md)."""
    if target == "input":
        return st_estimate(x, spp).to(y.dtype)
    return y


# The MSE floor of below_input_loss's PSNR ratio: 60 dB, so that a crop the
# input already matches exactly gives a finite deficit.
BELOW_INPUT_EPS = 1e-6


def below_input_loss(cp, ct, ci, alpha):
    """How far each crop's composite cp is below the composite of its own
    input ci, both against the target's ct (NCHW images, alpha the target's
    [n][1][h][w]), on the crop's hair pixels (alpha > 0), as `hairfilter
    eval` counts a frame below its input: the PSNR deficit in dB over 10
    plus the SSIM deficit, each only where positive (a hinge: a crop better
    than its input costs nothing), averaged over the crops. 0 for a crop
    without hair pixels. ci carries no gradient."""
    m = (alpha > 0).float()
    cnt = m.sum((1, 2, 3))
    has = (cnt > 0).float()
    cnt = cnt.clamp(min=1)
    e_net = (((cp - ct) ** 2).mean(1, keepdim=True) * m).sum((1, 2, 3)) / cnt
    e_in = (((ci - ct) ** 2).mean(1, keepdim=True) * m).sum((1, 2, 3)) / cnt
    db = 10 * torch.log10((e_net + BELOW_INPUT_EPS) / (e_in + BELOW_INPUT_EPS))
    r = SSIM_RADIUS
    mi = m[:, 0, r:-r, r:-r]
    ni = mi.sum((1, 2)).clamp(min=1)
    s_net = (ssim_map(cp, ct) * mi).sum((1, 2)) / ni
    s_in = (ssim_map(ci, ct) * mi).sum((1, 2)) / ni
    return ((F.relu(db) / 10 + F.relu(s_in - s_net)) * has).mean()


def look_loss(pred, target, looks, grad_weight=1.0, paper_weight=0.1, ssim_weight=0.0,
              lattice=(0.0, 8), below=(0.0, None, 4), display_st=False, srgb=False,
              l1=False, lowpass=(0.0, 8)):
    """The squared error of what a viewer sees: pred and target composited
    with looks (random_looks, or EVAL_LOOK broadcast), MSE of the images and,
    weighted by grad_weight, of their finite differences, as the paper's loss
    does on premultiplied channels; plus paper_weight times the paper's loss,
    which keeps every channel pinned where a look hides it (a dark hair
    colour hides the colour factor). Where the paper's loss weighs the three
    channels alike, a viewer sees the highlight at full strength and the
    colour factor scaled by the hair colour, so this puts the effort where
    the image's error is. ssim_weight adds that times hair_ssim_loss of the
    two images: the structure the evaluation's SSIM scores, which the MSE
    lets a blur trade away. lattice (weight, period) adds weight times
    lattice_loss of the two images: the periodic part of the error, which
    the MSE counts no more than any other error of the same energy. below
    (weight, features, spp) adds weight times below_input_loss against the
    composite of st_estimate(features, spp): the crops where the network
    does worse than the samples it reads. display_st: the display's clamp
    of the prediction's composite passes a gradient where the composite is
    below 0 or above 1 (clamp_st; the loss's value is the same): with the
    exact clamp a dark pixel whose colour factor has gone below 0 shows
    black and gets no gradient from the composite, so only the paper's
    term, a tenth of the loss, pulls it back. srgb: the images' MSE (and
    their finite differences') on the sRGB-encoded composites
    (srgb_encode), as a display's code values differ, instead of the
    linear ones; the other terms stay on the linear composites, as the
    evaluation scores them. l1: l1_and_gradients in place of
    mse_and_gradients for the images' term. lowpass (weight, size) adds
    weight times lowpass_loss of the two linear images."""
    cp = composite(pred, *looks, clamp=clamp_st if display_st else torch.clamp)
    ct = composite(target, *looks)
    image_term = l1_and_gradients if l1 else mse_and_gradients
    if srgb:
        loss = image_term(srgb_encode(cp), srgb_encode(ct), grad_weight)
    else:
        loss = image_term(cp, ct, grad_weight)
    if ssim_weight:
        loss = loss + ssim_weight * hair_ssim_loss(cp, ct, target[:, 2:3])
    if lattice[0]:
        loss = loss + lattice[0] * lattice_loss(cp, ct, lattice[1])
    if lowpass[0]:
        loss = loss + lowpass[0] * lowpass_loss(cp, ct, lowpass[1])
    if below[0]:
        with torch.no_grad():
            ci = composite(st_estimate(below[1], below[2]), *looks)
        loss = loss + below[0] * below_input_loss(cp, ct, ci, target[:, 2:3])
    if paper_weight:
        loss = loss + paper_weight * hair_loss(pred, target, grad_weight)
    return loss


def eval_looks(n, device):
    return tuple(torch.tensor(v, device=device).view(1, 3, 1, 1).expand(n, 3, 1, 1)
                 for v in EVAL_LOOK)


def run_loss(kind, pred, target, grad_weight, looks=None, ssim_weight=0.0, lattice=(0.0, 8),
             below=(0.0, None, 4), display_st=False, srgb=False, l1=False, lowpass=(0.0, 8)):
    """The loss a run trains with (--loss): "paper" (hair_loss) or "look"
    (look_loss with looks, EVAL_LOOK when None, ssim_weight, lattice,
    below, display_st, srgb, l1 and lowpass)."""
    if kind == "look":
        return look_loss(pred, target, looks if looks is not None
                         else eval_looks(pred.shape[0], pred.device), grad_weight,
                         ssim_weight=ssim_weight, lattice=lattice, below=below,
                         display_st=display_st, srgb=srgb, l1=l1, lowpass=lowpass)
    return hair_loss(pred, target, grad_weight)


# ---- fast path -------------------------------------------------------------------

# A 4x4 stride-2 pad-1 transposed convolution equals a 3x3 pad-1 convolution
# with 4x the output channels followed by a 2x pixel shuffle. Output row
# 2m + r takes input rows m + d through kernel row _KIDX[r][d + 1] (-1: none).
_KIDX = [[3, 1, -1], [-1, 2, 0]]


def deconv_as_conv_weight(wt):
    """ConvTranspose2d weight [in][out][4][4] -> Conv2d weight
    [out*4][in][3][3] for conv + pixel_shuffle(2); differentiable, so the
    trained parameters stay in ConvTranspose2d layout."""
    cin, cout = wt.shape[:2]
    padded = torch.cat([wt, wt.new_zeros(cin, cout, 1, 4)], 2)
    padded = torch.cat([padded, padded.new_zeros(cin, cout, 5, 1)], 3)  # index 4 = zero
    idx = torch.tensor([[k if k >= 0 else 4 for k in row] for row in _KIDX], device=wt.device)
    # w3[cin][cout][ry][rx][dy][dx] = padded[cin][cout][idx[ry][dy]][idx[rx][dx]]
    w = padded[:, :, idx[:, :, None, None], idx[None, None, :, :]]   # [cin][cout][ry][dy][rx][dx]
    w = w.permute(1, 2, 4, 0, 3, 5)                                     # [cout][ry][rx][cin][dy][dx]
    return w.reshape(cout * 4, cin, 3, 3)


def raw_shuffle(net, x):
    """net.raw() with every transposed convolution as conv + pixel shuffle.
    Same function and parameters (the weights stay in ConvTranspose2d
    layout); it runs under bf16 autocast, where torch 1.13 has no
    ConvTranspose2d. Timings: `train.py --benchmark`, docs/QUALITY.md."""
    inp, enc = x, []
    for i in range(net.levels):
        x = F.relu(getattr(net, f"enc{i}")(x))
        enc.append(x)
    y = enc[-1]
    for i in reversed(range(net.levels)):
        if i < net.levels - 1:
            y = torch.cat([y, enc[i]], dim=1)
        layer = getattr(net, f"dec{i}")
        w = deconv_as_conv_weight(layer.weight)
        b = layer.bias.repeat_interleave(4)
        y = F.pixel_shuffle(F.conv2d(y, w, b, padding=1), 2)
        if i > 0:
            y = F.relu(y)
    return net.apply_head(y, inp)


def clamp_st(x, lo=None, hi=None):
    """clamp() in value, identity in gradient (straight-through). The exact
    clamps of the output transforms pass no gradient where the raw output is
    out of range, so a channel pushed below zero early in training (the
    highlight, which is zero on most pixels) stays dead for good; with this
    the loss still sees the clamped value the backends compute, but a raw
    output on the wrong side is pulled back whenever the target needs it."""
    return x + (torch.clamp(x, lo, hi) - x).detach()


def forward(net, x, deconv="shuffle", bf16=False, straight_through=False):
    """Output-transformed prediction for NCHW x (sides multiples of 2^L)."""
    with torch.autocast(x.device.type, dtype=torch.bfloat16, enabled=bf16):
        y = net.raw(x) if deconv == "transpose" and not bf16 else raw_shuffle(net, x)
    return net.finish(y.float(), x, clamp_st if straight_through else torch.clamp)


# ---- helpers ---------------------------------------------------------------------

def fmt_time(s):
    s = int(max(0, s))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


class Progress:
    """One stderr line, rewritten in place (plain lines when not a tty)."""

    def __init__(self, total, start):
        self.total, self.start_step = total, start
        self.t0 = time.time()
        self.last = 0.0
        self.tty = sys.stderr.isatty()

    def update(self, step, loss, val, force=False):
        now = time.time()
        if not force and now - self.last < (0.5 if self.tty else 10):
            return
        self.last = now
        done = step - self.start_step
        rate = done / max(now - self.t0, 1e-9)
        eta = (self.total - step) / rate if rate > 0 else float("inf")
        width = 24
        fill = int(width * step / max(self.total, 1))
        bar = "#" * fill + "." * (width - fill)
        vs = f" val {val:.5f}" if val is not None else ""
        line = (f"[{bar}] {step}/{self.total} loss {loss:.5f}{vs} "
                f"{1000 / rate if rate > 0 else 0:.0f} ms/step ETA "
                f"{fmt_time(eta) if math.isfinite(eta) else '?'}")
        sys.stderr.write(("\r" + line + "\x1b[K") if self.tty else line + "\n")
        sys.stderr.flush()

    def close(self):
        if self.tty:
            sys.stderr.write("\n")


def rng_state(np_rng):
    return dict(torch=torch.get_rng_state(), numpy=np_rng.bit_generator.state,
                python=random.getstate())


def set_rng_state(np_rng, st):
    torch.set_rng_state(st["torch"])
    np_rng.bit_generator.state = st["numpy"]
    random.setstate(st["python"])


def save_checkpoint(path, **state):
    """Atomic: a crash mid-write never leaves a torn checkpoint."""
    tmp = path + ".tmp"
    torch.save(state, tmp)
    os.replace(tmp, path)


def averaged(net, avg):
    """The weights a run validates and exports: the moving average of
    --weight-ema once it has averaged a step, else the network's own."""
    return avg.module if avg is not None and int(avg.n_averaged) > 0 else net


@torch.no_grad()
def validate(net, frames, spp, grad_weight, mode, device, max_side=256, loss="paper",
             ssim_weight=0.0, lattice=(0.0, 8), below_weight=0.0, target="truth",
             lowpass=(0.0, 8)):
    """Mean loss over the held-out frames (first spp samples, no
    augmentation; frames larger than max_side are centre-cropped) against
    training_target; the look loss with the evaluation's look (EVAL_LOOK)."""
    if not frames:
        return None
    net.eval()
    total = 0.0
    for i, (f, t) in enumerate(zip(frames.feats, frames.tgts)):
        h, w = t.shape[:2]
        ch, cw = min(h, max_side), min(w, max_side)
        y0, x0 = (h - ch) // 2, (w - cw) // 2
        x = f[y0:y0 + ch, x0:x0 + cw, :spp].reshape(ch, cw, -1)
        if frames.ests:   # the estimate after the samples
            x = np.concatenate([x, frames.ests[i][y0:y0 + ch, x0:x0 + cw]], -1)
        y = t[y0:y0 + ch, x0:x0 + cw]
        x = torch.from_numpy(np.ascontiguousarray(x.astype(np.float32).transpose(2, 0, 1)))[None]
        y = torch.from_numpy(np.ascontiguousarray(y.astype(np.float32).transpose(2, 0, 1)))[None]
        x, y = x.to(device), y.to(device)
        y = training_target(x, y, target, spp)
        total += float(run_loss(loss, forward(net, x, *mode), y, grad_weight,
                                ssim_weight=ssim_weight, lattice=lattice,
                                below=(below_weight, x, spp), lowpass=lowpass))
    net.train()
    return total / len(frames)


def export(net, path, dtype, input_range=None, step=None, steps=None, run_path=None):
    """Writes the weights; input_range (weights/input_stats.py) becomes the
    `input_range` metadata that hairfilterd checks frames against. A run
    stopped before its --steps (--stop-at, --time-limit) exports the weights
    of the step it reached, and says so: the file is not the finished run's;
    run_path, when not path, is where the run's own export goes on its
    --resume (this command exported elsewhere)."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    meta = {"input_range": input_stats.input_range_json(input_range)} if input_range else None
    hfnet.save_safetensors(path, net.cfg, net.state_dict(), dtype=dtype, metadata=meta)
    early = step is not None and steps is not None and step < steps
    print(f"exported {net.cfg['name']} to {path} ({dtype}"
          f"{', input range of %d frames' % input_range['frames'] if input_range else ''})"
          + (f": the weights of step {step} of {steps}; --resume finishes the run and exports "
             "again" + (f" (to the run's --export, {run_path})"
                        if run_path and os.path.abspath(run_path) != os.path.abspath(path)
                        else "") if early else ""),
          file=sys.stderr)


# ---- main ------------------------------------------------------------------------

def pick_device(name):
    """auto: the GPU when PyTorch sees one, else the CPU."""
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        sys.exit("train.py: --device cuda: PyTorch sees no CUDA device")
    return torch.device(name)


def benchmark(args):
    """ms per training step (forward, loss, backward, Adam) of each way of
    computing the network, on random data of the run's batch and crop."""
    cfg = make_config(args)
    torch.manual_seed(args.seed)
    device = pick_device(args.device)
    net = hfnet.HairNet(cfg).to(device)
    opt = torch.optim.Adam(net.parameters(), lr=args.lr)
    x = torch.rand(args.batch, cfg["in_channels"], args.crop, args.crop, device=device)
    y = torch.rand(args.batch, 3, args.crop, args.crop, device=device)
    print(f"| {cfg['name']}, batch {args.batch}, {args.crop}x{args.crop}, "
          f"{args.threads} threads | ms/step |\n|---|---:|")
    for label, mode in (("ConvTranspose2d, fp32", ("transpose", False)),
                        ("conv + pixel shuffle, fp32", ("shuffle", False)),
                        ("conv + pixel shuffle, bf16 autocast", ("shuffle", True))):
        times = []
        for i in range(args.benchmark + 1):
            t = time.perf_counter()
            loss = hair_loss(forward(net, x, *mode), y, args.grad_weight)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            if device.type == "cuda":
                torch.cuda.synchronize()
            if i:  # the first step warms up oneDNN's primitive caches
                times.append(time.perf_counter() - t)
        print(f"| {label} | {1000 * float(np.median(times)):.0f} |")
    return 0


def make_parser():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", help="dataset directory (manifest.json + EXRs); several "
                    "separated by commas are trained on together")
    ap.add_argument("--variant", default="Base",
                    help="the variant: " + ", ".join(hfnet.VARIANTS) + " (default Base, the "
                    "paper's; the server's default is KernelMix)")
    ap.add_argument("--out", required=True, help="run directory (checkpoint, log)")
    ap.add_argument("--steps", type=int, default=10000, help="total optimizer steps (default 10000)")
    ap.add_argument("--batch", type=int, default=8, help="crops per step (default 8)")
    ap.add_argument("--crop", type=int, default=128,
                    help="side of the square crops, in pixels (default 128): inside every "
                    "frame, a multiple of 2 to the number of levels")
    ap.add_argument("--lr", type=float, default=5e-4, help="Adam's learning rate (default 5e-4)")
    ap.add_argument("--schedule", default="cosine", choices=["cosine", "constant"],
                    help="cosine: lr decays to --lr-floor x lr at --steps (a resumed run "
                    "with a larger --steps continues on the stretched curve)")
    ap.add_argument("--lr-floor", type=float, default=0.05,
                    help="--schedule cosine: the last lr, times --lr (default 0.05)")
    ap.add_argument("--grad-weight", type=float, default=1.0,
                    help="weight of the image-gradient MSE term (default 1)")
    ap.add_argument("--loss", default="paper", choices=["paper", "look"],
                    help="paper: the paper's MSE of premultiplied colour, highlight and "
                    "alpha and of their gradients; look: the same on the composited image "
                    "under a random hair colour, light and background per crop, plus a "
                    "tenth of the paper's (train.py look_loss)")
    ap.add_argument("--target", default="truth", choices=["truth", "input"],
                    help="truth: the ground truth (gt.*); input: the stochastic-transparency "
                    "estimate of each crop's own samples, to measure how much of its input "
                    "a variant can pass through (train.py training_target)")
    ap.add_argument("--ssim-weight", type=float, default=0.0,
                    help="--loss look: add this times 1 - the SSIM of the composited "
                    "images over the target's hair pixels (the evaluation's window and "
                    "constants; train.py hair_ssim_loss)")
    ap.add_argument("--lattice-weight", type=float, default=0.0,
                    help="--loss look: add this times the mean square of the error's part "
                    "that repeats every 2^levels pixels (a U-Net's transposed-convolution "
                    "lattice; train.py lattice_loss)")
    ap.add_argument("--below-input-weight", type=float, default=0.0,
                    help="--loss look: add this times the crops' deficit against their own "
                    "input (PSNR in dB / 10 plus SSIM, where the network is below the "
                    "stochastic-transparency estimate of its samples; train.py "
                    "below_input_loss)")
    ap.add_argument("--lowpass-weight", type=float, default=0.0,
                    help="--loss look: add this times the mean square of the composites' "
                    "error averaged over --lowpass-size blocks (its bias, which no blur "
                    "removes; train.py lowpass_loss)")
    ap.add_argument("--lowpass-size", type=int, default=8, metavar="N",
                    help="the blocks of --lowpass-weight, N x N pixels (default 8)")
    ap.add_argument("--clip-grad-norm", type=float, default=0.0, metavar="C",
                    help="scale each step's gradient down to global L2 norm C where it is "
                    "larger (torch.nn.utils.clip_grad_norm_; 0: off). The log records each "
                    "interval's median norm before clipping and the share of steps clipped")
    ap.add_argument("--styles", default="straight,wavy",
                    help="styles to train on (others are never loaded); '' = all (default "
                    "straight,wavy, the paper's two)")
    ap.add_argument("--val-fraction", type=float, default=0.1,
                    help="share of the frames held out for validation, chosen by a hash of "
                    "the file name (default 0.1; at least one, and one left to train on)")
    ap.add_argument("--val-every", type=int, default=500,
                    help="validate and log every N steps (default 500)")
    ap.add_argument("--ckpt-every", type=int, default=500,
                    help="write RUN/checkpoint.pt every N steps (default 500)")
    ap.add_argument("--seed", type=int, default=1,
                    help="seed of the initialisation and the crops (default 1)")
    ap.add_argument("--threads", type=int, default=min(2, os.cpu_count() or 1),
                    help="PyTorch's CPU threads (default 2, or 1 on a one-core machine)")
    ap.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"],
                    help="auto: CUDA when PyTorch sees a GPU, else the CPU (a run resumes "
                    "on any device)")
    ap.add_argument("--deconv", default="transpose", choices=["transpose", "shuffle"],
                    help="fp32 transposed convs with ConvTranspose2d or as conv + pixel "
                    "shuffle; same parameters either way")
    ap.add_argument("--bf16", action="store_true",
                    help="bf16 autocast, deconvs as conv + pixel shuffle (fastest on a CPU "
                    "with AVX512-BF16; weights and optimizer stay fp32)")
    ap.add_argument("--exact-clamps", dest="straight_through", action="store_false",
                    help="train through the exact output clamps (no gradient where the raw "
                    "output is out of range) instead of straight-through ones. The straight-"
                    "through ones revive a dead output channel when training from scratch; "
                    "for a fine-tune (--init) with --loss look use the exact ones: through the "
                    "straight-through ones such fine-tunes of Small, Shallow and Large "
                    "diverged (weights/small.md)")
    ap.add_argument("--equal-phase-sums", action="store_true",
                    help="keep the four output phases of every transposed convolution at "
                    "equal tap sums (hfnet.equalise_phase_sums_, applied to the start weights "
                    "and after every step): a flat input then gives a flat output, so the "
                    "transposed convolutions cannot paint a lattice there")
    ap.add_argument("--init", metavar="WEIGHTS",
                    help="start from these weights (safetensors of the same variant) "
                    "instead of a random initialisation: fine-tuning")
    ap.add_argument("--resume", action="store_true",
                    help="continue RUN/checkpoint.pt with the run's options (the data, variant, "
                    "loss, crop, batch, lr, seed, ...: those left out come from the checkpoint); "
                    "only --steps, --stop-at, --time-limit, --threads, --device, --val-every, "
                    "--ckpt-every, --reload-every, --export and --export-dtype may change, and "
                    "another value of any other option is refused; --steps, --val-every, "
                    "--ckpt-every, --reload-every, --export and --export-dtype left out are the "
                    "run's too, --stop-at, --time-limit, --threads and --device this command's. "
                    "Without --resume, an --out that holds a checkpoint is refused")
    ap.add_argument("--stop-at", type=int, default=0,
                    help="checkpoint and stop at this step (the run stays resumable)")
    ap.add_argument("--time-limit", type=float, default=0,
                    help="checkpoint and stop after this many seconds of this invocation")
    ap.add_argument("--benchmark", type=int, default=0, metavar="N",
                    help="only time N steps of each forward variant (median ms/step)")
    ap.add_argument("--levels", metavar="C0,C1,...",
                    help="the U-Net's channels per level instead of the variant's (recorded "
                         "in the weights' metadata); --init weights with as many levels, none "
                         "wider, are widened to the same function")
    ap.add_argument("--kernel-radius", type=int, default=0,
                    help="Kernel variant: half side of the per-pixel kernel (default: the "
                    "variant's); --init weights of a smaller radius are regrown to it "
                    "(hfnet.grow_kernel_radius)")
    ap.add_argument("--kernel-hidden", type=int, default=-1,
                    help="Kernel variant: channels of dec0 before the 1x1 head (0: dec0 "
                    "gives the kernel directly; default: the variant's)")
    ap.add_argument("--display-straight-through", action="store_true",
                    help="--loss look: the display clamp of the predicted composite passes "
                    "a gradient outside [0, 1] (train.py look_loss display_st), so a colour "
                    "factor gone below 0 in dark hair is pulled back")
    ap.add_argument("--look-srgb", action="store_true",
                    help="--loss look: the images' MSE on the sRGB-encoded composites "
                    "(train.py srgb_encode), as a display's code values differ, so an error "
                    "in dark hair weighs as a viewer sees it; the SSIM and lattice terms "
                    "stay linear")
    ap.add_argument("--look-l1", action="store_true",
                    help="--loss look: the images' term as a smooth L1 (train.py "
                    "l1_and_gradients) instead of the MSE: the median of what an input "
                    "could be, not the mean; validation stays the MSE")
    ap.add_argument("--dim-light", type=float, default=0.0, metavar="LO",
                    help="dim the light of --dim-share of the crops: colour factor and "
                    "highlight each scaled by a factor drawn log-uniform in [LO, 1], in the "
                    "samples, the target and the estimate alike (dataset.dim_light; "
                    "shadowed dense hair); 0: off")
    ap.add_argument("--dim-share", type=float, default=None,
                    help="with --dim-light: the share of the crops dimmed (default 0.5)")
    ap.add_argument("--reload-every", type=int, default=0, metavar="N",
                    help="every N steps, add the frames that appeared in the --data "
                    "directories since the start (a data set still being rendered) to the "
                    "training set")
    ap.add_argument("--weight-ema", type=float, default=0.0, metavar="DECAY",
                    help="keep an exponential moving average of the weights (torch's "
                    "AveragedModel; after each step avg = DECAY * avg + (1 - DECAY) * weights, "
                    "starting from the first step's), and validate and export it instead of "
                    "the last step's weights; 0: off")
    ap.add_argument("--export", help="write the weights here (safetensors)")
    ap.add_argument("--export-dtype", default="F32", choices=["F32", "F16"],
                    help="the exported tensors' type (default F32)")
    return ap


def given_options(argv):
    """{dest: action} of the options argv names (a default is not given)."""
    ap = make_parser()
    actions = {a.dest: a for a in ap._actions}
    for a in ap._actions:
        a.default = argparse.SUPPRESS
    return {k: actions[k] for k in vars(ap.parse_args(argv))}


def parse_args(argv):
    ap = make_parser()
    args = ap.parse_args(argv)
    # The options that act on the composited images, which only the look loss makes.
    for flag, does in (("--ssim-weight", "scores"), ("--lattice-weight", "scores"),
                       ("--below-input-weight", "scores"), ("--lowpass-weight", "scores"),
                       ("--display-straight-through", "clamps"), ("--look-srgb", "encodes"),
                       ("--look-l1", "scores")):
        if getattr(args, flag[2:].replace("-", "_")) and args.loss != "look":
            ap.error(f"{flag} needs --loss look (it {does} the composited images)")
    if args.lowpass_size < 1:
        ap.error("--lowpass-size must be 1 or more (pixels)")
    if args.dim_light and not 0 < args.dim_light <= 1:
        ap.error("--dim-light must be in (0, 1] (the dimmest factor; 0: off)")
    if args.dim_share is not None and not args.dim_light:
        ap.error("--dim-share needs --dim-light (the dimmest factor)")
    if args.dim_share is None:
        args.dim_share = 0.5
    if not 0 <= args.dim_share <= 1:
        ap.error("--dim-share must be a share in [0, 1]")
    if not 0 <= args.weight_ema < 1:
        ap.error("--weight-ema must be a decay in [0, 1) (0: off)")
    if args.clip_grad_norm < 0 or not math.isfinite(args.clip_grad_norm):
        ap.error("--clip-grad-norm must be a finite norm >= 0 (0: no clipping)")
    # Counts and rates in their ranges, before any data is read: out of
    # them a run did nothing (--steps 0) or ended in a traceback from numpy
    # or torch (--batch 0, --val-every 0, --lr -1, --threads 0, ...).
    for flag, lo, what in (("--steps", 1, "optimizer steps"), ("--batch", 1, "crops a step"),
                           ("--crop", 1, "pixels"), ("--val-every", 1, "steps"),
                           ("--ckpt-every", 1, "steps"), ("--threads", 1, "threads"),
                           ("--reload-every", 0, "steps; 0: off"),
                           ("--stop-at", 0, "a step; 0: off"), ("--benchmark", 0, "steps")):
        v = getattr(args, flag[2:].replace("-", "_"))
        if v < lo:
            ap.error(f"{flag} {v}: must be {lo} or more ({what})")
    # The loader's limits (src/hfcore.h HF_KERNEL_MAX_RADIUS, _MAX_HIDDEN):
    # beyond them a run trained weights no backend loads.
    if args.kernel_radius and not 1 <= args.kernel_radius <= KERNEL_MAX_RADIUS:
        ap.error(f"--kernel-radius {args.kernel_radius}: must be 1..{KERNEL_MAX_RADIUS} (kernels "
                 f"of up to {2 * KERNEL_MAX_RADIUS + 1}x{2 * KERNEL_MAX_RADIUS + 1} pixels, what "
                 f"the C loader and backends take)")
    if args.kernel_hidden != -1 and not 0 <= args.kernel_hidden <= KERNEL_MAX_HIDDEN:
        ap.error(f"--kernel-hidden {args.kernel_hidden}: must be 0..{KERNEL_MAX_HIDDEN} (what the "
                 f"C loader and backends take; 0: no head)")
    if not (math.isfinite(args.lr) and args.lr > 0):
        ap.error(f"--lr {args.lr}: must be a finite rate above 0")
    if not 0 <= args.lr_floor <= 1:
        ap.error(f"--lr-floor {args.lr_floor}: must be a share of --lr in [0, 1]")
    if not 0 <= args.val_fraction < 1:
        ap.error(f"--val-fraction {args.val_fraction}: must be a share in [0, 1) (0: no "
                 f"validation frames)")
    if not (math.isfinite(args.time_limit) and args.time_limit >= 0):
        ap.error(f"--time-limit {args.time_limit}: must be seconds >= 0 (0: none)")
    # Before any data is read (a mistyped name was a KeyError traceback
    # after the frames had loaded).
    if args.variant is not None and not any(k.lower() == args.variant.lower()
                                            for k in hfnet.VARIANTS):
        ap.error(f"--variant {args.variant!r} is not a variant: give one of "
                 f"{', '.join(hfnet.VARIANTS)}")
    return args


def init_mismatch(icfg, cfg):
    """What keeps weights of config icfg from starting a run of cfg ('' if
    nothing): each difference named, since the levels alone (what this
    said) are often the same, as Kernel's and KernelAC's are."""
    def inputs(c):
        est = " and the alpha-corrected estimate" if c.get("estimate") else ""
        return f"{c['spp']} sample{'s' if c['spp'] != 1 else ''}{est} ({c['in_channels']} " \
               f"input channels)"
    why = []
    if icfg.get("arch", "unet") != cfg["arch"]:
        why.append(f"architecture {icfg.get('arch', 'unet')}, not {cfg['arch']}")
    if icfg["in_channels"] != cfg["in_channels"]:
        why.append(f"it reads {inputs(icfg)}, {cfg['name']} {inputs(cfg)}")
    if icfg.get("kernel_mix") and not cfg.get("kernel_mix"):
        why.append(f"its kernel mixes the samples' sums with the estimate's, {cfg['name']}'s "
                   f"does not")
    if len(icfg["levels"]) != len(cfg["levels"]):
        why.append(f"{len(icfg['levels'])} levels {icfg['levels']}, not {len(cfg['levels'])} "
                   f"{cfg['levels']}")
    elif any(a > b for a, b in zip(icfg["levels"], cfg["levels"])):
        why.append(f"levels {icfg['levels']} wider than {cfg['levels']}")
    return "; ".join(why)


def file_error(e):
    """An OSError or a weights file's ValueError as one line: the file and
    what is wrong with it."""
    if isinstance(e, OSError) and e.filename is not None:
        return f"{e.filename}: {e.strerror}"
    return str(e)


MAX_LEVELS = 8           # src/hfcore.h HF_MAX_LEVELS
MAX_CHANNELS = 4096      # src/hfcore.h HF_MAX_CHANNELS
KERNEL_MAX_RADIUS = 4    # src/hfcore.h HF_KERNEL_MAX_RADIUS
KERNEL_MAX_HIDDEN = 64   # src/hfcore.h HF_KERNEL_MAX_HIDDEN


def make_config(args):
    """The variant's configuration with the run's kernel overrides."""
    cfg = hfnet.variant_config(args.variant)
    if cfg["arch"] != "kernel" and (getattr(args, "kernel_radius", 0) > 0
                                    or getattr(args, "kernel_hidden", -1) >= 0):
        # Checked here, after --resume has set the variant: dropped in
        # silence, the run would not be the one asked for.
        sys.exit(f"train.py: --kernel-radius and --kernel-hidden are for the kernel variants "
                 f"(Kernel, KernelAC), not {cfg['name']}")
    if getattr(args, "levels", None):
        try:
            cfg["levels"] = [int(c) for c in args.levels.split(",")]
        except ValueError:
            cfg["levels"] = []
        if not cfg["levels"] or min(cfg["levels"]) < 1:
            sys.exit(f"train.py: --levels {args.levels!r}: positive channel counts, "
                     f"e.g. 48,96,192")
        if len(cfg["levels"]) > MAX_LEVELS or max(cfg["levels"]) > MAX_CHANNELS:
            # Past the loader's limits the run would train weights no backend loads.
            sys.exit(f"train.py: --levels {args.levels!r}: at most {MAX_LEVELS} levels of at "
                     f"most {MAX_CHANNELS} channels (what the C loader and backends take)")
    if cfg["arch"] == "kernel":
        if getattr(args, "kernel_radius", 0) > 0:
            cfg["kernel_radius"] = args.kernel_radius
            cfg["out_channels"] = hfnet.kernel_taps(args.kernel_radius) + len(hfnet.OUTPUTS)
        if getattr(args, "kernel_hidden", -1) >= 0:
            cfg["kernel_hidden"] = args.kernel_hidden
    return cfg


# The options that make a run what it is: a resumed run takes them from its
# checkpoint, and refuses a command line that gives one another value.
RUN_OPTIONS = ("data", "variant", "styles", "val_fraction", "seed", "init", "levels",
               "kernel_radius", "kernel_hidden", "batch", "crop", "lr", "schedule", "lr_floor",
               "loss", "grad_weight", "ssim_weight", "lattice_weight", "below_input_weight",
               "lowpass_weight", "lowpass_size", "target", "clip_grad_norm", "dim_light",
               "dim_share", "display_straight_through", "look_srgb", "look_l1", "weight_ema",
               "deconv", "bf16", "straight_through", "equal_phase_sums")
# What a resumed run may change: how long it runs and where, how often it
# validates and checkpoints, what it exports (docs/TRAINING.md).
RESUME_MAY_CHANGE = ("--steps", "--stop-at", "--time-limit", "--threads", "--device",
                     "--val-every", "--ckpt-every", "--reload-every", "--export",
                     "--export-dtype")
# Of those, the ones a resumed run keeps from its checkpoint when the command
# line leaves them out: `--out RUN --resume` finishes the run as it was
# started (its length, cadence and export), not a run of the defaults'
# length under a stretched schedule. The others are this invocation's:
# --stop-at and --time-limit say when this one stops, and --threads and
# --device where it runs (a checkpoint moves between machines).
RESUME_KEEPS = ("steps", "val_every", "ckpt_every", "reload_every", "export", "export_dtype")


def saved_args(args):
    """The run's options as the checkpoint keeps them: the paths (--data,
    --init, --export) absolute, so that `--out RUN --resume` from another
    directory reads and writes the same files (relative ones were taken
    from wherever the resumed command ran)."""
    saved = dict(vars(args))
    # A resumed command's --export and --export-dtype are its own: the run
    # keeps the ones it was started with (else one export elsewhere, say
    # onto a file a daemon serves, became the run's for every later resume,
    # and only if this resume reached a checkpoint).
    run_export = saved.pop("run_export", None)
    if run_export is not None:
        saved["export"], saved["export_dtype"] = run_export
    if args.data:
        saved["data"] = ",".join(os.path.abspath(d) for d in args.data.split(",") if d)
    for k in ("init", "export"):
        if saved.get(k):
            saved[k] = os.path.abspath(saved[k])
    return saved


def same_option(key, a, b):
    """Whether option key's values a and b make the same run: paths as the
    files they name (from this directory), styles as sets, variant names
    in any case."""
    if a is None or b is None:
        return a == b
    if key in ("data", "init"):
        return ([os.path.realpath(p) for p in str(a).split(",") if p]
                == [os.path.realpath(p) for p in str(b).split(",") if p])
    if key == "styles":
        return set(dataset.parse_styles(a)) == set(dataset.parse_styles(b))
    if key == "variant":
        return str(a).lower() == str(b).lower()
    if key == "levels":
        return str(a).replace(" ", "") == str(b).replace(" ", "")
    return a == b


def option_text(action, v):
    """v as a command line gives it: a flag on or off, '' for an empty string."""
    if action.nargs == 0 and isinstance(action.const, bool):
        return "on" if v == action.const else "off"
    if v is None:
        return "none"
    return str(v) if str(v) else "''"


def resume_options(args, saved, given, ckpt_path):
    """Sets args' RUN_OPTIONS to the run's (saved: the checkpoint's args),
    and RESUME_KEEPS that the command line leaves out; exits naming every
    RUN_OPTION that given (the options the command line names,
    given_options) sets to another value."""
    diffs = []
    for k in RUN_OPTIONS:
        if k not in saved:   # a checkpoint older than the option: its default
            continue
        if k in given and not same_option(k, saved[k], getattr(args, k)):
            a = given[k]
            diffs.append(f"{a.option_strings[0]} is {option_text(a, saved[k])} there, "
                         f"{option_text(a, getattr(args, k))} here")
        setattr(args, k, saved[k])
    for k in RESUME_KEEPS:
        if k in saved and k not in given:
            setattr(args, k, saved[k])
    # What the checkpoints of this resume keep as the run's export
    # (saved_args): the run's own, whatever this command exports to.
    args.run_export = (saved.get("export"), saved.get("export_dtype", "F32"))
    if diffs:
        sys.exit(f"train.py: --resume: {ckpt_path} is a run with other options: "
                 f"{'; '.join(diffs)}; a resumed run may change only "
                 f"{', '.join(RESUME_MAY_CHANGE)}: leave the others out (the run's are used) "
                 f"or --out another directory for a new run")


def remove_if_empty(path):
    """Removes the folder at path if it holds nothing."""
    try:
        os.rmdir(path)
    except OSError:
        pass


def main(argv=None):
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    if args.benchmark:
        return benchmark(args)
    ckpt_path = os.path.join(args.out, CKPT)
    log_path = os.path.join(args.out, "log.jsonl")
    if args.resume and not os.path.exists(ckpt_path):
        # Before the directory is made: a mistyped --out is left as it was.
        sys.exit(f"train.py: --resume: {args.out} holds no {CKPT}: name the --out of the run "
                 f"to take up, or leave out --resume to start a run there")
    if not os.path.exists(args.out):
        # A run refused before it wrote anything (its data unreadable, an
        # option wrong) leaves no empty --out behind: removed at exit when
        # nothing is in it (os.rmdir refuses a folder that is not empty).
        atexit.register(remove_if_empty, args.out)
    os.makedirs(args.out, exist_ok=True)

    if not args.resume and os.path.exists(ckpt_path):
        # A second run would overwrite the first's checkpoint and append to its log.
        sys.exit(f"train.py: --out {args.out} holds a run ({ckpt_path}): add --resume to take "
                 f"it up, or give another --out (or remove {args.out}) for a new run")
    ckpt = None
    if args.resume:
        try:
            ckpt = torch.load(ckpt_path, map_location="cpu")
            if not isinstance(ckpt, dict) or not isinstance(ckpt.get("args"), dict):
                raise ValueError("not a train.py checkpoint")
        except Exception as e:   # torch.load raises whatever its unpickler meets
            sys.exit(f"train.py: --resume: {ckpt_path} cannot be read ({type(e).__name__}: "
                     f"{e}): a file cut short or not train.py's; restore it, or start the run "
                     f"again into another --out")
        resume_options(args, ckpt["args"], given_options(argv), ckpt_path)
        # The log as the checkpoint left it: records written after it (a run
        # killed between a validation and the next checkpoint) are made again.
        with open(log_path + ".tmp", "w") as f:
            f.writelines(json.dumps(rec) + "\n" for rec in ckpt["history"])
        os.replace(log_path + ".tmp", log_path)
    elif os.path.exists(log_path):
        print(f"train.py: {log_path} of a run that saved no checkpoint: started anew",
              file=sys.stderr)
        os.remove(log_path)
    if args.export:
        # Checked now, not after the training it would have lost the
        # export of (the checkpoint stays, but the run ended in a traceback).
        where = os.path.dirname(os.path.abspath(args.export))
        if os.path.isdir(args.export) or args.export.endswith(os.sep):
            sys.exit(f"train.py: --export {args.export} is a directory: give the weights "
                     f"file's name (e.g. {os.path.join(args.export, 'mine.safetensors')})")
        try:
            os.makedirs(where, exist_ok=True)
        except OSError as e:
            sys.exit(f"train.py: --export {args.export}: cannot make {where}: {e.strerror}")
        if not os.access(where, os.W_OK):
            sys.exit(f"train.py: --export {args.export}: {where} is not writable")
    cfg = make_config(args)
    # The U-Net halves a crop once per level; a crop that does not divide
    # ended in a torch size mismatch after the frames had loaded.
    period = 2 ** len(cfg["levels"])
    if args.crop % period:
        sys.exit(f"train.py: --crop {args.crop}: {cfg['name']} halves the crop "
                 f"{len(cfg['levels'])} times, so it must be a multiple of {period}: use "
                 f"{max(period, args.crop // period * period)}")
    # The period of a U-Net's lattice: its upsamplings' total stride.
    lattice = (args.lattice_weight, 2 ** len(cfg["levels"]))
    lowpass = (args.lowpass_weight, args.lowpass_size)
    torch.manual_seed(args.seed)
    np_rng = np.random.default_rng(args.seed)
    random.seed(args.seed)
    device = pick_device(args.device)
    net = hfnet.HairNet(cfg).to(device)
    opt = torch.optim.Adam(net.parameters(), lr=args.lr)
    # The weights' moving average (--weight-ema): what is validated and
    # exported; the optimiser steps the raw weights.
    avg = None
    if args.weight_ema:
        d = args.weight_ema
        avg = torch.optim.swa_utils.AveragedModel(
            net, avg_fn=lambda a, w, n: d * a + (1 - d) * w)
    step, history, elapsed, ema = 0, [], 0.0, None
    train_set = None
    # The --init weights' input range, which the export joins: read when
    # they are loaded and kept in the checkpoint, so that a resumed run
    # exports without the file (moved or deleted since; it was read after
    # the whole run, a traceback there).
    init_range = None
    if args.init and not ckpt:
        try:
            icfg, state = hfnet.load_safetensors(args.init)
        except (OSError, ValueError) as e:
            sys.exit(f"train.py: --init: {file_error(e)}")
        why = init_mismatch(icfg, cfg)
        if why:
            sys.exit(f"train.py: --init {args.init} is {icfg['name']}, which cannot start "
                     f"--variant {cfg['name']}: {why}; give weights of {cfg['name']} (or of its "
                     f"architecture and inputs, narrower levels)")
        if icfg["levels"] != cfg["levels"]:
            fresh = hfnet.HairNet(dict(cfg, kernel_hidden=icfg.get("kernel_hidden", 0)))
            state = hfnet.widen_levels(state, icfg["levels"], fresh.state_dict())
            print(f"widened levels {icfg['levels']} -> {cfg['levels']} (same function)",
                  file=sys.stderr)
        ih = icfg.get("kernel_hidden", 0)
        ir = icfg.get("kernel_radius")
        if cfg["arch"] == "kernel" and (ir > cfg.get("kernel_radius") or ih > cfg.get("kernel_hidden", 0)):
            sys.exit(f"train.py: --init {args.init} has kernel_radius {ir}"
                     f" and kernel_hidden {ih}; this run needs at least that radius and at least"
                     f" as many hidden channels")
        if cfg["arch"] == "kernel" and ir < cfg["kernel_radius"]:
            state = hfnet.grow_kernel_radius(state, ir, cfg["kernel_radius"], ih)
            print(f"kernel_radius {ir} -> {cfg['kernel_radius']}: each new tap starts as its"
                  f" nearest old border tap less 4 in logit", file=sys.stderr)
        if cfg.get("kernel_mix") and not icfg.get("kernel_mix"):
            state = hfnet.add_kernel_mix(state, ih)
            print("added the kernel's mixing output (beta 0.05: the estimate's sums and a "
                  "twentieth of the samples')", file=sys.stderr)
        if cfg["arch"] == "kernel" and ih < cfg.get("kernel_hidden", 0):
            state = hfnet.widen_kernel_hidden(state, ih, net.state_dict())
            print(f"widened kernel_hidden {ih} -> {cfg['kernel_hidden']} (same function)",
                  file=sys.stderr)
        net.load_state_dict(state)
        print(f"initialised from {args.init}", file=sys.stderr)
        init_range = hfnet.load_metadata(args.init).get("input_range")
    if ckpt:
        if "init_range" in ckpt:
            init_range = ckpt["init_range"]
        elif args.init:   # a checkpoint from before it kept the range
            try:
                init_range = hfnet.load_metadata(args.init).get("input_range")
            except (OSError, ValueError) as e:
                print(f"train.py: warning: --init {file_error(e)}: its input range is not joined "
                      f"to the export's", file=sys.stderr)
        net.load_state_dict(ckpt["model"])
        opt.load_state_dict(ckpt["optimizer"])
        step, history, elapsed = ckpt["step"], ckpt["history"], ckpt.get("elapsed", 0.0)
        ema = ckpt.get("ema")
        if avg is not None:
            if ckpt.get("weight_ema") is None:
                sys.exit(f"train.py: --resume: {ckpt_path} holds no weight average")
            avg.load_state_dict(ckpt["weight_ema"])
        set_rng_state(np_rng, ckpt["rng"])
        print(f"resumed {cfg['name']} at step {step} from {ckpt_path}", file=sys.stderr)
    if args.equal_phase_sums and not ckpt:
        moved = hfnet.equalise_phase_sums_(net)
        print(f"equal phase sums: start weights moved by at most {moved:.3g}", file=sys.stderr)

    if step < args.steps:
        if not args.data:
            sys.exit("train.py: --data is required to train")
        styles = dataset.parse_styles(args.styles)

        def every_frame():
            return dataset.read_sets(args.data)

        def of_styles(found):
            return [e for e in found if e["style"] in styles] if styles else found

        every = every_frame()
        entries = of_styles(every)
        if not entries:
            have = ", ".join(sorted({e["style"] for e in every})) or "no frames"
            sys.exit(f"train.py: no frames of styles {args.styles} in {args.data} (it has "
                     f"{have}): name them with --styles, or --styles '' for every style")
        train_e, val_e = dataset.split_frames(entries, args.val_fraction)
        t0 = time.time()
        est = bool(cfg.get("estimate"))
        train_set = dataset.FrameSet(train_e, cfg["spp"], estimate=est)
        val_set = dataset.FrameSet(val_e, cfg["spp"], estimate=est) if val_e else None
        # A crop larger than a frame would be cut to the frame (the whole
        # frame, mostly background), and frames of several sizes would then
        # not stack into one batch.
        small = min(((min(t.shape[:2]), e["file"], t.shape[1], t.shape[0])
                     for fs in (train_set, val_set) if fs for t, e in zip(fs.tgts, fs.entries)))
        if args.crop > small[0]:
            sys.exit(f"train.py: --crop {args.crop} is larger than the smallest frame, {small[1]} "
                     f"({small[2]}x{small[3]}): crops must fit inside every frame; use --crop "
                     f"{small[0] // 16 * 16} or less")
        print(f"{cfg['name']}: {len(train_e)} training / {len(val_e)} validation frames "
              f"({', '.join(sorted(set(e['style'] for e in entries)))}), "
              f"{(train_set.nbytes() + (val_set.nbytes() if val_set else 0)) / 2**20:.0f} MiB, "
              f"loaded in {time.time() - t0:.1f} s; training on {device}", file=sys.stderr)

        mode = (args.deconv, args.bf16)
        # The looks' own generator (kept in the checkpoint, so that a resumed
        # run draws the looks an uninterrupted one would).
        look_gen = torch.Generator().manual_seed(args.seed + step)
        if ckpt and "look_rng" in ckpt:
            look_gen.set_state(ckpt["look_rng"])
        net.train()
        prog = Progress(args.steps, step)
        val = history[-1]["val"] if history else None
        window, norms = [], []
        t_start = time.time()
        stop = min(args.steps, args.stop_at) if args.stop_at > 0 else args.steps
        while step < stop:
            if args.schedule == "cosine":
                f = args.lr_floor + (1 - args.lr_floor) * 0.5 * (1 + math.cos(math.pi * step / args.steps))
                for g in opt.param_groups:
                    g["lr"] = args.lr * f
            if args.reload_every and step % args.reload_every == 0 and step > 0:
                # Frames rendered since the start join the training set (the
                # validation frames stay those chosen at the start).
                known = {e["file"] for e in train_set.entries}
                known.update(e["file"] for e in val_e)
                new = [e for e in of_styles(every_frame()) if e["file"] not in known]
                if new:
                    train_set.add(new)
                    print(f"\n{len(new)} new frames: {len(train_set)} training frames",
                          file=sys.stderr)
            x, y = train_set.batch(np_rng, args.crop, args.batch,
                                   dim=(args.dim_share if args.dim_light else 0.0,
                                        args.dim_light or 1.0))
            x, y = torch.from_numpy(x).to(device), torch.from_numpy(y).to(device)
            y = training_target(x, y, args.target, cfg["spp"])
            looks = random_looks(x.shape[0], look_gen) if args.loss == "look" else None
            looks = tuple(v.to(device) for v in looks) if looks else None
            loss = run_loss(args.loss, forward(net, x, *mode, straight_through=args.straight_through),
                            y, args.grad_weight, looks, args.ssim_weight, lattice,
                            (args.below_input_weight, x, cfg["spp"]),
                            display_st=args.display_straight_through, srgb=args.look_srgb,
                            l1=args.look_l1, lowpass=lowpass)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            # The norm before clipping, recorded with or without a clip: a run
            # that diverges shows its gradient spikes in the log.
            gn = float(torch.nn.utils.clip_grad_norm_(
                net.parameters(), args.clip_grad_norm if args.clip_grad_norm > 0 else math.inf))
            norms.append(gn)
            opt.step()
            if args.equal_phase_sums:
                hfnet.equalise_phase_sums_(net)
            if avg is not None:
                avg.update_parameters(net)
            step += 1
            lv = float(loss)
            if not math.isfinite(lv):
                sys.exit(f"train.py: loss is {lv} at step {step}")
            ema = lv if ema is None else 0.98 * ema + 0.02 * lv
            window.append(lv)
            out_of_time = args.time_limit and time.time() - t_start > args.time_limit
            last = step == stop or out_of_time
            if step % args.val_every == 0 or last:
                val = validate(averaged(net, avg), val_set, cfg["spp"], args.grad_weight, mode, device,
                               loss=args.loss, ssim_weight=args.ssim_weight,
                               lattice=lattice, below_weight=args.below_input_weight,
                               target=args.target, lowpass=lowpass)
                # loss: mean training loss since the previous record.
                rec = dict(step=step, loss=float(np.mean(window)), val=val,
                           time=elapsed + time.time() - t_start,
                           grad_norm=float(np.median(norms)))
                if args.clip_grad_norm > 0:
                    rec["clipped"] = float(np.mean(np.array(norms) > args.clip_grad_norm))
                window, norms = [], []
                history.append(rec)
                with open(log_path, "a") as f:
                    f.write(json.dumps(rec) + "\n")
            prog.update(step, ema, val, force=last)
            if step % args.ckpt_every == 0 or last:
                save_checkpoint(ckpt_path, model=net.state_dict(), optimizer=opt.state_dict(),
                                step=step, rng=rng_state(np_rng), look_rng=look_gen.get_state(),
                                args=saved_args(args),
                                history=history, elapsed=elapsed + time.time() - t_start, ema=ema,
                                config=cfg, init_range=init_range,
                                weight_ema=avg.state_dict() if avg is not None else None)
            if out_of_time:
                print(f"\ntime limit: stopped at step {step}; --resume continues", file=sys.stderr)
                break
        prog.close()
        elapsed += time.time() - t_start
        with open(os.path.join(args.out, "summary.json"), "w") as f:
            json.dump(dict(variant=cfg["name"], steps=step,
                           data=[os.path.abspath(d) for d in args.data.split(",") if d],
                           styles=args.styles, train_frames=len(train_set),
                           val_frames=len(val_e), batch=args.batch, crop=args.crop,
                           lr=args.lr, schedule=args.schedule, lr_floor=args.lr_floor,
                           grad_weight=args.grad_weight, loss=args.loss,
                           ssim_weight=args.ssim_weight,
                           lattice_weight=args.lattice_weight,
                           below_input_weight=args.below_input_weight, target=args.target,
                           lowpass_weight=args.lowpass_weight, lowpass_size=args.lowpass_size,
                           clip_grad_norm=args.clip_grad_norm,
                           dim_light=args.dim_light, dim_share=args.dim_share,
                           display_straight_through=args.display_straight_through,
                           look_srgb=args.look_srgb, look_l1=args.look_l1, seed=args.seed,
                           weight_ema=args.weight_ema,
                           deconv=args.deconv, bf16=args.bf16, init=args.init,
                           straight_through=args.straight_through,
                           equal_phase_sums=args.equal_phase_sums, train_seconds=elapsed,
                           last=history[-1] if history else None), f, indent=1)
        # No validation frames (one frame of the styles, --val-fraction 0):
        # said so, not as a "nan" that reads as a diverged run.
        said = f"{val:.6f}" if val is not None else "none (no validation frames)"
        print(f"{cfg['name']}: step {step}, loss {ema if ema is not None else float('nan'):.6f}, "
              f"validation {said}, {fmt_time(elapsed)} of training", file=sys.stderr)
    elif ckpt:
        print(f"{cfg['name']}: already at step {step} >= --steps {args.steps}", file=sys.stderr)

    if args.export:
        # The range of the frames trained on: measured while loading them, or
        # (a finished run resumed only to export) read again from --data.
        if train_set is not None:
            rng = input_stats.input_range(train_set.stats, cfg["spp"])
        elif args.data:
            rng = stamp_range.range_of_frames(
                stamp_range.training_frames(args.data, args.styles, args.val_fraction),
                cfg["spp"])
        else:
            rng = None
            print("train.py: no --data: exported without an input range", file=sys.stderr)
        # Weights that started from others (--init) learnt those frames too:
        # their range joins this run's, or a fine-tune on a few frames would
        # record only those, and a server would flag every other frame.
        if rng is not None and init_range:
            rng = input_stats.union_range(rng, json.loads(init_range))
        run_export = getattr(args, "run_export", None)
        export(averaged(net, avg), args.export, args.export_dtype, rng, step, args.steps,
               run_export[0] if run_export else None)
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except dataset.DatasetError as e:
        # A data directory or frame that cannot be used: its own words, no traceback.
        sys.exit(f"train.py: {e}")
