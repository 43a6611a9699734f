"""The hairfilter wire protocol, versions 1 to 4 (protocol/PROTOCOL.md).

A pure codec, the Python twin of protocol/hfproto.c: functions turn messages
into bytes and bytes into messages, and do no I/O. Decoders take a frame's
payload and reject one with missing or trailing bytes (LENGTH) or a field
out of its domain (INVALID), as the C decoders do, by raising ProtocolError.

Everything is little-endian (struct's "<"); tensors travel as the bytes of
C-contiguous numpy arrays, NHWC (protocol/FEATURES.md).
"""

import math
import struct
from collections import namedtuple

MAGIC = 0x31504648          # the bytes "HFP1"
VERSION = 4                 # the newest version spoken here
VERSION_MIN = 1
HEADER = struct.Struct("<IHHII")   # magic, type, flags, request_id, length
HEADER_SIZE = HEADER.size

NAME_MAX = 64
TOKEN_MAX = 256
MESSAGE_MAX = 256
MAX_VARIANTS = 64
MAX_LEVELS = 8
MAX_SPP = 16
MAX_SIDE = 65535
FEATURES = 6                # per sample
OUTPUTS = 3                 # color, highlight, alpha
HIST_BUCKETS = 24
SHM_REF_SIZE = 32

# message types
HELLO, HELLO_OK, LIST_VARIANTS, VARIANTS, FILTER, RESULT, ERROR, STATS, STATS_REPLY, \
    SHM_CREATE, SHM_CREATED, SHM_DESTROY, CANCEL = range(1, 14)   # CANCEL: version 4

# error codes (positive on the wire)
OK, E_VERSION, E_PROTOCOL, E_UNKNOWN_VARIANT, E_TOO_LARGE, E_LENGTH, E_BUSY, \
    E_UNAUTHORIZED, E_INTERNAL, E_UNSUPPORTED, E_SHUTTING_DOWN, E_INVALID = range(12)
E_EXPIRED = 13              # version 4: the frame's budget passed before it ran
E_CANCELLED = 14            # version 4: a CANCEL took the frame off the queue
# 12 is never sent (the C codec's local NOSPACE).
CODE_NAMES = ("OK", "VERSION", "PROTOCOL", "UNKNOWN_VARIANT", "TOO_LARGE", "LENGTH", "BUSY",
              "UNAUTHORIZED", "INTERNAL", "UNSUPPORTED", "SHUTTING_DOWN", "INVALID", "NOSPACE",
              "EXPIRED", "CANCELLED")

# dtypes
F32, F16 = 0, 1
DTYPE_SIZE = {F32: 4, F16: 2}

# FILTER flags, RESULT flags, HELLO_OK server flags
FILTER_COMPOSITE = 0x1
FILTER_SHM = 0x2
FILTER_ESTIMATE = 0x4       # version 3: the alpha-corrected estimate follows the features
FILTER_DEADLINE = 0x8       # version 4: a u32 budget_us follows the variant name
BUDGET_MAX = 0xFFFFFFFF     # microseconds
ESTIMATE_VALUES = 3         # its colour, highlight, alpha per pixel
RESULT_INPUT_SANITISED = 0x4
RESULT_OUT_OF_RANGE = 0x8
SERVER_AUTH_REQUIRED = 0x1
SERVER_SHM = 0x2


class ProtocolError(Exception):
    """A frame that breaks PROTOCOL.md; code is the protocol's (E_LENGTH, ...)."""

    def __init__(self, code, what):
        super().__init__("%s: %s" % (CODE_NAMES[code], what))
        self.code = code


def code_name(code):
    """The protocol's name of an error code of either sign, or "UNKNOWN"."""
    code = abs(code)
    return CODE_NAMES[code] if code < len(CODE_NAMES) else "UNKNOWN"


class Reader:
    """Bounds-checked reads over a payload: a short frame is LENGTH."""

    def __init__(self, payload):
        self.b = memoryview(payload)
        self.off = 0

    def take(self, n):
        if self.off + n > len(self.b):
            raise ProtocolError(E_LENGTH, "payload ends early")
        v = self.b[self.off:self.off + n]
        self.off += n
        return v

    def unpack(self, fmt):
        s = struct.Struct("<" + fmt)
        return s.unpack(self.take(s.size))

    def left(self):
        return len(self.b) - self.off

    def text(self, n, maximum, allow_space=False, allow_empty=False):
        if n > maximum or (n == 0 and not allow_empty):
            raise ProtocolError(E_INVALID, "text of %d bytes" % n)
        raw = bytes(self.take(n))
        check_text(raw, allow_space)
        return raw.decode("ascii")

    def end(self):
        if self.off != len(self.b):
            raise ProtocolError(E_LENGTH, "%d trailing bytes" % (len(self.b) - self.off))


