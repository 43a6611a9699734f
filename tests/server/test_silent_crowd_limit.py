#!/usr/bin/env python3
"""Peers that connect and never say HELLO cannot hold every connection slot.

With --max-handshakes (default 32) not below --max-connections (6 here),
a crowd of silent peers filled all 6 slots and a client that said HELLO
got BUSY "connection limit (6) reached": --max-handshakes never came into
play (hairfilter conformance's handshake.crowd failed against such a
daemon). At the connection limit the oldest connection whose HELLO has
not arrived is now closed for the newcomer, with a fatal BUSY saying so;
clients that have said HELLO keep their slots, and a newcomer when every
slot is such a client still gets the connection limit's BUSY.

usage: test_silent_crowd_limit.py HAIRFILTERD WEIGHTS_DIR
"""
import os
import socket
import struct
import sys
import tempfile
import time

from rawwire import (ERROR, check, finish, hello, read_frame, require_started, start,
                     stop_and_clean)

HAIRFILTERD, WEIGHTS = sys.argv[1:3]
BUSY = 6


def main():
    w = tempfile.mkdtemp(prefix="hfcrowd-")
    proc = None
    crowd, held = [], []
    try:
        proc, sock = start(HAIRFILTERD, w,
                           ["--weights", os.path.join(WEIGHTS, "small.safetensors"),
                            "--max-connections", "6"])
        require_started(sock)
        for _ in range(10):
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            s.settimeout(5)
            s.connect(sock)
            crowd.append(s)
        time.sleep(0.3)   # the loop accepts them all
        for attempt in range(6):
            kind, got = hello(sock)
            check(kind == "ok", "a client after 10 silent peers (try %d of 6): %s %r"
                  % (attempt + 1, kind, got))
            if kind == "ok":
                held.append(got)
        # Every slot holds a client that said HELLO: the next one is refused.
        kind, got = hello(sock)
        check(kind == "error" and got[0] == BUSY and got[1] == 1 and
              got[2] == "connection limit (6) reached",
              "a 7th client beside 6 that said HELLO: %s %r" % (kind, got))
        # The silent peers pushed out were told why.
        told = 0
        for s in crowd:
            try:
                t, _, p = read_frame(s)
            except (OSError, EOFError):
                continue
            if t == ERROR:
                code, fatal, _, n = struct.unpack("<IBBH", p[:8])
                msg = p[8:8 + n].decode()
                check(code == BUSY and fatal == 1 and
                      "the oldest connection without its HELLO is closed for a newer one" in msg,
                      "a silent peer pushed out: code %d fatal %d %r" % (code, fatal, msg))
                told += 1
        check(told >= 6, "at least 6 silent peers told why they were closed (%d)" % told)
    finally:
        for s in crowd + held:
            s.close()
        stop_and_clean(proc, w)
    finish()


main()
