"""What the C reader (src/exr_read.c) checks of an OpenEXR file before it
reads pixels and OpenImageIO does not: whether the data window's pixels
can come out of a file of its size (claimed_size), whether a channel is
listed twice or has a type or sampling OpenEXR does not know (channel_fault), whether each uncompressed or ZIP chunk
holds its pixels' bytes (chunk_size_mismatch), and whether the file
holds every chunk its offset tables point to,
judged as the C reader (src/exr_read.c, chunk_table) judges it, and
whether a tiled file's table has as many chunks as its tile description
makes, as OpenEXRCore requires: OpenImageIO reads the full-resolution level
of one part and never looks at the rest, so a file cut short in its smaller
MIP levels, or in another part, or whose header names another level mode
than its tiles were written in, read as whole here and was refused by
`hairfilter infer`.

The layout is the format's (openexr.com, "OpenEXR File Layout"): magic and
version (8 bytes), each part's header (attributes of name\\0 type\\0 int32
size and value, ended by a 0 byte; a multi-part file ends its headers with
one more 0 byte), then the parts' offset tables (one little-endian uint64
per chunk), then the chunks, each led by [part number (multi-part)], its
scanline's y or its tile's 4 coordinates, and its data's size (a deep
chunk's: three uint64, the sample table's and the data's packed sizes
first)."""
import mmap
import os
import struct
import zlib

_DEEP = ("deepscanline", "deeptile")
_TILED = ("tiledimage", "deeptile")


def _chlist(v):
    """The channels of a chlist value (entries of name\\0, int32 pixel
    type, uchar pLinear, 3 reserved bytes, int32 x and y sampling; ended by
    a 0 byte) as (name bytes, pixel type, x sampling, y sampling)."""
    names, at = [], 0
    while at < len(v) and v[at]:
        end = v.find(b"\0", at)
        if end < 0 or end + 17 > len(v):
            break
        (ptype,) = struct.unpack_from("<i", v, end + 1)
        xs, ys = struct.unpack_from("<ii", v, end + 9)
        names.append((v[at:end], ptype, xs, ys))
        at = end + 17
    return names


def data_is_exr(path):
    """Whether the file at path starts with OpenEXR's magic number."""
    with open(path, "rb") as f:
        return f.read(4) == b"\x76\x2f\x31\x01"


def channel_fault(path):
    """None, or why the headers of the file at path cannot be read: cut
    short or damaged before OpenImageIO reads them (which reads a cut one
    on into garbage), or a channel list the C reader refuses, in its words
    (src/exr_channels.c): a channel listed twice (which
    OpenImageIO reads as one), a pixel type other than UINT, HALF or FLOAT
    (on which OpenImageIO aborts the process in some paths), a sampling
    below 1, or a name that is not UTF-8 (which OpenImageIO's Python
    binding raises UnicodeDecodeError on). To be asked before OpenImageIO
    opens the file."""
    with open(path, "rb") as f:
        if not f.seek(0, 2):
            return None
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
            why = []
            walked = _headers(data, why)
            size = len(data)
    if not walked and why == ["cut"]:
        return (f"truncated / incomplete file: it ends inside its header ({size} bytes); write "
                "or copy the file again")
    if not walked and data_is_exr(path):
        return "the EXR header cannot be read (an attribute runs past its end); the file is " \
               "damaged, write it again"
    for i, part in enumerate(walked[1] if walked else []):
        seen = set()
        for raw, ptype, xs, ys in part[4]:
            name = raw.decode("utf-8", "replace")
            if raw in seen:
                return (f'channel "{name}" is listed twice in the channel list of part {i}: '
                        "every channel of a part needs its own name; write the file again with "
                        "one of them renamed or left out")
            seen.add(raw)
            try:
                raw.decode("utf-8")
            except UnicodeDecodeError:
                return (f'channel "{name}" of part {i} has a name that is not UTF-8 '
                        f"({raw!r}); rename the channel")
            if not 0 <= ptype <= 2:
                return (f'channel "{name}" of part {i} has pixel type {ptype}, not UINT (0), '
                        "HALF (1) or FLOAT (2); the file is damaged, write it again")
            if xs < 1 or ys < 1:
                return (f'channel "{name}" of part {i} has sampling {xs}x{ys}, below 1; the '
                        "file is damaged, write it again")
    return None


