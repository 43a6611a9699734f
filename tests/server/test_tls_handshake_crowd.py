#!/usr/bin/env python3
"""On a TLS listener, a crowd of bare TCP connections does not push out a
client in the middle of its TLS handshake (--max-handshakes).

On a plain listener a client's HELLO arrives with its connection, and a
connection whose whole HELLO waits unread is passed over when a newer one
needs a slot. Over TLS the HELLO comes only after the handshake's round
trips, and the daemon refused the oldest connection before its HELLO
whatever it had sent: peers that only connect, each cheaper than a real
client, pushed it out in the middle of its handshake. Now a peer the
daemon has not answered goes first: one that has sent nothing, or less
than a ClientHello (a byte, the start of one), which costs it no more.

The client here stops after the server's first flight, as a client on a
slow link would, while more bare connections than --max-handshakes
arrive; then it ends its handshake and says HELLO.

usage: test_tls_handshake_crowd.py HAIRFILTERD WEIGHTS_DIR MAKE_TEST_CERTS
"""
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time

from rawwire import check, failures, finish, stop
from tlswire import Tls, start_tls

HAIRFILTERD, WEIGHTS, MAKE_TEST_CERTS = sys.argv[1:4]
TOKEN = b"crowd-token"
failed = []   # the crowds a check failed with


# What each peer of the crowd sends: nothing; one byte; the start of a
# ClientHello (a record header and a handshake header, the rest never
# sent). None of it is a ClientHello the daemon can answer, so none costs
# the peer more than a bare connection does.
CROWDS = [("silent", b""), ("one byte", b"\x16"),
          ("the start of a ClientHello", bytes([0x16, 3, 1, 1, 0, 1, 0, 0, 0xfc, 3, 3]))]


def main():
    w = tempfile.mkdtemp(prefix="hftlscrowd-")
    certs = os.path.join(w, "certs")
    os.mkdir(certs)
    subprocess.run([MAKE_TEST_CERTS, certs], check=True)
    try:
        for what, sends in CROWDS:
            run(w, certs, what, sends)
    finally:
        shutil.rmtree(w, ignore_errors=True)
    failures.extend("with a crowd that sent %s" % what for what in failed)
    finish()


def run(w, certs, what, sends):
    proc, crowd = None, []
    try:
        with open(os.path.join(w, "token"), "w") as f:
            f.write(TOKEN.decode())
        proc, port = start_tls(HAIRFILTERD, WEIGHTS, w, certs,
                               ["--auth-token-file", os.path.join(w, "token"),
                                "--max-handshakes", "4"])
        check(port is not None, "the daemon started")
        if port is None:
            raise RuntimeError("hairfilterd did not start")
        # Bare connections before the client, so it is not the oldest.
        for _ in range(4):
            crowd.append(socket.create_connection(("127.0.0.1", port)))
        time.sleep(0.3)
        c = Tls(port, os.path.join(certs, "ca.pem"))
        check(not c.step(), "the handshake needs the server's answer")
        c.flush()      # ClientHello
        c.feed()       # the server's first flight
        # A crowd twice --max-handshakes arrives while the client works.
        for _ in range(8):
            crowd.append(socket.create_connection(("127.0.0.1", port)))
            if sends:
                crowd[-1].sendall(sends)
        time.sleep(0.5)
        c.handshake()
        got = c.hello(TOKEN)
        check(got == "HELLO_OK", "the client in the middle of its handshake is served, not pushed "
              "out by a crowd (%s) that sent %s" % (got, what))
        c.sock.close()
    finally:
        for s in crowd:
            s.close()
        log = stop(proc, w) if proc else ""
        if failures:
            print(log)
            del failures[:]   # said with this crowd's log; counted below
            failed.append(what)


if __name__ == "__main__":
    main()
