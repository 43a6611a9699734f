"""The header of a safetensors file (weights/FORMAT.md), read as the C
loader (src/weights_load.c) reads it: without torch, so every script that
reads or rewrites weights files checks them the same way."""
import json
import os
import struct

# The largest weights file either loader reads (src/weights_load.c's
# FILE_MAX; Large is about 3 MB).
FILE_MAX = 1 << 31


def unique_keys(pairs):
    """object_pairs_hook for json: a name twice in one object is an error.
    JSON allows it and readers disagree on which one counts (json keeps the
    last, the C loader's cJSON finds the first), so such a file would be two
    different networks."""
    seen = set()
    for key, _ in pairs:
        if key in seen:
            raise ValueError(f"duplicate key {key!r}: each name may appear once "
                             "(readers disagree on which one counts)")
        seen.add(key)
    return dict(pairs)


def _surrogate(text, i):
    """1 when text[i:i + 6] is an escape of a high surrogate (\\uD800-
    \\uDBFF), 2 of a low one (\\uDC00-\\uDFFF), else 0."""
    e = text[i:i + 6]
    if len(e) < 6 or e[:3].lower() != "\\ud" or e[3].lower() not in "89abcdef" or \
            any(c not in "0123456789abcdefABCDEF" for c in e[4:]):
        return 0
    return 1 if e[3].lower() in "89ab" else 2


def text_fault(text):
    """(what, offset) of the first thing in JSON text that the C loader
    refuses although json takes it (src/json_check.c, hf_json_text_fault):
    a \\u0000 escape, at which C would cut a name or string short, so
    "a\\u0000b" would be "a" there and another name here; a lone half of a
    UTF-16 surrogate pair (\\uD800 not followed by \\uDC00-\\uDFFF, or
    \\uDC00 alone), no character, which cJSON refuses. None if none.
    Bytes that are not UTF-8 are refused when the text is decoded."""
    i = text.find("\\")
    while i >= 0:
        if text.startswith("u0000", i + 1):
            return ("\\u0000 (a NUL character, at which the C loader would cut its name or "
                    "string short)", i)
        half = _surrogate(text, i)
        if half == 1 and _surrogate(text, i + 6) == 2:
            i = text.find("\\", i + 12)
            continue
        if half:
            return ("a \\uD800-\\uDFFF escape that is half of a UTF-16 surrogate pair, alone "
                    "(no character: JSON readers disagree on it)", i)
        i = text.find("\\", i + 2)   # an escape is two characters: "\\\\" is one backslash
    return None


def _no_constant(name):
    """parse_constant for json: NaN, Infinity and -Infinity, which Python's
    json takes, are not JSON (RFC 8259), and the C loader refuses them."""
    raise ValueError(f"{name} is not a JSON number (JSON has no NaN or Infinity)")


def loads(text):
    """json.loads as every reader of a weights file's JSON reads it: a
    duplicate key (unique_keys) and NaN or Infinity refused, as the C
    loader refuses them."""
    return json.loads(text, object_pairs_hook=unique_keys, parse_constant=_no_constant)


def check_text(path, what, text):
    """Raises ValueError naming path and what (the header, 'hairfilter')
    when text holds what text_fault finds."""
    fault = text_fault(text)
    if fault:
        raise ValueError(f"{path}: {what} holds {fault[0]} at character {fault[1]} of its "
                         "JSON; write the file again")