def check_text(raw, allow_space=False):
    """Names and tokens: printable ASCII without spaces (messages: with)."""
    lo = 0x20 if allow_space else 0x21
    if any(c < lo or c > 0x7E for c in raw):
        raise ProtocolError(E_INVALID, "a byte outside printable ASCII")


def frame(type_, payload=b"", request_id=0, extra=0):
    """Header + payload; extra counts bytes the caller sends after them."""
    return HEADER.pack(MAGIC, type_, 0, request_id, len(payload) + extra) + payload


def encode_cancel(request_id):
    """CANCEL (version 4) of the FILTER with request_id: an empty payload."""
    if not 1 <= request_id <= 0xFFFFFFFF:
        raise ValueError("CANCEL of request id %d: want 1..2**32-1" % request_id)
    return frame(CANCEL, b"", request_id)


def decode_header(b):
    """(type, request_id, length) of a 16-byte header."""
    magic, type_, flags, rid, length = HEADER.unpack(b)
    if magic != MAGIC or flags != 0 or not 1 <= type_ <= SHM_DESTROY:
        raise ProtocolError(E_PROTOCOL, "bad frame header")
    return type_, rid, length


def _text_bytes(s, maximum, allow_empty=False):
    raw = s.encode("ascii")
    if len(raw) > maximum or (not raw and not allow_empty):
        raise ValueError("%r: want %s..%d bytes" % (s, 0 if allow_empty else 1, maximum))
    check_text(raw)
    return raw


# ---- HELLO / HELLO_OK ---------------------------------------------------------

def encode_hello(client_name, token="", lo=VERSION_MIN, hi=VERSION):
    name = _text_bytes(client_name, NAME_MAX)
    tok = _text_bytes(token or "", TOKEN_MAX, allow_empty=True)
    return frame(HELLO, struct.pack("<HHHH", lo, hi, len(name), len(tok)) + name + tok)


HelloOk = namedtuple("HelloOk", "version server_flags max_width max_height max_spp max_inflight "
                                "dtypes max_batch queue_size max_frame_bytes server_name "
                                "software_version")


def decode_hello_ok(payload):
    r = Reader(payload)
    (version, flags, mw, mh, spp, inflight, dtypes, batch, queue, max_frame,
     nn) = r.unpack("HHIIHHIIIQH")
    name = r.text(nn, NAME_MAX)
    software = ""
    # Version 2: the server's software version after its name, when sent.
    if version >= 2 and r.left():
        (n,) = r.unpack("B")
        software = r.text(n, NAME_MAX, allow_empty=True)
    r.end()
    if not VERSION_MIN <= version <= VERSION:
        raise ProtocolError(E_VERSION, "server chose version %d" % version)
    if not (1 <= spp <= MAX_SPP and 1 <= mw <= MAX_SIDE and 1 <= mh <= MAX_SIDE and
            inflight >= 1 and batch >= 1 and dtypes in (1, 2, 3)):
        raise ProtocolError(E_INVALID, "HELLO_OK limits")
    return HelloOk(version, flags, mw, mh, spp, inflight, dtypes, batch, queue, max_frame, name,
                   software)


# ---- VARIANTS ------------------------------------------------------------------

Variant = namedtuple("Variant", "name backend precision spp levels ranges estimate")
Variant.__doc__ = ("A loaded variant; ranges maps an input statistic's number "
                   "(protocol/FEATURES.md) to its trained (low, high), empty without one; "
                   "estimate is True when it reads the alpha-corrected estimate (version 3).")


def decode_variants(payload):
    r = Reader(payload)
    (count,) = r.unpack("H")
    if count > MAX_VARIANTS:
        raise ProtocolError(E_INVALID, "%d variants" % count)
    out = []
    for _ in range(count):
        name = r.text(r.unpack("B")[0], NAME_MAX)
        backend = r.text(r.unpack("B")[0], NAME_MAX)
        precision = r.text(r.unpack("B")[0], NAME_MAX)
        spp, nl = r.unpack("HH")
        if not 1 <= nl <= MAX_LEVELS or not 1 <= spp <= MAX_SPP:
            raise ProtocolError(E_INVALID, "variant %s" % name)
        levels = r.unpack("%dI" % nl)
        if min(levels) < 1:
            raise ProtocolError(E_INVALID, "variant %s levels" % name)
        out.append(Variant(name, backend, precision, spp, tuple(levels), {}, False))
    # Version 2: one block of ranges per entry after the last one.
    if r.left():
        for v in out:
            (n,) = r.unpack("B")
            if n > 16:
                raise ProtocolError(E_INVALID, "%d ranges" % n)
            for _ in range(n):
                stat, lo, hi = r.unpack("Bdd")
                if stat in v.ranges or not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                    raise ProtocolError(E_INVALID, "range of statistic %d" % stat)
                v.ranges[stat] = (lo, hi)
    # Version 3: the estimate each variant reads, one byte per entry.
    if r.left():
        for i, v in enumerate(out):
            (e,) = r.unpack("B")
            if e > 1:
                raise ProtocolError(E_INVALID, "variant %s: estimate %d" % (v.name, e))
            out[i] = v._replace(estimate=bool(e))
    r.end()
    return out


