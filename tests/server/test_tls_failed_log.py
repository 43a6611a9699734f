#!/usr/bin/env python3
"""Failed TLS handshakes, which any peer can cause as fast as it connects,
are logged at most 20 a second, as the protocol's error lines are; the
rest are counted in the next line.

Each was an error line: a peer sending a malformed ClientHello, or the
plain protocol, on new connections wrote thousands a second to the log,
and under systemd journald's own rate limit then drops every line of the
service for the rest of its interval, an operator's real errors too.

usage: test_tls_failed_log.py HAIRFILTERD WEIGHTS_DIR MAKE_TEST_CERTS
"""
import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time

from rawwire import HELLO, check, failures, finish, frame, stop
from tlswire import start_tls

# A handshake record holding a ClientHello one byte long: OpenSSL refuses
# it at once (a decode error).
BAD_HELLO = bytes([0x16, 3, 1, 0, 5, 1, 0, 0, 1, 0])
PLAIN_HELLO = frame(HELLO, b"\x01\x00\x03\x00\x04\x00\x00\x00test")
PEERS = 200


def peer(port, data):
    """Sends data on a new connection and waits for the daemon to close it."""
    s = socket.create_connection(("127.0.0.1", port), timeout=10)
    s.sendall(data)
    try:
        while s.recv(4096):
            pass
    except OSError:
        pass
    s.close()


def main():
    hairfilterd, weights, make_certs = sys.argv[1:4]
    w = tempfile.mkdtemp(prefix="hftlslog-")
    certs = os.path.join(w, "certs")
    os.mkdir(certs)
    subprocess.run([make_certs, certs], check=True)
    proc = None
    try:
        proc, port = start_tls(hairfilterd, weights, w, certs, ["--no-auth"])
        check(port is not None, "the daemon started")
        if port is None:
            raise RuntimeError("hairfilterd did not start")
        t0 = time.time()
        for i in range(PEERS):
            peer(port, BAD_HELLO if i % 2 == 0 else PLAIN_HELLO)
        took = time.time() - t0
        time.sleep(1.2)
        peer(port, BAD_HELLO)   # a line in a new second says how many were dropped
        time.sleep(0.3)
        log = open(os.path.join(w, "daemon.log")).read()
        lines = len(re.findall(r"TLS handshake failed|plain-text HELLO on TLS listener", log))
        dropped = sum(int(n) for n in re.findall(r"(\d+) error line\(s\) suppressed", log))
        print("%d peers in %.2f s: %d lines, %d counted as suppressed" % (PEERS + 1, took, lines,
                                                                           dropped))
        # 20 a second, over the seconds the peers took and the last one.
        check(lines <= 20 * (int(took) + 3),
              "at most 20 such lines a second (%d lines for %d peers in %.2f s)"
              % (lines, PEERS + 1, took))
        check(lines + dropped == PEERS + 1,
              "every failure logged or counted as suppressed (%d + %d of %d)"
              % (lines, dropped, PEERS + 1))
    finally:
        log = stop(proc, w) if proc else ""
        if failures:
            print(log[-3000:])
        shutil.rmtree(w, ignore_errors=True)
    finish()


if __name__ == "__main__":
    main()
