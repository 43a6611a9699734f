#!/usr/bin/env python3
"""A malformed FILTER or HELLO is refused with a message that names the
field at fault and what it must be, not the error code's name alone.

Every fault the codec finds in a FILTER's own fields was refused as
"malformed FILTER: field out of range" or "... payload length does not
match its fields": a client that set a DEADLINE budget of 0, cut its
budget short or sent a tensor one byte long could not tell which field
to fix. Each case below sends one such FILTER on a version-4 connection
and checks the non-fatal ERROR's code, its request id, the words its
message must hold, and that the connection still serves STATS.

usage: test_filter_refusal_text.py HAIRFILTERD WEIGHTS_DIR
"""
import os
import socket
import struct
import sys
import tempfile

from rawwire import (ERROR, FILTER, HELLO, HELLO_OK, STATS, STATS_REPLY, check, finish, frame,
                     read_frame, require_started, start, stop_and_clean)

HAIRFILTERD, WEIGHTS = sys.argv[1:3]
LENGTH, INVALID, UNSUPPORTED = 5, 11, 9
NAME, SPP = b"Small", 4
COMPOSITE, SHM, DEADLINE = 1, 2, 8


def hello_v4(path):
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(20)
    s.connect(path)
    s.sendall(frame(HELLO, struct.pack("<HHHH", 1, 4, 4, 0) + b"text"))
    t, _, p = read_frame(s)
    if t != HELLO_OK or struct.unpack("<H", p[:2])[0] != 4:
        raise RuntimeError("no version-4 HELLO_OK (type %d)" % t)
    return s


def fixed(flags=0, w=2, h=2, spp=SPP, dtypes=(0, 0), colours=(0.5,) * 9, name=NAME,
          name_len=None):
    return (struct.pack("<HHIIHBB", len(name) if name_len is None else name_len, flags, w, h,
                        spp, dtypes[0], dtypes[1]) + struct.pack("<9f", *colours) + name)


TENSOR = 2 * 2 * SPP * 6 * 4
REF = struct.pack("<IIQQQ", 7, 0, 0, 4096, 0)
NAN = float("nan")

# (what, payload, code, words the message must hold)
CASES = [
    ("budget 0", fixed(DEADLINE) + struct.pack("<I", 0) + bytes(TENSOR), INVALID,
     ["budget_us", "1..4294967295"]),
    ("tensor one byte short, with DEADLINE",
     fixed(DEADLINE) + struct.pack("<I", 1000) + bytes(TENSOR - 1), LENGTH,
     ["tensor is %d bytes" % (TENSOR - 1), "needs %d" % TENSOR]),
    ("tensor one byte long, with DEADLINE",
     fixed(DEADLINE) + struct.pack("<I", 1000) + bytes(TENSOR + 1), LENGTH,
     ["tensor is %d bytes" % (TENSOR + 1), "needs %d" % TENSOR]),
    ("budget cut short", fixed(DEADLINE) + b"\x01\x00", LENGTH, ["budget_us"]),
    ("variant_len 0", fixed(name_len=0), INVALID, ["variant_len 0", "1..64"]),
    ("name past the payload", fixed(name_len=40), LENGTH, ["40-byte variant name"]),
    ("name byte", fixed(name=b"Sm ll") + bytes(TENSOR), INVALID, ["byte 2", "0x20"]),
    ("unknown flag", fixed(0x10) + bytes(TENSOR), UNSUPPORTED, ["0x0010"]),
    ("dtype", fixed(dtypes=(0, 7)) + bytes(TENSOR), UNSUPPORTED, ["out_dtype 7"]),
    ("colour", fixed(colours=(0.5, 0.5, 0.5, 0.5, NAN, 0.5, 0.5, 0.5, 0.5)) + bytes(TENSOR),
     INVALID, ["light colour component 1"]),
    ("spp", fixed(spp=0) + bytes(TENSOR), INVALID, ["spp 0"]),
    ("width", fixed(w=0) + bytes(TENSOR), INVALID, ["width 0"]),
    ("height", fixed(h=70000) + bytes(TENSOR), INVALID, ["height 70000"]),
    ("SHM segment 0", fixed(SHM | DEADLINE) + struct.pack("<I", 5) +
     struct.pack("<IIQQQ", 0, 0, 0, 4096, 0), INVALID, ["segment 0"]),
    ("SHM reserved word", fixed(SHM) + struct.pack("<IIQQQ", 7, 3, 0, 4096, 0), INVALID,
     ["reserved word is 3"]),
    ("SHM rgba without COMPOSITE", fixed(SHM) + struct.pack("<IIQQQ", 7, 0, 0, 4096, 8192),
     INVALID, ["rgba_offset is 8192"]),
    ("SHM payload long", fixed(SHM) + REF + b"x", LENGTH, ["32-byte reference"]),
]

PROTOCOL = 2
# A malformed HELLO, a fatal PROTOCOL: (what, payload, words the message must hold)
HELLO_CASES = [
    ("name_len 0", struct.pack("<HHHH", 1, 4, 0, 0),
     ["malformed HELLO", "name_len 0 is outside 1..64"]),
    ("token_len 257", struct.pack("<HHHH", 1, 4, 4, 257) + b"text",
     ["token_len 257 is outside 0..256"]),
    ("name byte", struct.pack("<HHHH", 1, 4, 4, 0) + b"te t", ["client name byte 2 is 0x20"]),
    ("trailing byte", struct.pack("<HHHH", 1, 4, 4, 0) + b"textx",
     ["the payload is 13 bytes but its fields", "make 12"]),
    ("of 5 bytes", bytes(5), ["its payload is 5 bytes; a HELLO's is 9 to 328"]),
]


def main():
    w = tempfile.mkdtemp(prefix="hffiltertext-")
    proc = None
    try:
        proc, sock = start(HAIRFILTERD, w,
                           ["--weights", os.path.join(WEIGHTS, "small.safetensors")])
        require_started(sock)
        s = hello_v4(sock)
        for i, (what, payload, code, words) in enumerate(CASES):
            rid = 100 + i
            s.sendall(frame(FILTER, payload, rid))
            t, got_id, p = read_frame(s)
            check(t == ERROR, "%s: an ERROR (type %d)" % (what, t))
            if t != ERROR:
                continue
            c, fatal, _, n = struct.unpack("<IBBH", p[:8])
            msg = p[8:8 + n].decode()
            check(c == code and fatal == 0 and got_id == rid,
                  "%s: non-fatal %d for request %d (got %d fatal %d id %d: %s)" %
                  (what, code, rid, c, fatal, got_id, msg))
            for word in words:
                check(word in msg, "%s: the message names %r (%s)" % (what, word, msg))
        s.sendall(frame(STATS))
        t, _, _ = read_frame(s)
        check(t == STATS_REPLY, "the connection still serves STATS")
        s.close()
        for what, payload, words in HELLO_CASES:
            h = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            h.settimeout(20)
            h.connect(sock)
            h.sendall(frame(HELLO, payload))
            t, _, p = read_frame(h)
            check(t == ERROR, "HELLO %s: an ERROR (type %d)" % (what, t))
            if t == ERROR:
                c, fatal, _, n = struct.unpack("<IBBH", p[:8])
                msg = p[8:8 + n].decode()
                check(c == PROTOCOL and fatal == 1, "HELLO %s: fatal PROTOCOL (got %d fatal %d: "
                      "%s)" % (what, c, fatal, msg))
                for word in words:
                    check(word in msg, "%s: the message names %r (%s)" % (what, word, msg))
            h.close()
    finally:
        stop_and_clean(proc, w)
    finish()


main()
