#!/usr/bin/env python3
"""A fatal refusal of a bad header or a malformed control message names
the field or the message at fault and what it must be.

A bad header was refused as "bad frame header (magic, type or flags)",
whichever of the three it was; a control message with the wrong payload
length as "this request has no payload" or "malformed shared-memory
request", without the message's type or its length; a request before
HELLO as "HELLO must come first", without what came instead. Each case
sends one such frame on a fresh connection and checks the fatal ERROR's
code and the words its message must hold.

usage: test_header_refusal_text.py HAIRFILTERD WEIGHTS_DIR
"""
import os
import socket
import struct
import sys
import tempfile

from rawwire import (ERROR, HELLO, HELLO_OK, MAGIC, check, finish, read_frame, require_started,
                     start, stop_and_clean)

HAIRFILTERD, WEIGHTS = sys.argv[1:3]
PROTOCOL, LENGTH = 2, 5
STATS, SHM_CREATE, SHM_DESTROY, CANCEL = 8, 10, 12, 13


def raw(t, payload=b"", flags=0, magic=MAGIC, rid=0):
    return struct.pack("<IHHII", magic, t, flags, rid, len(payload)) + payload


def hello():
    return raw(HELLO, struct.pack("<HHHH", 1, 4, 4, 0) + b"text")


# (what, whether HELLO goes first, the frame, code, words the message must hold)
CASES = [
    ("bad magic", True, raw(STATS, magic=0x32504648), PROTOCOL, ["magic 0x32504648", "HFP1"]),
    ("unknown type", True, raw(99), PROTOCOL, ["message type 99"]),
    ("header flags", True, raw(STATS, flags=1), PROTOCOL, ["flags 0x0001", "STATS", "must be 0"]),
    ("CANCEL before HELLO", False, raw(CANCEL, rid=5), PROTOCOL, ["HELLO must come first",
                                                                  "CANCEL (type 13)"]),
    ("CANCEL with a payload", True, raw(CANCEL, b"x", rid=5), LENGTH,
     ["CANCEL has an empty payload", "1 bytes"]),
    ("STATS with a payload", True, raw(STATS, b"abc"), LENGTH,
     ["STATS has an empty payload", "3 bytes"]),
    ("SHM_CREATE of 9 bytes", True, raw(SHM_CREATE, bytes(9)), LENGTH,
     ["SHM_CREATE", "its payload is 9 bytes; it must be 8"]),
    ("SHM_DESTROY of 3 bytes", True, raw(SHM_DESTROY, bytes(3)), LENGTH,
     ["SHM_DESTROY", "its payload is 3 bytes; it must be 4"]),
]


def main():
    w = tempfile.mkdtemp(prefix="hfheadertext-")
    proc = None
    try:
        proc, sock = start(HAIRFILTERD, w,
                           ["--weights", os.path.join(WEIGHTS, "small.safetensors")])
        require_started(sock)
        for what, after_hello, data, code, words in CASES:
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            s.settimeout(20)
            s.connect(sock)
            if after_hello:
                s.sendall(hello())
                t, _, _ = read_frame(s)
                check(t == HELLO_OK, "%s: HELLO_OK first (type %d)" % (what, t))
            s.sendall(data)
            t, rid, p = read_frame(s)
            check(t == ERROR, "%s: an ERROR (type %d)" % (what, t))
            if t == ERROR:
                c, fatal, _, n = struct.unpack("<IBBH", p[:8])
                msg = p[8:8 + n].decode()
                check(c == code and fatal == 1 and rid == 0,
                      "%s: fatal %d with id 0 (got %d fatal %d id %d: %s)" %
                      (what, code, c, fatal, rid, msg))
                for word in words:
                    check(word in msg, "%s: the message names %r (%s)" % (what, word, msg))
            s.close()
    finally:
        stop_and_clean(proc, w)
    finish()


main()
