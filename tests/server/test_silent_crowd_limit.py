#!/usr/bin/env python3
"""Peers that connect and never say HELLO cannot hold every connection slot.

With --max-handshakes (default 32) not below --max-connections (6 here),
a crowd of silent peers filled all 6 slots and a client that said HELLO
got BUSY "connection limit (6) reached": --max-handshakes never came into
play (hairfilter conformance's handshake.crowd failed against such a
daemon). The daemon now holds such peers to half the slots, saying so at
start, so the crowd's oldest is closed for the client.

usage: test_silent_crowd_limit.py HAIRFILTERD WEIGHTS_DIR
"""
import os
import socket
import sys
import tempfile
import time

from rawwire import check, finish, hello, require_started, start, stop_and_clean

HAIRFILTERD, WEIGHTS = sys.argv[1:3]


def main():
    w = tempfile.mkdtemp(prefix="hfcrowd-")
    proc = None
    crowd = []
    try:
        proc, sock = start(HAIRFILTERD, w,
                           ["--weights", os.path.join(WEIGHTS, "small.safetensors"),
                            "--max-connections", "6"])
        require_started(sock)
        with open(os.path.join(w, "daemon.log")) as f:
            log = f.read()
        check("--max-handshakes 32 is not below --max-connections 6" in log and
              "3 of them at most" in log,
              "the start says that --max-handshakes was held below the connection limit: %r"
              % log[-600:])
        for _ in range(10):
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            s.connect(sock)
            crowd.append(s)
        time.sleep(0.3)   # the loop accepts them all
        for attempt in range(3):
            kind, got = hello(sock)
            check(kind == "ok", "a client after 10 silent peers (try %d): %s %r"
                  % (attempt + 1, kind, got))
            if kind == "ok":
                got.close()
    finally:
        for s in crowd:
            s.close()
        stop_and_clean(proc, w)
    finish()


main()