# ---- FILTER / RESULT ------------------------------------------------------------

FILTER_FIXED = struct.Struct("<HHIIHBB3f3f3f")   # 52 bytes
RESULT_FIXED = struct.Struct("<HBBIIIQQQQQ")     # 56 bytes


def features_bytes(width, height, spp, dtype):
    return width * height * spp * FEATURES * DTYPE_SIZE[dtype]


def output_bytes(width, height, channels, dtype):
    return width * height * channels * DTYPE_SIZE[dtype]


def encode_filter_head(request_id, variant, width, height, spp, in_dtype, out_dtype,
                       composite=False, hair=(0, 0, 0), light=(0, 0, 0), background=(0, 0, 0),
                       shm=None, estimate=False, budget_us=0):
    """The FILTER frame up to its tensor. shm: (segment, in_offset, out_offset,
    rgba_offset) to send a reference instead; the features then do not follow.
    estimate: the features are followed by the frame's alpha-corrected
    estimate, [h][w][3] of in_dtype (flag ESTIMATE, version 3).
    budget_us: 1..2^32-1, the frame's budget from its arrival at the server
    (flag DEADLINE, version 4), after the name; 0: none."""
    name = _text_bytes(variant, NAME_MAX)
    if not (1 <= width <= MAX_SIDE and 1 <= height <= MAX_SIDE and 1 <= spp <= MAX_SPP):
        raise ValueError("frame %dx%d of %d spp: want 1..%d pixels a side, 1..%d spp"
                         % (width, height, spp, MAX_SIDE, MAX_SPP))
    if not 0 <= budget_us <= BUDGET_MAX:
        raise ValueError("budget of %d us: want 1..%d, or 0 for none" % (budget_us, BUDGET_MAX))
    flags = (FILTER_COMPOSITE if composite else 0) | (FILTER_SHM if shm else 0) | \
        (FILTER_ESTIMATE if estimate else 0) | (FILTER_DEADLINE if budget_us else 0)
    fixed = FILTER_FIXED.pack(len(name), flags, width, height, spp, in_dtype, out_dtype,
                              *hair, *light, *background)
    if budget_us:
        name += struct.pack("<I", budget_us)
    if shm:
        seg, off_in, off_out, off_rgba = shm
        ref = struct.pack("<IIQQQ", seg, 0, off_in, off_out, off_rgba)
        return frame(FILTER, fixed + name + ref, request_id)
    return frame(FILTER, fixed + name, request_id,
                 extra=features_bytes(width, height, spp, in_dtype) +
                 (output_bytes(width, height, ESTIMATE_VALUES, in_dtype) if estimate else 0))


ResultHead = namedtuple("ResultHead", "status dtype flags width height batch queue_us input_us "
                                      "infer_us output_us total_us")


def decode_result_head(head, length):
    """The 56 fixed bytes of a RESULT whose payload is length bytes."""
    h = ResultHead(*RESULT_FIXED.unpack(head))
    if h.status:
        if length != RESULT_FIXED.size:
            raise ProtocolError(E_LENGTH, "failed RESULT with tensors")
        return h
    if h.dtype not in DTYPE_SIZE or h.batch < 1:
        raise ProtocolError(E_INVALID, "RESULT fields")
    tensors = 0
    if not h.flags & FILTER_SHM:
        tensors = output_bytes(h.width, h.height, OUTPUTS, h.dtype)
        if h.flags & FILTER_COMPOSITE:
            tensors += output_bytes(h.width, h.height, 4, h.dtype)
    if length != RESULT_FIXED.size + tensors:
        raise ProtocolError(E_LENGTH, "RESULT of %d bytes" % length)
    return h


# ---- ERROR ------------------------------------------------------------------------

def decode_error(payload):
    """(code, fatal, message)."""
    r = Reader(payload)
    code, fatal, _, n = r.unpack("IBBH")
    message = r.text(n, MESSAGE_MAX, allow_space=True, allow_empty=True)
    r.end()
    if code == 0 or fatal > 1:
        raise ProtocolError(E_INVALID, "ERROR fields")
    return code, bool(fatal), message


# ---- STATS -------------------------------------------------------------------------

