"""Base weights with a full-resolution carry: the paper's network, unchanged
in shape, started so that its first skip connection hands each pixel's own
samples to the output (weights/base.md, "A full-resolution carry").

Base's first convolution has stride 2 (enc0: 3x3, stride 2, 32 channels), so
its output is computed from half-resolution features only: dec0, a 4x4
transposed convolution of stride 2, over cat[dec1, enc0]. That path can
still hold every pixel: enc0 at half-resolution position (i, j) reads input
rows 2i-1..2i+1 and columns 2j-1..2j+1, so 4 x 3 of its channels can carry
the mean over the samples of colour, highlight and alpha of the 2x2 pixels
(2i+a, 2j+b), a, b in {0, 1} (tap (1+a, 1+b)); dec0's tap (1+a, 1+b) of the
same position puts them back on those pixels (a transposed convolution of
stride 2 reaches output 2i+a from input i through tap a+1). Trained, the
network does not use such a path (Base stays below its own samples on
opaque frames, where they are close to the truth); this script builds it
into trained weights:

1. measures, on crops of the given frames, how much each enc0 channel adds
   (the error of the output, colour x alpha, highlight x alpha and alpha,
   when the channel is zeroed), and takes the 12 that add least;
2. makes them the carry (enc0 weights 1/spp on the taps above, bias 0) and
   zeroes enc1's weights from them, so the deeper levels see what they saw
   with those channels switched off;
3. refits dec0 (weights and bias) by weighted least squares on the same
   crops, in the output's pre-transform space: colour through the inverse of
   the paper's cubic (section 3.3.2, hfnet.output_transform) weighted by the
   truth's alpha and the cubic's slope squared, highlight weighted by the
   truth's alpha, alpha unweighted; then twice more without the pixels
   where the truth sits at a clamp's bound and the fit is beyond it (no
   error after the clamp). dec0 is linear in its weights, so each fit is
   exact for the crops given.

Measured (weights/base.md, "A full-resolution carry"): the carry costs more
than it brings. On the crops it was fitted on, the graft's output error is
above that of the weights it started from (the script prints both), and a
fine-tune from the graft stays below one from those weights on the same
steps, on opaque frames too. The script stays as the record of that
measurement.

The result is a plain Base file (same configuration, tensor names and
shapes; the input range of the weights it started from) that every backend
runs; weights/train.py --init takes it for a fine-tune. Usage, from the
repository root:

  /usr/bin/python3 weights/experiments/base_carry.py BASE.safetensors OUT.safetensors \
      --data data/a,data/b [--crops 256] [--seed 1]
"""
import argparse
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import numpy as np  # noqa: E402
import torch  # noqa: E402
import torch.nn.functional as F  # noqa: E402

import dataset  # noqa: E402
import hfnet  # noqa: E402

CARRIED = (0, 1, 2)          # colour, highlight, alpha (protocol/FEATURES.md)
# (input offset, tap) per output phase: output 2i+a reads input i through
# tap a+1, and input i-1 (a = 0) through tap 3 or input i+1 (a = 1) through 0.
PHASE_TAPS = {0: ((0, 1), (-1, 3)), 1: ((0, 2), (1, 0))}


def color_preactivation(c):
    """The x with x^3/32 + x/5 + 1 = c (the inverse of the paper's colour
    transform; one real root, the cubic rises everywhere), by Cardano."""
    p, q = 32.0 / 5.0, 32.0 * (1.0 - c)
    r = np.sqrt(q * q / 4 + p ** 3 / 27)
    return np.cbrt(-q / 2 + r) + np.cbrt(-q / 2 - r)


def decoder_input(net, x):
    """cat[dec1, enc0] (dec0's input) of NCHW input x, and enc0 alone (its
    last channels), taken from HairNet.raw's own pass by a hook on dec0."""
    seen = []
    hook = net.dec0.register_forward_pre_hook(lambda m, args: seen.append(args[0]))
    try:
        net.raw(x)
    finally:
        hook.remove()
    z = seen[0]
    return z, z[:, z.shape[1] - net.enc0.out_channels:]


