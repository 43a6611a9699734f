#!/usr/bin/python3
"""Records in a weights file the range of input statistics it was trained on
(its `input_range` metadata, weights/FORMAT.md), measured on dataset frames:

    /usr/bin/python3 weights/stamp_range.py weights/base.safetensors \
        --data data/train --styles straight,wavy

Pass the --data, --styles and --val-fraction of the training run: the range
is taken over the same training frames train.py trained on (its split holds
out the validation frames; --val-fraction 0 takes every frame). The frames'
first `spp` samples are measured, spp being the variant's. Only the header
is rewritten (tensor bytes are copied unchanged); --out writes a copy.
train.py --export stamps its exports this way by itself. hairfilterd and
`hairfilter filter|infer|eval` then say when a frame is outside the range.

A range the file already records is replaced, and said so; --join keeps it
and adds these frames' (as train.py --export joins its --init weights'
range), for weights fine-tuned from others, which learnt both.
"""
import argparse
import json
import os
import struct
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import dataset  # noqa: E402
import input_stats  # noqa: E402
import safetensors_header  # noqa: E402


def read_safetensors_header(path):
    """(header dict, tensor bytes) of a safetensors file, refused as the C
    loader refuses it (duplicate keys, __metadata__ not of strings)."""
    header, data, base = safetensors_header.read_header(path)
    return header, data[base:]


def write_safetensors_header(path, header, body):
    """The header padded with spaces to 8 bytes (as hfnet.save_safetensors)."""
    h = json.dumps(header, separators=(",", ":")).encode()
    h += b" " * ((-len(h)) % 8)
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(struct.pack("<Q", len(h)))
        f.write(h)
        f.write(body)
    os.replace(tmp, path)


def training_frames(data, styles="", val_fraction=0.1):
    """The entries train.py trains on: every frame of the comma-separated
    dataset directories, of the given styles, less its validation split."""
    entries = dataset.read_sets(data)
    wanted = dataset.parse_styles(styles)
    if wanted:
        entries = [e for e in entries if e["style"] in wanted]
    if not entries:
        raise dataset.DatasetError(f"no frames of styles {styles!r} in {data}")
    train, _ = dataset.split_frames(entries, val_fraction)
    return train


def range_of_frames(entries, spp, log=None):
    stats = []
    for i, e in enumerate(entries):
        feat, _ = dataset.load_frame(e["file"], spp=spp, dtype="float32",
                                     sanitise=False)
        stats.append(dataset.entry_stats(e, feat, spp))
        if log:
            log(f"{i + 1}/{len(entries)} {os.path.basename(e['file'])}")
    return input_stats.input_range(stats, spp)


def recorded_range(header, path):
    """The input_range the header records (its dict), or None."""
    text = (header.get("__metadata__") or {}).get("input_range")
    if text is None:
        return None
    try:
        rng = safetensors_header.loads(text)
    except ValueError as e:
        raise ValueError(f"{path}: its input_range is not JSON ({e}): stamp without --join "
                         "to replace it") from None
    if not isinstance(rng, dict):
        raise ValueError(f"{path}: its input_range is not a JSON object: stamp without --join "
                         "to replace it")
    return rng


def check_joinable(old, spp, path):
    """Refuses (ValueError) a recorded range that these frames' cannot join:
    another version of the statistics' definitions, or another spp
    (input_stats.union_range would keep the old one as it is)."""
    for k, want in (("definition", input_stats.DEFINITION), ("spp", spp)):
        if old.get(k) != want:
            raise ValueError(f"{path}: its input_range has {k} {old.get(k)!r}, these frames' "
                             f"{want!r}: the two cannot be joined; stamp without --join "
                             "to replace it")


def stamp(path, rng, out=None):
    header, body = read_safetensors_header(path)
    meta = header.setdefault("__metadata__", {})
    meta["input_range"] = input_stats.input_range_json(rng)
    write_safetensors_header(out or path, header, body)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("weights", help="safetensors file to stamp")
    ap.add_argument("--data", required=True, help="dataset directories, comma-separated")
    ap.add_argument("--styles", default="", help="only these styles (default: all)")
    ap.add_argument("--val-fraction", type=float, default=0.1,
                    help="train.py's validation split, left out (default 0.1)")
    ap.add_argument("--join", action="store_true",
                    help="keep the input_range the file records and add these frames' (per "
                         "statistic the lower minimum and the higher maximum, frames summed), "
                         "as train.py --export joins its --init weights' range: for weights "
                         "fine-tuned from others. Without it a recorded range is replaced")
    ap.add_argument("--out", help="write a stamped copy here instead")
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    try:
        header, _ = read_safetensors_header(args.weights)
    except OSError as e:
        sys.exit(f"stamp_range.py: {args.weights}: {e.strerror}")
    except ValueError as e:   # the header's checks, naming the file
        sys.exit(f"stamp_range.py: {e}")
    try:
        cfg = safetensors_header.loads(header["__metadata__"]["hairfilter"])
    except (KeyError, TypeError, ValueError):
        sys.exit(f"stamp_range.py: {args.weights}: no hairfilter metadata")
    try:
        old = recorded_range(header, args.weights)
        if args.join and old is not None:   # before the frames are measured
            check_joinable(old, int(cfg["spp"]), args.weights)
    except ValueError as e:
        old = None
        if args.join:
            sys.exit(f"stamp_range.py: {e}")
    # Where it writes, checked before the frames are measured (a missing
    # directory was a traceback after them).
    if args.out and (os.path.isdir(args.out) or args.out.endswith(os.sep)):
        # os.replace onto a directory was a traceback after the frames.
        sys.exit(f"stamp_range.py: --out {args.out} is a directory: give the stamped copy's "
                 f"file name (e.g. {os.path.join(args.out, os.path.basename(args.weights))})")
    where = os.path.dirname(os.path.abspath(args.out or args.weights))
    if not os.path.isdir(where):
        sys.exit(f"stamp_range.py: --out {args.out}: the directory {where} does not exist; "
                 f"create it first (mkdir -p {where})")
    if not os.access(where, os.W_OK):
        sys.exit(f"stamp_range.py: {args.out or args.weights}: {where} is not writable"
                 + ("" if args.out else "; write a stamped copy elsewhere with --out"))
    entries = training_frames(args.data, args.styles, args.val_fraction)
    log = None if args.quiet else (lambda m: print(f"\r{m}\x1b[K", end="", file=sys.stderr))
    rng = range_of_frames(entries, int(cfg["spp"]), log)
    if log:
        print(file=sys.stderr)
    if args.join and old is not None:
        rng = input_stats.union_range(rng, old)
    elif old is not None:
        # Said: weights fine-tuned from others would lose the range of the
        # frames they learnt first, and a server would flag those frames.
        print(f"stamp_range.py: {args.out or args.weights}: replaces the input_range "
              f"{args.weights} recorded (over {old.get('frames', '?')} frames); add --join to "
              "keep it and add these frames' (weights fine-tuned from others learnt both)",
              file=sys.stderr)
    stamp(args.weights, rng, args.out)
    print(f"{args.out or args.weights}: {cfg['name']}, input_range over {rng['frames']} frames: "
          + ", ".join(f"{k} {v[0]:.4g}..{v[1]:.4g}" for k, v in rng.items()
                      if isinstance(v, list)))
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except dataset.DatasetError as e:
        # A data directory or frame that cannot be used: its own words, no traceback.
        sys.exit(f"stamp_range.py: {e}")