VariantStats = namedtuple("VariantStats", "name requests_ok requests_failed rejected batches "
                                          "sum_queue_us sum_infer_us sum_total_us hist_total "
                                          "hist_infer out_of_range frames_sanitised cache_bytes "
                                          "expired cancelled")
Stats = namedtuple("Stats", "uptime_us connections_total connections_open queue_depth "
                            "queue_capacity protocol_errors variants")


def decode_stats(payload):
    r = Reader(payload)
    uptime, total, open_, depth, cap, perr, nv, nb = r.unpack("QQIIIQHH")
    if nv > MAX_VARIANTS or nb != HIST_BUCKETS:
        raise ProtocolError(E_INVALID, "STATS_REPLY sizes")
    rows = []
    for _ in range(nv):
        name = r.text(r.unpack("B")[0], NAME_MAX)
        counts = r.unpack("7Q")
        ht = r.unpack("%dQ" % nb)
        hi = r.unpack("%dQ" % nb)
        rows.append([name, *counts, ht, hi, 0, 0, 0, 0, 0])
    # Version 2: per-variant counters after the last entry; known ones first
    # (version 4 adds expired and cancelled).
    if r.left():
        (nc,) = r.unpack("H")
        if not 1 <= nc <= 64:
            raise ProtocolError(E_INVALID, "%d counters" % nc)
        for row in rows:
            counters = r.unpack("%dQ" % nc)
            row[10:15] = (list(counters) + [0] * 5)[:5]
    r.end()
    return Stats(uptime, total, open_, depth, cap, perr, [VariantStats(*row) for row in rows])


# ---- shared segments ------------------------------------------------------------

def encode_shm_create(nbytes):
    if nbytes < 1:
        raise ValueError("a segment of %d bytes" % nbytes)
    return frame(SHM_CREATE, struct.pack("<Q", nbytes))


def decode_shm_created(payload):
    r = Reader(payload)
    seg, nbytes = r.unpack("IQ")
    r.end()
    if not seg or not nbytes:
        raise ProtocolError(E_INVALID, "SHM_CREATED fields")
    return seg, nbytes


def encode_shm_destroy(segment):
    return frame(SHM_DESTROY, struct.pack("<I", segment))


# ---- addresses (PROTOCOL.md, "Addresses") ----------------------------------------

Address = namedtuple("Address", "kind path host port")   # kind "unix", "tcp" or "tls"

_HOST_CHARS = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-._")
_V6_CHARS = set("0123456789abcdefABCDEF:.")


def parse_url(url):
    """unix:PATH, tcp:HOST:PORT, tcp:[IPV6]:PORT or tcp:PORT, and the same with
    tls: (TCP with TLS), as hfp_url_parse reads them; ValueError naming the
    URL and what is wrong."""
    def bad(why):
        return ValueError("bad URL '%.120s': %s" % (url, why))
    if url.startswith("unix:"):
        path = url[5:]
        if not path:
            raise bad("empty socket path")
        if len(path.encode()) > 107:
            raise bad("socket path longer than 107 bytes")
        return Address("unix", path, None, None)
    kind = url[:3]
    if not url.startswith("tcp:") and not url.startswith("tls:"):
        raise bad("want unix:PATH, tcp:HOST:PORT, tls:HOST:PORT or tcp:PORT")
    rest = url[4:]
    if rest.startswith("//"):
        raise bad("no '//' after '%s:': write %s:HOST:PORT" % (kind, kind))
    if rest.startswith("["):
        close = rest.find("]")
        if close < 0:
            raise bad("'[' without ']' around the IPv6 address")
        host = rest[1:close]
        addr = host.split("%", 1)[0]
        if not addr:
            raise bad("empty IPv6 address")
        if any(c not in _V6_CHARS for c in addr):
            raise bad("a character that is not in an IPv6 address")
        if rest[close + 1:close + 2] != ":":
            raise bad("want [ADDRESS]:PORT")
        port_s = rest[close + 2:]
    elif ":" in rest:
        host, port_s = rest.split(":", 1)
        if ":" in port_s:
            raise bad("an IPv6 address goes in brackets: tcp:[ADDRESS]:PORT")
        if not host:
            raise bad("empty host before ':'")
        if any(c not in _HOST_CHARS for c in host):
            raise bad("a character that is not in a host name")
    else:
        host, port_s = "127.0.0.1", rest
    if not port_s:
        raise bad("no port")
    if not port_s.isascii() or not port_s.isdigit():
        raise bad("port '%.20s' is not a decimal number" % port_s)
    port = int(port_s)
    if not 1 <= port <= 65535:
        raise bad("port %s is outside 1..65535" % port_s)
    return Address(kind, None, host, port)