def targets(t):
    """Pre-transform targets [n][3][h][w] and their weights, of NCHW truth t."""
    tc = t.numpy()
    alpha = tc[:, 2]
    xc = color_preactivation(tc[:, 0].astype(np.float64))
    slope = 3 * xc * xc / 32 + 0.2
    tgt = np.stack([xc, tc[:, 1], alpha], 1)
    wgt = np.stack([alpha * slope * slope, alpha, np.ones_like(alpha)], 1)
    return tgt, wgt


def phase_taps(a, b):
    """dec0's (input offset y, input offset x, tap y, tap x) for the output
    pixels (2i+a, 2j+b), the 2x2 pairs in the order design() lays them."""
    return [(dy, dx, ky, kx) for dy, ky in PHASE_TAPS[a] for dx, kx in PHASE_TAPS[b]]


def design(z, a, b):
    """The values dec0 combines for the output pixels (2i+a, 2j+b): for each
    of phase_taps(a, b), z shifted by its offset ([n][h/2][w/2][4 *
    channels]), and those pairs' taps."""
    n, c, h, w = z.shape
    zp = F.pad(z, (1, 1, 1, 1))
    pairs = phase_taps(a, b)
    cols = [zp[:, :, 1 + dy:1 + dy + h, 1 + dx:1 + dx + w] for dy, dx, _, _ in pairs]
    taps = [(ky, kx) for _, _, ky, kx in pairs]
    return torch.cat(cols, 1).permute(0, 2, 3, 1).numpy().astype(np.float64), taps


# Output channels clamped below and above (hfnet.output_transform): where the
# truth sits at a bound and the fit is beyond it, the output has no error.
CLAMPS = {1: (0.0, None), 2: (0.0, 1.0)}


def refit_dec0(net, batches, ridge=1e-6, rounds=3):
    """Weighted least squares for dec0's weights and bias (see the module).
    The clamped outputs are fitted again `rounds` - 1 times without the
    pixels where the truth sits at a bound and the previous fit is beyond
    it (no error after the clamp)."""
    dec0 = net.dec0
    cin, cout = dec0.weight.shape[:2]
    m = 4 * 4 * cin + 1                       # four phases' weights, one shared bias
    with torch.no_grad():
        cached = [(decoder_input(net, x)[0], targets(t)) for x, t in batches]
    sol = None
    for _ in range(rounds):
        gram = np.zeros((cout, m, m))
        rhs = np.zeros((cout, m))
        for z, (tgt, wgt) in cached:
            for a in (0, 1):
                for b in (0, 1):
                    d, _ = design(z, a, b)
                    d = d.reshape(-1, 4 * cin)
                    ph = (2 * a + b) * 4 * cin
                    for o in range(cout):
                        y = tgt[:, o, a::2, b::2].reshape(-1)
                        w = wgt[:, o, a::2, b::2].reshape(-1)
                        if sol is not None and o in CLAMPS:
                            pred = d @ sol[o][ph:ph + 4 * cin] + sol[o][-1]
                            lo, hi = CLAMPS[o]
                            off = (y <= lo) & (pred <= lo)
                            if hi is not None:
                                off |= (y >= hi) & (pred >= hi)
                            w = np.where(off, 0.0, w)
                        dw = d * w[:, None]
                        g = gram[o]
                        g[ph:ph + 4 * cin, ph:ph + 4 * cin] += d.T @ dw
                        g[ph:ph + 4 * cin, -1] += dw.sum(0)
                        g[-1, ph:ph + 4 * cin] += dw.sum(0)
                        g[-1, -1] += w.sum()
                        rhs[o, ph:ph + 4 * cin] += dw.T @ y
                        rhs[o, -1] += (w * y).sum()
        sol = [np.linalg.solve(gram[o] + ridge * np.trace(gram[o]) / m * np.eye(m), rhs[o])
               for o in range(cout)]
    weight = torch.zeros_like(dec0.weight)
    bias = torch.zeros_like(dec0.bias)
    for o in range(cout):
        for a in (0, 1):
            for b in (0, 1):
                ph = (2 * a + b) * 4 * cin
                for s_, (_, _, ky, kx) in enumerate(phase_taps(a, b)):
                    weight[:, o, ky, kx] = torch.from_numpy(
                        sol[o][ph + s_ * cin:ph + (s_ + 1) * cin])
        bias[o] = float(sol[o][-1])
    with torch.no_grad():
        dec0.weight.copy_(weight)
        dec0.bias.copy_(bias)


