"""Training data of the hairfilter recipe: dataset directories, EXR frames,
the train/validation split, random crops and the augmentations that are valid
for hair features.

A dataset directory (written by `hairfilter render dataset`, or by
weights/synth_dataset.py) holds one EXR file per render and a manifest.json:

    {"format": "hairfilter-dataset", "version": 1,
     "frames": [{"file": "straight_0000.exr", "style": "straight",
                 "spp": 4, "width": 256, "height": 256, "seed": 17}, ...]}

Each EXR holds the features S{k}.<feature> (protocol/FEATURES.md), the
ground truth gt.color/gt.highlight/gt.alpha and optional baselines
st{N}.* / opaque.*. Only "file" is required in a frame entry; "style" falls
back to the file name's prefix before the first '_'. A directory without a
manifest is read as every *.exr in it.
"""
import glob
import hashlib
import json
import math
import os
import re
import sys

import numpy as np
import OpenImageIO as oiio

import exr_complete
import input_stats
import sample_rule

FEATURES = ["color", "highlight", "alpha", "depth", "tangent.x", "tangent.y"]
TARGETS = ["color", "highlight", "alpha"]
# The alpha-corrected estimate (protocol/FEATURES.md), read by variants whose
# configuration has "estimate".
ESTIMATE = ["acst4.color", "acst4.highlight", "acst4.alpha"]
COLOR, HIGHLIGHT = 0, 1
TANGENT_X, TANGENT_Y = 4, 5

# Keys a manifest may use for its frame list and for a frame's file name.
_LIST_KEYS = ("frames", "images", "renders", "items", "files")
_FILE_KEYS = ("file", "path", "exr", "name")


class DatasetError(Exception):
    pass


# ---- manifest --------------------------------------------------------------

def _style_from_name(fname):
    base = os.path.basename(fname)
    return base.split("_")[0].split(".")[0].lower()


def read_manifest(root):
    """List of frame dicts, each with at least 'file' (absolute path) and
    'style', sorted by file name so every reader sees the same order."""
    if not os.path.isdir(root):
        raise DatasetError(f"{root}: no such directory (give a directory that "
                           "`hairfilter render dataset` wrote)")
    path = os.path.join(root, "manifest.json")
    entries = []
    if os.path.exists(path):
        with open(path) as f:
            try:
                doc = json.load(f)
            except ValueError as e:
                raise DatasetError(f"{path}: not JSON ({e}); `hairfilter render dataset` "
                                   "writes the manifest whole: render the set again") from None
        items = doc
        if isinstance(doc, dict):
            items = next((doc[k] for k in _LIST_KEYS if isinstance(doc.get(k), list)), None)
            if items is None:
                raise DatasetError(f"{path}: no frame list (one of {', '.join(_LIST_KEYS)})")
        for it in items:
            if isinstance(it, str):
                it = {"file": it}
            fname = next((it[k] for k in _FILE_KEYS if isinstance(it.get(k), str)), None)
            if fname is None:
                raise DatasetError(f"{path}: frame entry without a file name: {it}")
            e = dict(it)
            e["file"] = fname if os.path.isabs(fname) else os.path.join(root, fname)
            e["style"] = str(it.get("style") or _style_from_name(fname)).lower()
            entries.append(e)
    else:
        for fname in glob.glob(os.path.join(root, "*.exr")):
            entries.append({"file": fname, "style": _style_from_name(fname)})
    if not entries:
        sets = sets_below(root)
        if sets:
            # The parent of the sets (data/ rather than data/mine,data/bob).
            shown = ",".join(sets[:4]) + (",..." if len(sets) > 4 else "")
            raise DatasetError(f"{root}: no frames of its own; it holds {len(sets)} set(s) "
                               f"(directories with a manifest.json): give them, comma-separated "
                               f"(--data {shown})")
        raise DatasetError(f"{root}: no frames (no manifest.json entries, no *.exr)")
    entries.sort(key=lambda e: os.path.basename(e["file"]))
    return entries


