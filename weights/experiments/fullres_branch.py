"""A full-resolution branch for the Kernel architecture, measured against it
and not part of any backend (weights/kernel.md says what it scored).

The U-Net's first convolution has stride 2, so the only layers that see a
pixel's neighbours at full resolution are dec0 (from half-resolution
features) and nothing else: the head is a 1x1 convolution over ReLU(dec0)
and the pixel's own samples. Where strands are about a pixel wide, what
separates one strand from the next lies inside that half-resolution step.
The branch adds a 3x3 convolution, stride 1, over the input features
(`fullres` output channels, ReLU), whose output joins the head's input:

  head(cat[ReLU(dec0), input, GAIN x ReLU(full(input))])

GAIN (a constant, foldable into the head's weights) makes the head's new
columns move GAIN times as fast under Adam, whose steps are about lr in
each weight whatever the gradient's scale: from zero at lr 3e-4 they would
stay near zero over a fine-tune of a thousand steps.

Its cost at 16 channels is about a quarter more of the network's
multiply-adds per pixel (24 x 9 x 16 for the convolution, 16 x 52 more in the head, against
about 18,000 for Kernel).

Weights start from Kernel weights with the head's columns for the branch at
zero, which computes the same function (start_from_kernel); the branch's
convolution starts random. Usage, from the repository root:

  python3 weights/experiments/fullres_branch.py init OUT.safetensors [KERNEL.safetensors] [--channels 16]
  python3 weights/experiments/fullres_branch.py train <weights/train.py arguments>

`train` runs weights/train.py with the branch installed (--variant Kernel,
--init the file of `init`); weights/experiments/eval_rows.py --stage
fullres scores the result with `hairfilter eval`. The C backends refuse
these files (the head's shape does not match the configuration they
know)."""
import json
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import torch  # noqa: E402
import torch.nn as nn  # noqa: E402
import torch.nn.functional as F  # noqa: E402

import hfnet  # noqa: E402
import patching  # noqa: E402

CHANNELS = 16
GAIN = 8.0

_HairNet = patching.ORIGINAL["HairNet"]


class FullResNet(_HairNet):
    """hfnet.HairNet with the branch when cfg["fullres"] > 0 (Kernel with a
    head only); otherwise the same network."""

    def __init__(self, cfg):
        super().__init__(cfg)
        self.fullres = cfg.get("fullres", 0) if self.hidden else 0
        if self.fullres:
            cin = cfg["in_channels"]
            self.full = nn.Conv2d(cin, self.fullres, 3, padding=1)
            self.head = nn.Conv2d(self.hidden + cin + self.fullres, cfg["out_channels"], 1)

    def apply_head(self, y, inp):
        if not self.fullres:
            return super().apply_head(y, inp)
        inp = inp.to(y.dtype)
        return self.head(torch.cat([F.relu(y), inp, GAIN * F.relu(self.full(inp))], dim=1))


def install(channels=CHANNELS):
    """Makes hfnet build Kernel networks with the branch (`channels` wide);
    weights without a `fullres` entry keep the plain network."""
    patching.install(lambda cfg: {"fullres": channels}, HairNet=FullResNet)


uninstall = patching.uninstall


def start_from_kernel(cfg, state, channels=CHANNELS, seed=1):
    """(cfg, state) of Kernel weights with the branch added: its convolution
    random (seeded), the head's weights for it zero, so the same function."""
    cfg = dict(cfg, fullres=channels)
    torch.manual_seed(seed)
    fresh = FullResNet(cfg).state_dict()
    state = dict(state)
    w = state["head.weight"]                     # [out][hidden + in][1][1]
    state["head.weight"] = torch.cat([w, w.new_zeros(w.shape[0], channels, 1, 1)], 1)
    state["full.weight"], state["full.bias"] = fresh["full.weight"], fresh["full.bias"]
    return cfg, state


def main(argv):
    if len(argv) < 2 or argv[0] not in ("init", "train"):
        sys.exit(__doc__)
    args = list(argv[1:])
    if argv[0] == "init":
        channels = CHANNELS
        if "--channels" in args:
            i = args.index("--channels")
            channels = int(args[i + 1])
            del args[i:i + 2]
    else:
        init = args[args.index("--init") + 1] if "--init" in args else None
        # The header alone: hfnet.load_safetensors checks the tensors against
        # the network, which has no branch until install() below.
        channels = (json.loads(hfnet.load_metadata(init)["hairfilter"]).get("fullres", CHANNELS)
                    if init else CHANNELS)
    install(channels)
    return patching.init_or_train(argv[0], args,
                                  lambda cfg, state: start_from_kernel(cfg, state, channels=channels))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