def output_error(net, batches, drop=None):
    """Squared error of the output against the truth, summed over the crops
    (colour x alpha, highlight x alpha and alpha, as the composite weighs
    them), with enc0 channel `drop` zeroed (None: none)."""
    total = 0.0
    for x, t in batches:
        with torch.no_grad():
            z, _ = decoder_input(net, x)
            if drop is not None:
                z[:, z.shape[1] - net.enc0.out_channels + drop] = 0
            y = hfnet.output_transform(
                F.conv_transpose2d(z, net.dec0.weight, net.dec0.bias, stride=2, padding=1))
        a, ta = y[:, 2], t[:, 2]
        total += float(((y[:, 0] * a - t[:, 0] * ta) ** 2 + (y[:, 1] * a - t[:, 1] * ta) ** 2
                        + (a - ta) ** 2).sum())
    return total


def graft(net, batches, channels, spp):
    """Steps 1-3 of the module on net (a Base HairNet), in place, with
    `channels` = 4 x len(CARRIED); returns the enc0 channels made into the
    carry and each enc0 channel's cost (output_error's rise when zeroed)."""
    base = output_error(net, batches)
    cost = [output_error(net, batches, c) - base for c in range(net.enc0.out_channels)]
    chosen = sorted(int(c) for c in np.argsort(cost)[:channels])
    nfeat = len(hfnet.FEATURES)
    with torch.no_grad():
        for k, c in enumerate(chosen):
            pix, feat = divmod(k, len(CARRIED))
            a, b = divmod(pix, 2)
            net.enc0.weight[c].zero_()
            net.enc0.bias[c] = 0
            for s in range(spp):
                net.enc0.weight[c, s * nfeat + CARRIED[feat], 1 + a, 1 + b] = 1.0 / spp
            net.enc1.weight[:, c] = 0
    refit_dec0(net, batches)
    return chosen, cost


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("base")
    ap.add_argument("out")
    ap.add_argument("--data", required=True, help="dataset directories, comma-separated")
    ap.add_argument("--crops", type=int, default=256, help="128x128 crops to fit on")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    cfg, sd = hfnet.load_safetensors(args.base)
    if cfg.get("arch", "unet") != "unet":
        sys.exit(f"{args.base}: arch {cfg.get('arch')}: the carry is for the paper's U-Net")
    net = hfnet.HairNet(cfg)
    net.load_state_dict(sd)
    net.eval()
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    entries = dataset.read_sets(args.data.split(","))
    frames = dataset.FrameSet(entries, cfg["spp"])
    batches = []
    for _ in range(0, args.crops, 16):
        x, t = frames.batch(rng, 128, 16)
        batches.append((torch.from_numpy(x), torch.from_numpy(t)))
    before = output_error(net, batches)
    chosen, _ = graft(net, batches, 4 * len(CARRIED), cfg["spp"])
    after = output_error(net, batches)
    print(f"carry channels {chosen}; output error on {args.crops} crops of {len(frames)} "
          f"frames: {before:.6g} before, {after:.6g} after")
    meta = {k: v for k, v in hfnet.load_metadata(args.base).items() if k != "hairfilter"}
    hfnet.save_safetensors(args.out, cfg, net.state_dict(), metadata=meta)


if __name__ == "__main__":
    main()
