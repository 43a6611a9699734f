"""Input statistics of a frame of features, and the range of them over a
variant's training frames: the numpy twin of src/input_stats.c (the
definitions are in protocol/FEATURES.md, "Input statistics"). The values are
bit for bit those of the C code, so a range recorded here when the weights
are made is checked by hairfilterd and the CLI against the same numbers.

    stats = frame_stats(features)          # features [h][w][spp][6] or [h][w][spp*6]
    rng = input_range([stats, ...], spp)   # -> the weights' input_range metadata

Only numpy is needed.
"""
import json

import numpy as np

DEFINITION = 1   # HF_INPUT_STATS_DEFINITION
STATS = ["strand_alpha_p50", "strand_alpha_p90", "full_coverage", "hair_fraction", "long_side"]
FEATURES = 6
ALPHA = 2

# The histogram of src/input_stats.c: bin 0 below 2^-16, then the top 16
# bits of the float (128 bins per octave) up to 1, then everything from 1.
_LOW_KEY = 111 << 7
_NBINS = 2 + (127 << 7) - _LOW_KEY


def _bins(v):
    """Bin of each positive float32 value."""
    key = (np.ascontiguousarray(v, np.float32).view(np.uint32) >> 16).astype(np.int64)
    return np.clip(key - _LOW_KEY + 1, 0, _NBINS - 1)


def _bin_value(b):
    """Lower edge of bin b, the value a percentile falling in it reports."""
    if b == 0:
        return 0.0
    if b == _NBINS - 1:
        return 1.0
    return float(np.array([(b - 1 + _LOW_KEY) << 16], np.uint32).view(np.float32)[0])


def strand_alpha(features, spp=None):
    """Per pixel: mean alpha of the covered (alpha > 0) samples, summed in
    sample order in float32 as the C code does (0 where none is covered),
    and the number of covered samples. features: [h][w][spp][6] or
    [h][w][spp*6] (float16 is widened exactly)."""
    f = np.asarray(features)
    if f.ndim == 3:
        f = f.reshape(f.shape[0], f.shape[1], -1, FEATURES)
    if spp is not None:
        f = f[:, :, :spp]
    a = f[..., ALPHA].astype(np.float32)
    covered = a > 0
    total = np.zeros(a.shape[:2], np.float32)
    for k in range(a.shape[2]):   # one add per sample, in order: no pairwise sums
        total = total + np.where(covered[..., k], a[..., k], np.float32(0))
    n = covered.sum(axis=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(n > 0, total / np.maximum(n, 1).astype(np.float32), np.float32(0))
    return mean.astype(np.float32), n


def frame_stats(features, spp=None):
    """The statistics of one frame (dict keyed by STATS, NaN where undefined)
    plus hair_pixels and full_pixels, as hf_input_stats_compute."""
    f = np.asarray(features)
    if f.ndim == 3:
        f = f.reshape(f.shape[0], f.shape[1], -1, FEATURES)
    spp = f.shape[2] if spp is None else spp
    h, w = f.shape[:2]
    mean, n = strand_alpha(f, spp)
    hair = n > 0
    nh = int(hair.sum())
    out = {"hair_pixels": nh, "full_pixels": int((n == spp).sum()),
           "hair_fraction": nh / float(h * w), "long_side": float(max(w, h))}
    if nh:
        b = np.sort(_bins(mean[hair]))
        out["strand_alpha_p50"] = _bin_value(int(b[(nh + 1) // 2 - 1]))
        out["strand_alpha_p90"] = _bin_value(int(b[(9 * nh + 9) // 10 - 1]))
        out["full_coverage"] = out["full_pixels"] / float(nh)
    else:
        out["strand_alpha_p50"] = out["strand_alpha_p90"] = out["full_coverage"] = float("nan")
    return out


# The statistics a trained range records: all but long_side. The networks
# are fully convolutional and train on crops, so a pixel's result depends on
# the samples around it, not on the size of the frame; what a resolution does
# change (strands' width in pixels, full coverage, hair's share of the frame)
# the other four measure. Recorded, long_side would flag every frame larger
# than the largest the crops were cut from, whatever its hair: every
# 1920x1080 frame, for weights trained on frames up to 1024 wide.
RANGE_STATS = [k for k in STATS if k != "long_side"]


def input_range(stats, spp):
    """The `input_range` metadata (weights/FORMAT.md) over a list of
    frame_stats: [min, max] of each statistic of RANGE_STATS over the frames
    where it is defined (a statistic no frame defines is left out)."""
    if not stats:
        raise ValueError("input_range: no frames")
    out = {"definition": DEFINITION, "spp": int(spp), "frames": len(stats)}
    for k in RANGE_STATS:
        v = [s[k] for s in stats if np.isfinite(s[k])]
        if v:
            out[k] = [float(min(v)), float(max(v))]
    return out


def union_range(a, b):
    """The `input_range` covering both a and b (each input_range's dict):
    per statistic the lower of the minima and the higher of the maxima, the
    frames summed. Ranges of another definition or spp cannot be merged:
    a is returned as it is."""
    if b is None or a.get("definition") != b.get("definition") or a.get("spp") != b.get("spp"):
        return a
    out = dict(a, frames=int(a.get("frames", 0)) + int(b.get("frames", 0)))
    for k in RANGE_STATS:
        if k in a and k in b:
            out[k] = [min(a[k][0], b[k][0]), max(a[k][1], b[k][1])]
        elif k in b:
            out[k] = list(b[k])
    return out


def input_range_json(rng):
    """The metadata string: JSON whose floats read back exactly."""
    return json.dumps(rng, separators=(", ", ": "))