def read_sets(dirs):
    """The frames of the dataset directories dirs (comma-separated, or a
    list), each as read_manifest lists them, in that order. A frame reached
    twice (a set given twice, a manifest that lists a file twice) is refused,
    naming both: it would be trained on twice, and could be a validation and
    a training frame at once, the split going by file name."""
    if isinstance(dirs, str):
        dirs = [d for d in dirs.split(",") if d]
    entries, seen = [], {}
    for d in dirs:
        for e in read_manifest(d):
            try:
                st = os.stat(e["file"])
                key = (st.st_dev, st.st_ino)
            except OSError:   # missing: named when it is read
                key = os.path.realpath(e["file"])
            if key in seen:
                f0, d0 = seen[key]
                what = (f"{e['file']} is given twice" if f0 == e["file"]
                        else f"{e['file']} and {f0} are one frame, given twice")
                raise DatasetError(f"{what} (by the sets {d0} and {d}: a set given twice, or "
                                   "a manifest that lists the frame twice): give each set once")
            seen[key] = (e["file"], d)
            entries.append(e)
    return entries


def sets_below(root):
    """The directories right under root that hold a manifest.json, in name
    order (root joined to each): the sets of a directory that is their
    parent."""
    try:
        names = sorted(os.listdir(root))
    except OSError:
        return []
    return [os.path.join(root, n) for n in names
            if os.path.isfile(os.path.join(root, n, "manifest.json"))]


def split_frames(entries, val_fraction=0.1):
    """Deterministic split: the frames whose file-name hash is lowest go to
    validation (round(val_fraction * n), at least one when n > 1, and at
    most n - 1, so one frame is left to train on). Depends only on the
    names, never on a seed or on the listing order."""
    if val_fraction <= 0 or len(entries) < 2:
        return list(entries), []
    # Capped: a large fraction of a few frames held out every one of them,
    # and the run failed drawing a crop from no frames (numpy "high <= 0").
    n_val = min(len(entries) - 1, max(1, int(round(val_fraction * len(entries)))))
    key = lambda e: hashlib.sha1(os.path.basename(e["file"]).encode()).hexdigest()
    ranked = sorted(entries, key=key)
    val = set(id(e) for e in ranked[:n_val])
    train = [e for e in entries if id(e) not in val]
    valid = [e for e in entries if id(e) in val]
    return train, valid


# ---- EXR -------------------------------------------------------------------

def _oiio_error(inp=None):
    """OpenImageIO's last error (inp's, else the global one), its bytes
    that are not UTF-8 replaced: the binding raises UnicodeDecodeError on
    them, and a damaged file's names end up in its messages."""
    try:
        return (inp.geterror() if inp else "") or oiio.geterror()
    except UnicodeDecodeError as e:
        return e.object.decode("utf-8", "replace") if isinstance(e.object, bytes) else str(e)


def read_exr(path):
    """(channel names, float32 array [h][w][c]) of the file's part that the
    C reader (src/exr_read.c) chooses: the only part, else the one part
    holding S0.color; other multi-part files are refused, naming the parts,
    and so are files cut short anywhere, tiled files whose header
    contradicts its tiles and files whose channel list OpenEXR refuses
    (exr_complete.py)."""
    # Before OpenImageIO reads the header: it aborts the process on some
    # channel lists, and raises UnicodeDecodeError on names that are not
    # UTF-8.
    why = exr_complete.channel_fault(path) if os.path.isfile(path) else None
    if why:
        raise DatasetError(f"{path}: {why}")
    inp = oiio.ImageInput.open(path)
    if not inp:
        raise DatasetError(f"cannot read {path}: {_oiio_error()}")
    try:
        return _read_opened(inp, path)
    except UnicodeDecodeError as e:
        # A name the header walk above could not reach (a damaged header).
        raise DatasetError(f"{path}: a name in its header is not UTF-8 ({e}); the file is "
                           "damaged, write it again") from None
    finally:
        inp.close()


