#!/usr/bin/python3
"""Trains only KernelMix's mixing output (the head's last row: 59 weights and
a bias, protocol/FEATURES.md "Mixing the two sums"), everything else of
the network as it is: where beta stays 0 the output cannot move, and what
the mix can gain on a kind of hair is measured apart from the rest.

    kernel_mix_beta_row.py --out NEW.safetensors [--weights KERNELMIX.safetensors]
        [--steps 600] [--lr 3e-3] [--batch 8] [--seed 1] [--threads 2] FRAME.exr|DIR ...

FRAME.exr|DIR: training frames with the alpha-corrected estimate (a
directory: its *.exr, as `render dataset` writes them). The network up to
the head is run once per frame and its output kept (the head's input, the
kernel's weighted sums of both estimates, the three corrections), so a
step costs the head's last row and the output stage only: whole frames,
not crops. The loss is train.py's --loss look --ssim-weight 0.01 with the
exact clamps (random looks per frame, the paper's term beside), Adam,
constant learning rate. NEW.safetensors: the input weights with that row
replaced, their metadata (input_range) kept. Prints the loss every 100
steps and beta's median over each frame's hair pixels before and after.
"""
import argparse
import glob
import os
import sys

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import dataset  # noqa: E402
import hfnet  # noqa: E402
import train  # noqa: E402


def frames_of(args):
    out = []
    for a in args:
        if os.path.isdir(a):
            found = sorted(glob.glob(os.path.join(a, "*.exr")))
            if not found:
                sys.exit(f"kernel_mix_beta_row.py: {a}: no .exr frames in it")
            out += found
        elif os.path.isfile(a):
            out.append(a)
        else:
            sys.exit(f"kernel_mix_beta_row.py: {a}: no such file or directory")
    return out


def cached(net, path):
    """What the head's mixing row and the output stage need of one frame,
    computed once: z, the head's input [1][59][h][w]; agg, the kernel-weighted
    sums of the samples (0:3) and of the estimate (3:6); corr, the three
    corrections; the truth [1][3][h][w]."""
    spp, radius = net.cfg["spp"], net.cfg["kernel_radius"]
    taps = hfnet.kernel_taps(radius)
    feat, truth = dataset.load_frame(path, spp=spp, dtype=np.float32)
    est = dataset.load_estimate(path, dtype=np.float32)
    h, w = feat.shape[:2]
    x = hfnet.nhwc_to_nchw(np.concatenate([feat.reshape(h, w, -1), est], -1)[None])
    with torch.no_grad():
        a = net.align
        xp = F.pad(x, (0, (-w) % a, 0, (-h) % a))
        z = net.head_input(net.decoded(xp), xp)[..., :h, :w].contiguous()
        raw = net.head(z)
        sums = torch.cat([hfnet.pixel_sums(x, spp), hfnet.estimate_sums(x, spp)], 1)
        agg = hfnet.kernel_aggregate(raw[:, :taps], sums, radius)
    g = torch.from_numpy(truth).permute(2, 0, 1)[None].contiguous()
    return {"z": z, "agg": agg, "corr": raw[:, taps:taps + 3], "truth": g, "path": path}


def output(d, w, b, spp):
    """The network's output [1][3][h][w] with mixing row (w, b)."""
    m = torch.einsum("c,nchw->nhw", w, d["z"])[:, None] + b
    return hfnet.kernel_mix_normalise(d["agg"], m, d["corr"], spp)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--weights", default=hfnet.bundled("kernel_mix.safetensors"),
        help="the KernelMix weights to start from (default: the bundled %(default)s)")
    ap.add_argument("--out", required=True,
                    help="where the weights with the trained row go (its directory must exist)")
    ap.add_argument("--steps", type=int, default=600, help="Adam steps (default %(default)s)")
    ap.add_argument("--lr", type=float, default=3e-3, help="learning rate (default %(default)s)")
    ap.add_argument("--batch", type=int, default=8, help="frames per step (default %(default)s)")
    ap.add_argument("--seed", type=int, default=1,
                    help="frame and look draws (default %(default)s)")
    ap.add_argument("--threads", type=int, default=2, help="PyTorch threads (default %(default)s)")
    ap.add_argument("frames", nargs="+", help="frames with the estimate, or directories of them")
    args = ap.parse_args()
    if args.steps < 1 or args.batch < 1 or not args.lr > 0:
        sys.exit("kernel_mix_beta_row.py: --steps and --batch take a count of at least 1, --lr "
                 "a positive rate")
    # The output is checked before the frames are read and trained on, so a
    # path that cannot be written does not cost the run.
    out_dir = os.path.dirname(os.path.abspath(args.out))
    if os.path.isdir(args.out) or not os.path.isdir(out_dir) or not os.access(out_dir, os.W_OK):
        sys.exit(f"kernel_mix_beta_row.py: --out {args.out}: "
                 + ("a directory: give a file name in it" if os.path.isdir(args.out)
                    else f"cannot write into {out_dir}: create it first (mkdir -p {out_dir})"))
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    net = hfnet.load_model_or_exit(args.weights, "kernel_mix_beta_row.py").eval()
    if not net.cfg.get("kernel_mix"):
        sys.exit(f"kernel_mix_beta_row.py: {args.weights} is not a KernelMix file (no kernel_mix "
                 "in its metadata)")
    spp, row = net.cfg["spp"], hfnet.kernel_taps(net.cfg["kernel_radius"]) + 3
    paths = frames_of(args.frames)
    try:
        data = [cached(net, p) for p in paths]
    except dataset.DatasetError as e:
        sys.exit(f"kernel_mix_beta_row.py: {e}")
    w0 = net.head.weight[row, :, 0, 0].detach().clone()
    b0 = net.head.bias[row].detach().clone()
    w, b = w0.clone().requires_grad_(True), b0.clone().requires_grad_(True)
    opt = torch.optim.Adam([w, b], lr=args.lr)
    gen = torch.Generator().manual_seed(args.seed)
    for step in range(1, args.steps + 1):
        pick = torch.randint(0, len(data), (args.batch,), generator=gen).tolist()
        looks = train.random_looks(args.batch, gen)
        opt.zero_grad()
        loss = 0
        for k, i in enumerate(pick):
            pred, _ = output(data[i], w, b, spp)
            look = tuple(v[k:k + 1] for v in looks)
            loss = loss + train.look_loss(pred, data[i]["truth"], look, ssim_weight=0.01)
        loss = loss / args.batch
        loss.backward()
        opt.step()
        if step % 100 == 0 or step == args.steps:
            print(f"step {step}: loss {loss.item():.6f}", flush=True)
    print("| frame | beta p50 before | beta p50 after |\n|---|---:|---:|")
    with torch.no_grad():
        for d in data:
            hair = d["truth"][:, 2:3] > 0.01
            if not hair.any():
                continue
            _, before = output(d, w0, b0, spp)
            _, after = output(d, w.detach(), b.detach(), spp)
            print(f"| {d['path']} | {before[hair].median().item():.3f} | "
                  f"{after[hair].median().item():.3f} |")
    state = {k: v.clone() for k, v in net.state_dict().items()}
    state["head.weight"][row, :, 0, 0] = w.detach()
    state["head.bias"][row] = b.detach()
    meta = {k: v for k, v in hfnet.load_metadata(args.weights).items() if k != "hairfilter"}
    hfnet.save_safetensors(args.out, net.cfg, state, metadata=meta)
    print(f"wrote {args.out}: {args.weights} with the mixing row trained on {len(data)} frames, "
          f"{args.steps} steps", file=sys.stderr)


if __name__ == "__main__":
    main()
