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
import struct

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
}
TABLE1 = ["Base", "Base@1spp", "Base@2spp", "Large", "Small", "Shallow", "Deep"]


def variant_config(name):
    """Metadata dict of a Table 1 variant, as stored in the weights file."""
    for key, v in VARIANTS.items():
        if key.lower() == name.lower():
            return dict(name=key, arch=v.get("arch", "unet"), spp=v["spp"],
                        in_channels=v["spp"] * len(FEATURES),
                        levels=list(v["levels"]), out_channels=len(OUTPUTS),
                        features=list(FEATURES))
    raise KeyError(f"unknown variant {name!r}; known: {', '.join(VARIANTS)}")


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


def residual_base(x, spp):
    """Stochastic-transparency estimate over the 5x5 window around each pixel
    of NCHW features x (the frame, unpadded): covered fraction of the
    window's samples as alpha, mean colour and highlight of the covered ones
    (colour 1 where none is); src/net_config.c hf_residual_base."""
    n, _, h, w = x.shape
    s = x.view(n, spp, len(FEATURES), h, w)
    cov = (s[:, :, 2] > 0).to(x.dtype)
    cnt = _box_sum(cov.sum(1, keepdim=True))
    col = _box_sum((s[:, :, 0] * cov).sum(1, keepdim=True))
    hl = _box_sum((s[:, :, 1] * cov).sum(1, keepdim=True))
    samples = _box_sum(x.new_ones(1, 1, h, w)) * spp
    safe = torch.clamp(cnt, min=1)
    color = torch.where(cnt > 0, col / safe, torch.ones_like(cnt))
    return torch.cat([color, hl / safe, cnt / samples], dim=1)


def residual_finish(raw, base, clamp=torch.clamp):
    color = base[:, 0:1] + raw[:, 0:1]
    highlight = clamp(base[:, 1:2] + raw[:, 1:2], 0, None)
    alpha = clamp(base[:, 2:3] + raw[:, 2:3], 0, 1)
    return torch.cat([color, highlight, alpha], dim=1)


class HairNet(nn.Module):
    def __init__(self, cfg):
        super().__init__()
        self.cfg = dict(cfg)
        self.arch = cfg.get("arch", "unet")
        if self.arch not in ("unet", "residual"):
            raise ValueError(f"unknown arch {self.arch!r}")
        lv = cfg["levels"]
        L = len(lv)
        self.levels = L
        for i in range(L):
            cin = cfg["in_channels"] if i == 0 else lv[i - 1]
            self.add_module(f"enc{i}", nn.Conv2d(cin, lv[i], 3, stride=2, padding=1))
        for i in range(L):
            cin = lv[i] if i == L - 1 else 2 * lv[i]
            cout = cfg["out_channels"] if i == 0 else lv[i - 1]
            self.add_module(f"dec{i}", nn.ConvTranspose2d(cin, cout, 4, stride=2, padding=1))

    @property
    def align(self):
        return 1 << self.levels

    def raw(self, x):
        """The network without output transforms; x is NCHW, sides multiples
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

    def forward(self, x):
        """NCHW input of any size: zero-padded right/bottom to a multiple of
        2^L, output cropped back, output transforms applied."""
        h, w = x.shape[-2:]
        a = self.align
        ph, pw = (-h) % a, (-w) % a
        raw = self.raw(F.pad(x, (0, pw, 0, ph)) if ph or pw else x)[..., :h, :w]
        return self.finish(raw, x)

    def finish(self, raw, x, clamp=torch.clamp):
        """The architecture's output stage on raw output raw of the unpadded
        input x (same size)."""
        if self.arch == "residual":
            return residual_finish(raw, residual_base(x, self.cfg["spp"]), clamp)
        return output_transform(raw, clamp)


# ---- safetensors ----------------------------------------------------------

_DTYPES = {"F32": (np.float32, 4), "F16": (np.float16, 2)}


def save_safetensors(path, cfg, state_dict, dtype="F32", metadata=None):
    """Writes state_dict with the hairfilter metadata (weights/FORMAT.md);
    metadata: more string entries, e.g. {"input_range": json_text}."""
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
    with open(path, "wb") as f:
        f.write(struct.pack("<Q", len(h)))
        f.write(h)
        for b in blobs:
            f.write(b)


def load_metadata(path):
    """The header's __metadata__ map (strings) of a safetensors file."""
    with open(path, "rb") as f:
        (n,) = struct.unpack("<Q", f.read(8))
        return json.loads(f.read(n)).get("__metadata__", {})


def load_safetensors(path):
    """Returns (cfg, state_dict of float32 tensors)."""
    with open(path, "rb") as f:
        data = f.read()
    (n,) = struct.unpack("<Q", data[:8])
    if n > len(data) - 8:
        raise ValueError(f"{path}: header length {n} exceeds file size")
    header = json.loads(data[8:8 + n])
    cfg = json.loads(header.pop("__metadata__")["hairfilter"])
    base = 8 + n
    sd = {}
    for name, t in header.items():
        np_dtype, _ = _DTYPES[t["dtype"]]
        b, e = t["data_offsets"]
        a = np.frombuffer(data[base + b:base + e], dtype=np_dtype).reshape(t["shape"])
        sd[name] = torch.from_numpy(a.astype(np.float32))
    return cfg, sd


def load_model(path):
    cfg, sd = load_safetensors(path)
    net = HairNet(cfg)
    net.load_state_dict(sd)
    return net


# ---- layouts --------------------------------------------------------------

def nhwc_to_nchw(a):
    return torch.from_numpy(np.ascontiguousarray(a)).permute(0, 3, 1, 2).contiguous()


def nchw_to_nhwc(t):
    return t.permute(0, 2, 3, 1).contiguous().numpy()