def chunk_size_mismatch(path, part):
    """None, or why a chunk of the full-resolution level of part (an
    index) holds another number of bytes than its pixels: uncompressed,
    its data; ZIP or ZIPS, its data once inflated. The C reader refuses
    such a chunk (src/exr_read.c, check_raw_size, and OpenEXRCore's
    decoder); OpenEXR's C++ library read it, a header whose channel type
    or data window had been changed giving garbage values with no error.
    Other compressions are left to the decoder."""
    with open(path, "rb") as f:
        if not f.seek(0, 2):
            return None
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
            return _chunk_sizes(data, part)


def _chunk_sizes(data, part):
    walked = _headers(data)
    if not walked or part >= len(walked[1]):
        return None
    at, parts, multipart = walked
    kind, chunks, tiles, window, channels, comp = parts[part]
    if comp not in (0, 2, 3) or not window or not channels or kind in _DEEP:
        return None
    x0, y0, x1, y1 = window
    w, h = x1 - x0 + 1, y1 - y0 + 1
    pixel = sum(2 if t == 1 else 4 for _, t, _, _ in channels)
    if w < 1 or h < 1:
        return None
    if multipart:
        if any(p[1] is None or p[1] < 0 for p in parts):
            return None
        at += 8 * sum(p[1] for p in parts[:part])
        count = chunks
    else:
        count = _single_count(parts[0])   # None: up to the first chunk
    first, n, pos = None, 0, at
    lines = {0: 1, 2: 1, 3: 16}[comp]
    while (count is None and (first is None or pos < first)) or (count is not None and n < count):
        if pos + 8 > len(data):
            return None
        (off,) = struct.unpack_from("<Q", data, pos)
        pos += 8
        n += 1
        if off and (first is None or off < first):
            first = off
        lead = off + (4 if multipart else 0)
        if kind in _TILED:
            if not tiles or lead + 20 > len(data):
                return None
            tx, ty, lx, ly, packed = struct.unpack_from("<4iI", data, lead)
            if lx or ly:
                continue
            cw = min(tiles[0], w - tx * tiles[0])
            ch = min(tiles[1], h - ty * tiles[1])
            what = f"tile ({tx}, {ty})"
            body = lead + 20
        else:
            if lead + 8 > len(data):
                return None
            y, packed = struct.unpack_from("<iI", data, lead)
            cw, ch = w, min(lines, y1 - y + 1)
            what = f"scanlines {y}-{y + ch - 1}"
            body = lead + 8
        if cw < 1 or ch < 1 or body + packed > len(data):
            return None   # the decoder's to say
        want = cw * ch * pixel
        got = packed
        if comp and packed < want:   # a chunk compression would not shrink is stored raw
            try:
                got = len(zlib.decompress(data[body:body + packed]))
            except zlib.error as e:
                return f"{what}: its ZIP data cannot be inflated ({e})"
        if got != want:
            return (f"{what} holds {got} bytes of pixels, but its {cw}x{ch} pixels of "
                    f"{len(channels)} channels are {want} bytes: the header does not describe "
                    "its data")
    return None


def _headers(data, why=None):
    """(offset past the headers, [per part: (type string, chunkCount or
    None, tiles (x size, y size, mode) or None, dataWindow or None,
    _chlist's channels, compression code or None)], multi-part), or None
    when they cannot be walked: then why (a list, when given) gets "cut"
    when the file ends inside them, else "damaged"."""
    def fail(kind):
        if why is not None:
            why.append(kind)
        return None
    if len(data) < 8 or data[:4] != b"\x76\x2f\x31\x01":
        return fail("cut" if len(data) < 8 and data[:4] == b"\x76\x2f\x31\x01"[:len(data)]
                    else "damaged")
    flags = data[5]
    multipart, single_tiled = bool(flags & 0x10), bool(flags & 0x02)
    at, parts = 8, []
    while True:
        kind, chunks = ("tiledimage" if single_tiled else "scanlineimage"), None
        tiles = window = names = compression = None
        nattr = 0
        while True:
            end = data.find(b"\0", at, at + 256)
            if end < 0:
                return fail("cut" if at + 256 > len(data) else "damaged")
            name = data[at:end]
            at = end + 1
            if not name:
                break
            tend = data.find(b"\0", at, at + 256)
            if tend < 0 or tend + 5 > len(data):
                return fail("cut" if at + 256 > len(data) or tend + 5 > len(data) else "damaged")
            (size,) = struct.unpack_from("<i", data, tend + 1)
            value_at = tend + 5
            if size < 0 or value_at + size > len(data):
                return fail("damaged" if size < 0 else "cut")
            if name == b"type":
                kind = data[value_at:value_at + size].split(b"\0")[0].decode("latin-1")
            elif name == b"chunkCount" and size == 4:
                (chunks,) = struct.unpack_from("<i", data, value_at)
            elif name == b"tiles" and size == 9:
                tiles = struct.unpack_from("<IIB", data, value_at)
            elif name == b"dataWindow" and size == 16:
                window = struct.unpack_from("<4i", data, value_at)
            elif name == b"channels":
                names = _chlist(data[value_at:value_at + size])
            elif name == b"compression" and size == 1:
                compression = data[value_at]
            at = value_at + size
            nattr += 1
        if nattr == 0 and parts:
            break   # the empty header that ends a multi-part file's
        parts.append((kind, chunks, tiles, window, names or [], compression))
        if not multipart:
            break
    return at, parts, multipart


