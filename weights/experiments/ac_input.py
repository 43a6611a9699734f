"""Kernel networks that also read stochastic transparency's alpha-corrected
estimate (`hairfilter render --alpha-corrected`, channels acst4.*: Enderton
et al. 2010, exact alpha, colour weighted by each fragment's visibility in
the 4 depth samples) and filter it instead of the samples' sums.

The estimate travels as a fifth sample slot [colour, highlight, alpha, 0, 0,
0] after the spp samples, so the configuration says spp + 1 samples (and
(spp + 1) x 6 input channels); augmentation permutes the real samples only.
The output stage is Kernel's (hfnet.kernel_finish) with each tap's sums
taken from the estimate (premultiplied) instead of the samples: alpha =
sum w a, colour = sum w a c / sum w a, highlight = sum w a h / sum w a,
then the corrections.

  python3 weights/experiments/ac_input.py init OUT.safetensors [KERNEL]
      # Kernel weights (default weights/kernel.safetensors) with zero weights
      # on the new inputs: the same U-Net, the estimate filtered by its kernel
  python3 weights/experiments/ac_input.py train ARGS...   # weights/train.py's
  python3 weights/experiments/ac_input.py export IN.safetensors OUT.safetensors
      # the KernelAC variant every backend runs (hfnet.variant_config
      # "KernelAC": the estimate as 3 input channels after the samples, the
      # slot's 3 always-zero inputs dropped): the same function

Frames need the acst4.* channels (dataset.DatasetError otherwise). No
backend runs these networks as they are; eval_rows.py --stage ac scores them,
and `export` makes them the KernelAC variant the backends run."""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import numpy as np  # noqa: E402
import torch  # noqa: E402

import dataset  # noqa: E402
import hfnet  # noqa: E402
import patching  # noqa: E402

NF = len(hfnet.FEATURES)
CHANNELS = ["acst4.color", "acst4.highlight", "acst4.alpha"]
ORIGINAL_LOAD, ORIGINAL_AUGMENT = dataset.load_frame, dataset.augment


def load_frame(path, spp=None, dtype=np.float16):
    """dataset.load_frame with the estimate as one more sample slot: features
    [h][w][samples + 1][6]; spp counts the slot (a file's samples + 1)."""
    feat, tgt = ORIGINAL_LOAD(path, None if spp is None else spp - 1, np.float32)
    names, data = dataset.read_exr(path)
    if any(c not in names for c in CHANNELS):
        raise dataset.DatasetError(f"{path}: no acst4.* channels: render it with "
                                   f"`hairfilter render ... --alpha-corrected`")
    ac = dataset.pick_channels(names, data, CHANNELS, path)
    slot = np.zeros(feat.shape[:2] + (1, NF), np.float32)
    slot[:, :, 0, :3] = ac
    return np.concatenate([feat, slot], axis=2).astype(dtype), tgt.astype(dtype)


def augment(feat, tgt, rng, flips=True, rotations=True, permute=True):
    """dataset.augment with the last slot (the estimate) kept last."""
    feat, tgt = ORIGINAL_AUGMENT(feat, tgt, rng, flips, rotations, permute=False)
    n = feat.shape[2] - 1
    if permute and n > 1:
        order = np.concatenate([rng.permutation(n), [n]])
        feat = np.ascontiguousarray(feat[:, :, order])
    return feat, tgt


def kernel_finish(raw, x, spp, radius, clamp=torch.clamp):
    """Kernel's output stage over the estimate: x holds spp - 1 samples and
    the estimate's slot last (see the module's docstring). The estimate is
    handed to hfnet.kernel_finish_sums as n samples that all show it: count
    n a, colour sum n a c, highlight sum n a h."""
    n = spp - 1
    o = NF * n
    c, h, a = (x[:, o + k:o + k + 1].float() for k in range(3))
    sums = torch.cat([n * a, n * a * c, n * a * h], 1)
    return hfnet.kernel_finish_sums(raw, sums, n, radius, clamp)


def entries(cfg):
    return {"spp": cfg["spp"] + 1, "in_channels": (cfg["spp"] + 1) * NF, "ac_input": 1}


def install():
    patching.install(entries, kernel_finish=kernel_finish)
    dataset.load_frame = load_frame
    dataset.augment = augment


def uninstall():
    patching.uninstall()
    dataset.load_frame = ORIGINAL_LOAD
    dataset.augment = ORIGINAL_AUGMENT


def start_from_kernel(cfg, state):
    """Kernel weights cfg/state with the estimate's 6 input channels added at
    zero weight in enc0 and in the head."""
    if cfg.get("arch") != "kernel" or cfg.get("ac_input"):
        raise ValueError("start from plain Kernel weights")
    cfg = dict(cfg, **entries(cfg))
    state = dict(state)
    w = state["enc0.weight"]
    state["enc0.weight"] = torch.cat([w, w.new_zeros(w.shape[0], NF, *w.shape[2:])], 1)
    if "head.weight" in state:
        w = state["head.weight"]
        state["head.weight"] = torch.cat([w, w.new_zeros(w.shape[0], NF, *w.shape[2:])], 1)
    return cfg, state


def to_variant(cfg, state):
    """Experiment weights (cfg with ac_input) as hfnet's KernelAC: enc0's and
    the head's input columns of the slot's depth and tangents (inputs that
    are always 0) dropped, so the input is the samples then the estimate's
    colour, highlight, alpha (in_channels spp x 6 + 3)."""
    if not cfg.get("ac_input"):
        raise ValueError("not weights of this experiment (no 'ac_input' in the metadata)")
    spp = cfg["spp"] - 1
    keep = list(range(spp * NF + 3))
    out = patching.ORIGINAL["variant_config"]("KernelAC")   # installed or not
    for key in ("kernel_radius", "kernel_hidden", "levels", "out_channels"):
        if cfg[key] != out[key]:
            raise ValueError(f"{key} {cfg[key]} is not KernelAC's {out[key]}")
    state = dict(state)
    state["enc0.weight"] = state["enc0.weight"][:, keep].clone()
    if "head.weight" in state:
        hidden = cfg["kernel_hidden"]
        cols = list(range(hidden)) + [hidden + k for k in keep]
        state["head.weight"] = state["head.weight"][:, cols].clone()
    return out, state


def main(argv):
    if argv in (["-h"], ["--help"]):
        print(__doc__)
        return 0
    if len(argv) == 3 and argv[0] == "export":
        cfg, state = to_variant(*hfnet.load_safetensors(argv[1]))
        meta = {k: v for k, v in hfnet.load_metadata(argv[1]).items() if k != "hairfilter"}
        hfnet.save_safetensors(argv[2], cfg, state, metadata=meta)
        return 0
    if len(argv) < 2 or argv[0] not in ("init", "train"):
        sys.exit(__doc__)
    install()
    return patching.init_or_train(argv[0], argv[1:], start_from_kernel)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