def _read_opened(inp, path):
    """read_exr's reading of the file at path, open in inp."""
    # OpenImageIO reads one level of one part: a file cut short elsewhere
    # (its smaller MIP levels, another part) is refused, as the C reader
    # refuses it, not read as whole.
    why = exr_complete.levels_mismatch(path)
    if why:
        inp.close()
        raise DatasetError(f"{path}: the EXR header contradicts itself: {why}; the file is "
                           "damaged, write it again")
    why = exr_complete.cut_short(path)
    if why:
        inp.close()
        raise DatasetError(f"{path}: truncated / incomplete file: {why}; write or copy the "
                           "file again")
    specs = []
    while inp.seek_subimage(len(specs), 0):
        specs.append(inp.spec())
    part = 0
    if len(specs) > 1:
        with_features = [i for i, s in enumerate(specs) if "S0.color" in s.channelnames]
        if len(with_features) != 1:
            inp.close()
            listed = ", ".join(f'{i} "{s.getattribute("name") or ""}" ({s.nchannels} channels)'
                               for i, s in enumerate(specs))
            raise DatasetError(f"{path} has {len(specs)} parts, "
                               f"{'several' if with_features else 'none'} with channel "
                               f"S0.color: {listed}; write the frame's features as one part")
        part = with_features[0]
    spec = specs[part]
    names = list(spec.channelnames)
    if spec.deep:
        inp.close()
        raise DatasetError(f"{path}: deep data (several samples per pixel of varying count) is "
                           f"not read; flatten it first, e.g. oiiotool {path} --flatten -o "
                           "flat.exr")
    formats = list(spec.channelformats) or [spec.format] * spec.nchannels
    why = exr_complete.claimed_size(path, spec.width, spec.height,
                                    [2 if f.basetype == oiio.HALF else 4 for f in formats],
                                    spec.getattribute("compression"))
    if why:
        inp.close()
        raise DatasetError(f"{path}: {why}; the file is damaged, write it again")
    why = exr_complete.chunk_size_mismatch(path, part)
    if why:
        inp.close()
        raise DatasetError(f"{path}: {why}; the file is damaged, write it again")
    data = inp.read_image(part, 0, 0, spec.nchannels, oiio.FLOAT)
    if data is None:
        why = _oiio_error(inp)
        inp.close()
        raise DatasetError(f"cannot read pixels of {path}: {why or 'no reason given'}; the "
                           "file is damaged or incomplete, write or copy it again")
    data = np.array(data, np.float32).reshape(spec.height, spec.width, len(names))
    # OpenImageIO scales a UINT channel to [0, 1]; OpenEXR (and the C
    # reader) convert its integers to float as they are: read as such.
    for c, f in enumerate(formats):
        if f.basetype == oiio.UINT32:
            ints = inp.read_image(part, 0, c, c + 1, oiio.UINT32)
            data[..., c] = np.asarray(ints, np.uint32).reshape(spec.height, spec.width)
    inp.close()
    return names, data


def write_exr(path, names, hwc, half=False):
    h, w, c = hwc.shape
    spec = oiio.ImageSpec(w, h, c, oiio.HALF if half else oiio.FLOAT)
    spec.channelnames = tuple(names)
    spec.attribute("compression", "zip")
    out = oiio.ImageOutput.create(path)
    if not out or not out.open(path, spec):
        raise DatasetError(f"cannot write {path}: {oiio.geterror()}")
    out.write_image(np.ascontiguousarray(hwc, dtype=np.float32))
    out.close()


def count_spp(names):
    """Consecutive S{k}.color channels from S0 (protocol/FEATURES.md)."""
    s = set(names)
    k = 0
    while f"S{k}.color" in s:
        k += 1
    return k


def pick_channels(names, data, wanted, path=""):
    idx = {n: i for i, n in enumerate(names)}
    missing = [n for n in wanted if n not in idx]
    if missing:
        raise DatasetError(f"{path}: missing channels {', '.join(missing)}")
    return data[..., [idx[n] for n in wanted]]


