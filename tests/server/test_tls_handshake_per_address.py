#!/usr/bin/env python3
"""A flood of ClientHellos from one address cannot push out a TLS client
of another address in the middle of its handshake
(--max-handshakes-per-address; docs/SERVER.md, "Handshakes and slow
peers").

Every connection before its HELLO counts against --max-handshakes, and
one more pushes out the oldest whose HELLO (over TLS: whose record) is
not waiting. A peer replaying a recorded ClientHello on new connections
made them all answered and stalled handshakes, among which the real
client, stopped after the server's first flight (a slow link), was the
oldest: it was refused. Now one IP address holds at most
--max-handshakes-per-address of them (4 here, of 8), and one more closes
that address's own oldest, or the new one; other addresses' clients keep
their slots.

Here a client from 127.0.0.2 sends its ClientHello and reads the server's
first flight; 127.0.0.1 then opens 48 connections that each send a
ClientHello and stall; the client ends its handshake and says HELLO, and
a client from 127.0.0.3 makes a whole handshake meanwhile. Both get
HELLO_OK; the flood is left 4 connections at most, and the refusals are
logged, rate-limited.

usage: test_tls_handshake_per_address.py HAIRFILTERD WEIGHTS_DIR MAKE_TEST_CERTS
"""
import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time

from rawwire import check, failures, finish, stop
from tlswire import Tls, burst, client_hello, start_tls

HAIRFILTERD, WEIGHTS, MAKE_TEST_CERTS = sys.argv[1:4]
PER_ADDRESS = 4
ROUNDS, BURST = 3, 16


def still_open(s):
    """Whether the daemon keeps s open: its bytes (the server's flight)
    are read until it closes or stays quiet for a while."""
    s.setblocking(True)
    s.settimeout(0.5)
    try:
        while True:
            if not s.recv(65536):
                return False
    except socket.timeout:
        return True
    except OSError:
        return False


def main():
    w = tempfile.mkdtemp(prefix="hftlsaddr-")
    certs = os.path.join(w, "certs")
    os.mkdir(certs)
    subprocess.run([MAKE_TEST_CERTS, certs], check=True)
    ca = os.path.join(certs, "ca.pem")
    proc, flood = None, []
    try:
        proc, port = start_tls(HAIRFILTERD, WEIGHTS, w, certs,
                               ["--no-auth", "--max-handshakes", str(2 * PER_ADDRESS)])
        check(port is not None, "the daemon started")
        if port is None:
            raise RuntimeError("hairfilterd did not start")
        hello = client_hello()
        c = Tls(port, ca, "127.0.0.2", timeout=20)
        check(not c.step(), "the handshake needs the server's answer")
        c.flush()      # ClientHello
        c.feed()       # the server's first flight: this client is answered
        t0 = time.time()
        for _ in range(ROUNDS):
            flood += burst(port, hello, BURST, 5)[0]
            time.sleep(0.2)
        # Another address makes a whole handshake while the flood's
        # connections are there.
        c2 = Tls(port, ca, "127.0.0.3", timeout=20)
        c2.handshake()
        got2 = c2.hello()
        took = time.time() - t0
        c.handshake()
        got = c.hello()
        check(got == "HELLO_OK", "the client of 127.0.0.2, in the middle of its handshake "
              "during a flood of %d ClientHellos from 127.0.0.1, is served (%s)"
              % (ROUNDS * BURST, got))
        check(got2 == "HELLO_OK", "a client of 127.0.0.3 completes its handshake during the "
              "flood (%s)" % got2)
        left = sum(still_open(s) for s in flood)
        check(left <= PER_ADDRESS, "127.0.0.1 is left at most %d connections before their "
              "HELLO (%d of %d open)" % (PER_ADDRESS, left, len(flood)))
        c.sock.close()
        c2.sock.close()
        time.sleep(0.2)
        log = open(os.path.join(w, "daemon.log")).read()
        lines = len(re.findall(r"too many connections before their HELLO from address "
                               r"127\.0\.0\.1 \(--max-handshakes-per-address %d\)"
                               % PER_ADDRESS, log))
        print("flood of %d in %.2f s: %d left open, %d refusal line(s)"
              % (len(flood), took, left, lines))
        check(lines >= 1, "the refusals are logged, naming the address and the option")
        check(lines <= 20 * (int(took) + 3),
              "at most 20 such lines a second (%d in %.2f s)" % (lines, took))
    finally:
        for s in flood:
            s.close()
        log = stop(proc, w) if proc else ""
        if failures:
            print(log[-4000:])
        shutil.rmtree(w, ignore_errors=True)
    finish()


if __name__ == "__main__":
    main()