def read_header(path):
    """The safetensors header of path as (header dict, file bytes, data
    start), checked as the C loader (src/weights_load.c) checks it: no
    duplicate keys at any level, and "__metadata__", when present, an object
    of string values. Raises ValueError naming the file and what is wrong."""
    with open(path, "rb") as f:
        # Measured before it is read, as the C loader measures it: a large
        # file given for weights by mistake (a dataset, a disk image) was
        # read whole into memory.
        size = os.fstat(f.fileno()).st_size
        if size > FILE_MAX:
            raise ValueError(f"{path}: larger than the {FILE_MAX} bytes a weights file may have "
                             f"({size} bytes): not a weights file of this project")
        data = f.read()
    if len(data) < 8:
        raise ValueError(f"{path}: file too short ({len(data)} bytes)")
    (n,) = struct.unpack("<Q", data[:8])
    if n > len(data) - 8:
        # Files given for weights by mistake, named as the C loader names them.
        if data[:4] == b"PK\3\4":
            raise ValueError(f"{path}: a zip archive, not a safetensors file: a PyTorch "
                             "checkpoint (train.py's RUN/checkpoint.pt)? Export its weights "
                             "with weights/train.py --out RUN --resume --export W.safetensors")
        if data[:4] == b"\x76\x2f\x31\x01":
            raise ValueError(f"{path}: an OpenEXR image, not a safetensors weights file")
        raise ValueError(f"{path}: header length {n} exceeds file size (not a safetensors "
                         "file, or one cut short)")
    if data[8:9] != b"{":
        raise ValueError(f"{path}: header does not start with '{{' (a byte order mark or other "
                         "bytes come before the JSON): write the file again with a safetensors "
                         "writer")
    # UTF-8 strictly (json.loads of bytes would pass encoded surrogates),
    # as the C loader and safetensors' reference reader read it.
    try:
        text = data[8:8 + n].decode("utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: header holds a byte that is not UTF-8 at byte {e.start} of "
                         "its JSON: a safetensors header is UTF-8 JSON; write the file again "
                         "with a safetensors writer") from None
    check_text(path, "header", text)
    try:
        header = loads(text)
    except ValueError as e:
        raise ValueError(f"{path}: header: {e}") from None
    except RecursionError:
        # Arrays or objects nested thousands deep: no header of a network.
        raise ValueError(f"{path}: header: JSON nested too deeply to read (not a safetensors "
                         "header of weights)") from None
    if not isinstance(header, dict):
        raise ValueError(f"{path}: header is not a JSON object")
    meta = header.get("__metadata__", {})
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: header: '__metadata__' is {type(meta).__name__}, but "
                         "safetensors wants an object of string values")
    for k, v in meta.items():
        if not isinstance(v, str):
            raise ValueError(f"{path}: header: '__metadata__.{k}' is {type(v).__name__}, "
                             "but safetensors metadata values are strings")
    # "shape": [32.0, ...] equals [32, ...] in Python, but safetensors'
    # reference reader refuses it (as the C loader does): integers only,
    # true and false included.
    for name, t in header.items():
        if name == "__metadata__" or not isinstance(t, dict):
            continue
        for key in ("shape", "data_offsets"):
            for v in t.get(key) if isinstance(t.get(key), list) else ():
                # true is 1 to Python (a shape [52, 56, true, true] equalled
                # the network's), not to the C loader.
                if isinstance(v, (float, bool)):
                    v = json.dumps(v)
                    raise ValueError(f"{path}: tensor '{name}': {key} holds {v}, not an "
                                     "integer: safetensors shapes and offsets are integers, "
                                     "written without a fraction or exponent; write the file "
                                     "again with a safetensors writer")
    check_tiling(path, header, len(data) - 8 - n)
    return header, data, 8 + n


def check_tiling(path, header, data_len):
    """The tensors' byte ranges tile the data, as the C loader and the
    safetensors reference reader require: sorted by start, each begins where
    the one before ends, the first at 0, the last at the end of the file.
    Entries without two integer data_offsets are left to the tensor checks."""
    ranges = []
    for name, t in header.items():
        offs = t.get("data_offsets") if name != "__metadata__" and isinstance(t, dict) else None
        if isinstance(offs, list) and len(offs) == 2 and all(type(o) is int for o in offs):
            ranges.append((offs[0], offs[1], name))
    at, prev = 0, None
    for b, e, name in sorted(ranges):
        if b < 0 or e < b:
            raise ValueError(f"{path}: tensor '{name}': data_offsets [{b}, {e}) are outside "
                             "the file (a negative offset, or an end before the begin)")
        if b < at:
            raise ValueError(f"{path}: tensor '{name}': data_offsets [{b}, {e}) overlap tensor "
                             f"'{prev[2]}' [{prev[0]}, {prev[1]}): in safetensors each tensor "
                             "owns its bytes")
        if b > at:
            raise ValueError(f"{path}: bytes [{at}, {b}) of the data belong to no tensor: "
                             "safetensors tensors follow one another with no gap")
        if e > data_len:
            # Said as the C loader says it, with the likely cause: "bytes
            # after the last tensor" with a negative count misled.
            raise ValueError(f"{path}: tensor '{name}': data_offsets [{b}, {e}) end past the "
                             f"{data_len} bytes of data in the file: the file is cut short "
                             "(copy or export it again)")
        at, prev = e, (b, e, name)
    if ranges and at != data_len:
        raise ValueError(f"{path}: {data_len - at} bytes after the last tensor: safetensors "
                         "data ends with its last tensor")