def _warn_sanitised(path, changed, before, names, estimate=False):
    """One warning per frame for what the out-of-contract rule changed, in
    the words `hairfilter infer` and `eval` print it (cli_warn_sanitised):
    how many, and the first in memory order. changed: [h][w][n] mask;
    before: [h][w][n][k] values as read; names(k, f): the channel of group
    k, feature f."""
    n = int(changed.sum())
    if not n:
        return
    y, x, k = (int(i) for i in np.argwhere(changed)[0])
    vals = [float(v) for v in before[y, x, k]]
    gone = "the pixel's estimate becomes 0 (no hair)" if estimate else \
        "the sample counts as uncovered"
    high = sample_rule.ESTIMATE_HIGH if estimate else sample_rule.SAMPLE_HIGH
    low = np.zeros(3, np.float32) if estimate else sample_rule.SAMPLE_LOW
    f = next((i for i, v in enumerate(vals) if not math.isfinite(v)), None)
    if f is not None:
        what = f"{names(k, f)} = {vals[f]:g} is not finite: {gone}"
    elif not vals[2] > 0:
        other = "colour or highlight is not 0" if estimate else "other features are not 0"
        what = f"{names(k, 2)} = {vals[2]:g} but {other}: {gone}"
    else:
        f = next(i for i, v in enumerate(vals) if v < low[i] or v > high[i])
        what = f"{names(k, f)} = {vals[f]:g} is out of range: clamped"
    kind = "estimate pixel" if estimate else "sample"
    print(f"dataset: warning: {path}: {n} {kind}{'' if n == 1 else 's'} sanitised "
          f"(protocol/FEATURES.md, \"Out-of-contract values\") as hairfilter sanitises them "
          f"before the network, the first at pixel ({x}, {y}) of the data window: {what}",
          file=sys.stderr)


def sanitise_samples(path, feat):
    """feat ([h][w][spp][6] samples of the frame at path) as the network
    sees them: the out-of-contract rule applied (sample_rule.py), as the C
    library applies it before every backend, with one warning on stderr
    when it changed any."""
    fixed, changed = sample_rule.sanitise_samples(feat)
    _warn_sanitised(path, changed, feat, lambda k, f: f"S{k}.{FEATURES[f]}")
    return fixed


def load_frame(path, spp=None, dtype=np.float16, sanitise=True):
    """Features [h][w][spp][6] and target [h][w][3] (gt.color, gt.highlight,
    gt.alpha) of one dataset EXR. spp=None keeps every sample in the file.
    With sanitise, the samples are those the network sees
    (sanitise_samples); without, the file's values, which the input
    statistics are measured on (protocol/FEATURES.md, "Input statistics").
    A non-finite ground truth value is refused, naming its pixel, as
    `hairfilter eval` refuses it: no loss can be taken against it."""
    names, data = read_exr(path)
    have = count_spp(names)
    if have == 0:
        raise DatasetError(f"{path}: no S0.color channel: not a feature file")
    spp = have if spp is None else spp
    if spp > have:
        raise DatasetError(f"{path}: {have} samples per pixel, {spp} needed: render the set "
                           f"with --spp {spp}, or read at most {have}")
    feat = pick_channels(names, data, [f"S{k}.{f}" for k in range(spp) for f in FEATURES], path)
    if not any(f"gt.{t}" in names for t in TARGETS):
        # The frame was rendered for filtering only: said, with the option.
        raise DatasetError(f"{path}: no ground truth (gt.color, gt.highlight, gt.alpha): render "
                           f"the set without --gt-ss 0")
    tgt = pick_channels(names, data, [f"gt.{t}" for t in TARGETS], path)
    h, w = data.shape[:2]
    bad = np.argwhere(~np.isfinite(tgt))
    if bad.size:
        y, x, c = (int(i) for i in bad[0])
        raise DatasetError(f"{path}: its ground truth gt.{TARGETS[c]} = {float(tgt[y, x, c]):g} "
                           f"at pixel ({x}, {y}) of the data window is not finite: nothing can "
                           "be trained against it; render the frame again")
    feat = feat.reshape(h, w, spp, 6)
    if sanitise:
        feat = sanitise_samples(path, feat)
    return feat.astype(dtype), tgt.astype(dtype)


def load_estimate(path, dtype=np.float16):
    """The alpha-corrected estimate [h][w][3] (acst4.color, .highlight,
    .alpha) of one dataset EXR, its out-of-contract rule applied
    (sample_rule.py; a warning on stderr when it changed any); DatasetError
    naming the render option when the file has none."""
    names, data = read_exr(path)
    if any(c not in names for c in ESTIMATE):
        raise DatasetError(f"{path}: no acst4.* channels (the alpha-corrected estimate): "
                           f"render it without --no-alpha-corrected")
    raw = pick_channels(names, data, ESTIMATE, path)
    est, changed = sample_rule.sanitise_estimate(raw)
    _warn_sanitised(path, changed[..., None], raw[..., None, :], lambda k, f: ESTIMATE[f],
                    estimate=True)
    return est.astype(dtype)