# The most bytes of pixels one byte of a chunk's data can decode to, by
# compression (OpenImageIO's name): src/exr_read.c's max_expansion, whose
# comment gives the formats' reasons and the measurements.
_EXPANSION = {"none": 1, "rle": 64, "zips": 1032, "zip": 1032, "piz": 1032,
              "pxr24": 1032 * 4 / 3, "b44": 32 / 3, "b44a": 32 / 3}


def claimed_size(path, width, height, channel_bytes, compression):
    """None, or why a data window of width x height pixels of channels of
    channel_bytes bytes each (2 for HALF, 4 for FLOAT and UINT) cannot come
    out of the file at path with that compression, as the C reader
    (check_claimed_size) refuses it before allocating: a damaged header of
    a small file made OpenImageIO allocate what it claims (755 MB for a
    7 KB file) and return it filled with garbage."""
    size = os.path.getsize(path)
    name = (compression or "none").split(":")[0].lower()
    most = size * _EXPANSION.get(name, 64 * 1032)
    claimed = float(width) * float(height) * float(sum(channel_bytes))
    if claimed <= most:
        return None
    return (f"its data window claims {width}x{height} pixels of {len(channel_bytes)} channels "
            f"({claimed / 1e6:.1f} MB of pixels), more than {size} bytes of {name}-compressed "
            f"data can hold ({most / 1e6:.1f} MB)")


def _log2(n, up):
    """OpenEXR's roundLog2: floor(log2 n), or ceil with up."""
    k = n.bit_length() - 1
    return k + 1 if up and n > 1 << k else k


def _tiles(w, h, desc):
    """How many tiles OpenEXR's layout gives a w x h data window with tile
    description desc (x size, y size, mode): every level of its level mode
    (one level, MIP levels, RIP levels), each level's side halved and
    rounded as the mode's rounding bit says."""
    tw, th, mode = desc
    level, up = mode & 0xF, (mode >> 4) & 0xF == 1

    def side(n, k):
        return max(1, (n + (1 << k) - 1) >> k if up else n >> k)

    def count(lw, lh):
        return -(-lw // tw) * -(-lh // th)
    if level == 0:
        return count(w, h)
    if level == 1:
        return sum(count(side(w, k), side(h, k)) for k in range(_log2(max(w, h), up) + 1))
    if level == 2:
        return sum(count(side(w, kx), side(h, ky)) for kx in range(_log2(w, up) + 1)
                   for ky in range(_log2(h, up) + 1))
    return None


# Scanlines per chunk, by compression code (NONE, RLE, ZIPS, ZIP, PIZ, PXR24,
# B44, B44A, DWAA, DWAB): the format's.
_LINES = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256}


