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
import ssl
import struct
import subprocess
import sys
import tempfile
import time

from rawwire import (ERROR, HELLO, HELLO_OK, check, failures, finish, frame, recvn, stop)

HAIRFILTERD, WEIGHTS, MAKE_TEST_CERTS = sys.argv[1:4]
TOKEN = b"crowd-token"
failed = []   # the crowds a check failed with


def start(w, certs):
    """hairfilterd on a TLS listener: (process, port), or (process, None)."""
    ready = os.path.join(w, "ready")
    with open(os.path.join(w, "token"), "w") as f:
        f.write(TOKEN.decode())
    with open(os.path.join(w, "daemon.log"), "w") as log:
        proc = subprocess.Popen(
            [HAIRFILTERD, "--config", "none", "--backend", "cpu", "--ready-file", ready,
             "--weights", os.path.join(WEIGHTS, "small.safetensors"),
             "--listen", "tls:127.0.0.1:0", "--tls-cert", os.path.join(certs, "server.pem"),
             "--tls-key", os.path.join(certs, "server.key"),
             "--auth-token-file", os.path.join(w, "token"), "--max-handshakes", "4"],
            stdout=log, stderr=subprocess.STDOUT)
    deadline = time.time() + 60
    while time.time() < deadline and not os.path.exists(ready):
        if proc.poll() is not None:
            return proc, None
        time.sleep(0.02)
    if not os.path.exists(ready):
        return proc, None
    return proc, int(open(ready).read().split()[0].rsplit(":", 1)[1])


class Tls:
    """A TLS client driven by hand over a socket, so that it can stop in
    the middle of its handshake."""

    def __init__(self, port, ca):
        ctx = ssl.create_default_context(cafile=ca)
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=10)
        self.inc, self.out = ssl.MemoryBIO(), ssl.MemoryBIO()
        self.obj = ctx.wrap_bio(self.inc, self.out, server_hostname="localhost")

    def step(self):
        """One handshake step: 1 when it is done, else 0 (bytes to send
        are in self.out)."""
        try:
            self.obj.do_handshake()
            return 1
        except ssl.SSLWantReadError:
            return 0

    def flush(self):
        data = self.out.read()
        if data:
            self.sock.sendall(data)

    def feed(self):
        data = self.sock.recv(65536)
        if not data:
            raise EOFError("the daemon closed the connection")
        self.inc.write(data)

    def handshake(self):
        while not self.step():
            self.flush()
            self.feed()
        self.flush()

    def send(self, data):
        self.obj.write(data)
        self.flush()

    def recv(self, n):
        out = b""
        while len(out) < n:
            try:
                out += self.obj.read(n - len(out))
            except ssl.SSLWantReadError:
                self.feed()
        return out


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
        proc, port = start(w, certs)
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
        c.send(frame(HELLO, struct.pack("<HHHH", 1, 3, 4, len(TOKEN)) + b"test" + TOKEN))
        _, t, _, _, n = struct.unpack("<IHHII", c.recv(16))
        p = c.recv(n)
        got = "HELLO_OK"
        if t == ERROR:
            got = "ERROR %d: %s" % (struct.unpack("<I", p[:4])[0], p[8:].decode(errors="replace"))
        check(t == HELLO_OK, "the client in the middle of its handshake is served, not pushed "
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