# ---- augmentation ----------------------------------------------------------

def entry_stats(entry, feat, spp):
    """input_stats.frame_stats of a manifest entry's features [h][w][spp*6],
    with long_side that of the whole frame when the entry is a crop (the
    manifest's "full_width"/"full_height"): an engine sends the whole frame,
    so that is the resolution the regime tables count it at, as `hairfilter
    eval` reports it (a trained range does not record it:
    input_stats.RANGE_STATS)."""
    st = input_stats.frame_stats(feat, spp)
    full = max(int(entry.get("full_width") or 0), int(entry.get("full_height") or 0))
    if full > st["long_side"]:
        st["long_side"] = float(full)
    return st


def augment(feat, tgt, rng, flips=True, rotations=True, permute=True):
    """Random dihedral transform and sample-slot permutation of one crop.

    feat: [h][w][spp][6], tgt: [h][w][3] (numpy). Tangents are view-space
    with y up while image rows go down, so a view vector (tx, ty) is the image
    displacement (du, dv) = (tx, -ty). Hence:
      horizontal flip (columns reversed):  tx -> -tx
      vertical flip (rows reversed):       ty -> -ty
      np.rot90 (counter-clockwise on screen): (tx, ty) -> (-ty, tx)
    Permuting the sample slots of every pixel the same way is valid because
    the samples of a pixel are exchangeable draws of the same distribution.
    """
    feat = feat.copy()
    if flips and rng.random() < 0.5:
        feat, tgt = feat[:, ::-1], tgt[:, ::-1]
        feat[..., TANGENT_X] *= -1
    if flips and rng.random() < 0.5:
        feat, tgt = feat[::-1], tgt[::-1]
        feat[..., TANGENT_Y] *= -1
    k = int(rng.integers(4)) if rotations else 0
    for _ in range(k):
        feat, tgt = np.rot90(feat, 1, axes=(0, 1)), np.rot90(tgt, 1, axes=(0, 1))
        tx = feat[..., TANGENT_X].copy()
        feat[..., TANGENT_X] = -feat[..., TANGENT_Y]
        feat[..., TANGENT_Y] = tx
    if permute and feat.shape[2] > 1:
        feat = feat[:, :, rng.permutation(feat.shape[2])]
    return np.ascontiguousarray(feat), np.ascontiguousarray(tgt)


def dim_light(feat, tgt, rng, lo):
    """Dims one crop's light: its colour factor by kc and its highlight by
    kh, each drawn log-uniform in [lo, 1], in every sample, the target and,
    where tgt holds one (6 channels: target, then estimate), the
    alpha-corrected estimate. Consistent because every one of them is
    linear in the fragments' colour factors and highlights (the samples are
    fragments', the target and estimate alpha-weighted means of them,
    protocol/FEATURES.md); coverage, depth and tangents do not change. It
    stands in, approximately, for a dimmer light or deeper shadow: a
    shadow does not dim the ambient term of the colour factor, and the two
    factors are drawn independently, as a light's diffuse and specular
    strengths may differ. Shadowed, dense hair is rare in rendered frames
    and a network should see it as darker colour factors, not as less
    hair.

    feat: [h][w][spp][6], tgt: [h][w][3 or 6] (numpy); lo in (0, 1].
    Returns new arrays."""
    if not 0 < lo <= 1:
        raise ValueError(f"dim_light: lo {lo} is outside (0, 1]")
    kc, kh = np.exp(rng.uniform(math.log(lo), 0.0, size=2))
    feat, tgt = feat.copy(), tgt.copy()
    feat[..., COLOR] *= kc
    feat[..., HIGHLIGHT] *= kh
    for base in range(0, tgt.shape[-1], 3):
        tgt[..., base + COLOR] *= kc
        tgt[..., base + HIGHLIGHT] *= kh
    return feat, tgt