def _single_count(part):
    """The chunks a single-part file's header makes, or None when it
    cannot say: scanline chunks of the data window's lines, or the tiles of
    every level."""
    kind, chunks, tiles, window, _, comp = part
    if chunks is not None:
        return chunks if chunks >= 0 else None
    if not window:
        return None
    w, h = window[2] - window[0] + 1, window[3] - window[1] + 1
    if w < 1 or h < 1:
        return None
    if kind in _TILED:
        return _tiles(w, h, tiles) if tiles and tiles[0] and tiles[1] else None
    if kind in _DEEP or comp not in _LINES:
        return None
    return -(-h // _LINES[comp])


def levels_mismatch(path):
    """None, or why the tiled part of a single-part file has another number
    of chunks than its tile description makes (a level mode written over
    another's data: RIPMAP over MIPMAP levels, one level over either), as
    the C reader (OpenEXRCore) refuses it: the header contradicts itself."""
    with open(path, "rb") as f:
        if not f.seek(0, 2):
            return None
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
            walked = _headers(data)
            if not walked or walked[2] or walked[1][0][0] not in _TILED:
                return None
            at, ((kind, chunks, tiles, window, _, _),), _ = walked
            if not tiles or not window or not tiles[0] or not tiles[1]:
                return None
            w, h = window[2] - window[0] + 1, window[3] - window[1] + 1
            if w < 1 or h < 1:
                return None
            want = _tiles(w, h, tiles)
            have = chunks
            if have is None:   # no chunkCount: the table's length
                have, pos, first = 0, at, None
                while (first is None or pos < first) and pos + 8 <= len(data):
                    (off,) = struct.unpack_from("<Q", data, pos)
                    pos += 8
                    have += 1
                    if off and (first is None or off < first):
                        first = off
            if want is None or want == have:
                return None
            mode = {0: "one level", 1: "MIP levels", 2: "RIP levels"}.get(tiles[2] & 0xF)
            return (f"its tile description ({tiles[0]}x{tiles[1]} tiles, {mode}) makes {want} "
                    f"tiles of its {w}x{h} data window, its chunk table holds {have}")


def cut_short(path):
    """None when every chunk the file's offset tables point to lies in the
    file, else why not, in words for a message ("it ends (at N bytes) inside
    the data of a chunk its table points to"). Also None when the tables
    cannot be found (a damaged header: the reader says so)."""
    with open(path, "rb") as f:
        if not f.seek(0, 2):
            return None   # empty: the reader says so
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
            return _cut_short(data)


def _cut_short(data):
    size = len(data)
    walked = _headers(data)
    if not walked:
        return None
    at, parts, multipart = walked
    if multipart and any(p[1] is None or p[1] < 0 for p in parts):
        return None
    # A single-part file records no chunk count: its table runs from the
    # end of the header to the first chunk, which its writer puts right
    # after it (the smallest offset the table holds).
    offsets = []
    if multipart:
        count = sum(p[1] for p in parts)
        if at + 8 * count > size:
            return (f"its chunk tables ({count} chunks) do not fit in its {size} bytes")
        offsets = list(struct.unpack_from(f"<{count}Q", data, at))
        tables_end = at + 8 * count
    elif _single_count(parts[0]) is not None:
        count = _single_count(parts[0])
        if at + 8 * count > size:
            return f"its chunk table ({count} chunks) does not fit in its {size} bytes"
        offsets = list(struct.unpack_from(f"<{count}Q", data, at))
        tables_end = at + 8 * count
    else:
        first, pos = None, at
        while first is None or pos < first:
            if pos + 8 > size:
                return f"its chunk table does not fit in its {size} bytes"
            (off,) = struct.unpack_from("<Q", data, pos)
            pos += 8
            offsets.append(off)
            if off and (first is None or off < first):
                first = off
            if len(offsets) > size // 8:
                return None
        tables_end = pos
    if any(o >= size or o < tables_end for o in offsets):
        return (f"an offset of its chunk table points outside the file's chunks (it has "
                f"{size} bytes)")
    last = max(offsets) if offsets else 0
    if not last:
        return None
    pos, owner = last, 0
    if multipart:
        if pos + 4 > size:
            return f"it ends (at {size} bytes) inside the data of a chunk its table points to"
        (owner,) = struct.unpack_from("<i", data, pos)
        if not 0 <= owner < len(parts):
            return None
        pos += 4
    kind = parts[owner][0]
    pos += 16 if kind in _TILED else 4
    if kind in _DEEP:
        if pos + 24 > size:
            return f"it ends (at {size} bytes) inside the data of a chunk its table points to"
        table, packed, _ = struct.unpack_from("<QQQ", data, pos)
        end = pos + 24 + table + packed
    else:
        if pos + 4 > size:
            return f"it ends (at {size} bytes) inside the data of a chunk its table points to"
        (packed,) = struct.unpack_from("<I", data, pos)
        end = pos + 4 + packed
    if end > size:
        return f"it ends (at {size} bytes) inside the data of a chunk its table points to"
    return None