class FrameSet:
    """Frames held in memory (float16) for crop sampling, and the input
    statistics of each (weights/input_stats.py) at the variant's spp, measured
    on the file's values before they are rounded to float16."""

    def __init__(self, entries, spp, log=None, estimate=False):
        """Keeps every sample a file holds, so that variants reading fewer
        samples than the files hold train on random subsets of them. With
        estimate, also each frame's alpha-corrected estimate (load_estimate),
        which follows the samples in every input (NHWC channels spp * 6 +
        0..2)."""
        self.entries = []
        self.feats, self.tgts, self.stats, self.ests = [], [], [], []
        self.spp = spp
        self.estimate = estimate
        self.add(entries, log)

    def add(self, entries, log=None):
        """Loads more frames (a dataset that is still being rendered)."""
        spp = self.spp
        for i, e in enumerate(entries):
            f, t = load_frame(e["file"], dtype=np.float32, sanitise=False)
            if f.shape[2] < spp:
                raise DatasetError(f"{e['file']}: {f.shape[2]} samples per pixel, the variant "
                                   f"reads {spp}: render the set with --spp {spp}, or train a "
                                   f"variant of fewer samples (Base@1spp reads 1, Base@2spp 2)")
            self.stats.append(entry_stats(e, f, spp))
            f = sanitise_samples(e["file"], f)
            if self.estimate:
                self.ests.append(load_estimate(e["file"]))
            self.feats.append(f.astype(np.float16))
            self.tgts.append(t.astype(np.float16))
            self.entries.append(e)
            if log:
                log(f"loading {i + 1}/{len(entries)}")

    def __len__(self):
        return len(self.feats)

    def nbytes(self):
        return sum(f.nbytes + t.nbytes for f, t in zip(self.feats, self.tgts)) + \
            sum(e.nbytes for e in self.ests)

    def crop(self, rng, size, hair_bias=0.9):
        """One random crop (feat [s][s][samples in file][6], tgt [s][s][3],
        and with an estimate tgt [s][s][6]: the target, then the estimate,
        both moved only by augment's spatial transforms). With probability
        hair_bias, retries (a few times) until the crop holds some hair, so
        training does not spend its steps on background."""
        for attempt in range(8):
            i = int(rng.integers(len(self.feats)))
            f, t = self.feats[i], self.tgts[i]
            h, w = t.shape[:2]
            ch, cw = min(size, h), min(size, w)
            y = int(rng.integers(h - ch + 1))
            x = int(rng.integers(w - cw + 1))
            fc, tc = f[y:y + ch, x:x + cw], t[y:y + ch, x:x + cw]
            if rng.random() > hair_bias or float(tc[..., 2].max()) > 0:
                break
        if self.estimate:
            tc = np.concatenate([tc, self.ests[i][y:y + ch, x:x + cw]], -1)
        return fc, tc

    def batch(self, rng, size, n, augment_on=True, dim=(0.0, 1.0)):
        """Batch of n augmented crops as float32 NCHW input [n][spp*6][s][s]
        and target [n][3][s][s]. When the frames hold more samples than the
        variant reads, each crop uses a random subset of them. dim (share,
        lo): with augment_on, that share of the crops has its light dimmed
        (dim_light, down to lo); share 0 draws nothing, so runs without it
        are unchanged."""
        xs, ys = [], []
        for _ in range(n):
            f, t = self.crop(rng, size)
            if augment_on:
                f, t = augment(f, t, rng)
                if dim[0] > 0 and rng.random() < dim[0]:
                    f, t = dim_light(f, t, rng, dim[1])
            if f.shape[2] > self.spp:
                f = f[:, :, np.sort(rng.choice(f.shape[2], self.spp, replace=False))]
            h, w = t.shape[:2]
            x = f.reshape(h, w, -1)
            if self.estimate:
                x, t = np.concatenate([x, t[..., 3:]], -1), t[..., :3]
            xs.append(x)
            ys.append(t)
        x = np.stack(xs).astype(np.float32).transpose(0, 3, 1, 2)
        y = np.stack(ys).astype(np.float32).transpose(0, 3, 1, 2)
        return np.ascontiguousarray(x), np.ascontiguousarray(y)


def parse_styles(s):
    return [x.strip().lower() for x in s.split(",") if x.strip()] if s else []

