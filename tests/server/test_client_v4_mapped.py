#!/usr/bin/env python3
"""An IPv4 peer is one client whether it reaches an IPv4 listener or an
IPv6 one that takes IPv4 connections (docs/SERVER.md, "Limits and
backpressure").

An IPv6 listener open to IPv4 (a dual-stack [::], or a v4-mapped
address) sees an IPv4 peer as ::ffff:A.B.C.D. Named so, the peer was
another client than on an IPv4 listener: twice its part of the handshake
slots (--max-handshakes-per-address) and twice its share of the queue, by
opening connections to both listeners.

Here the daemon listens on tcp:[::ffff:127.0.0.1]:0 and tcp:127.0.0.1:0
with --max-handshakes-per-address 1. A silent connection to the first,
then one to the second, from 127.0.0.1: the second is the address's
second before its HELLO, and the first (the older, silent) is closed with
a fatal BUSY naming the option and the address 127.0.0.1.

usage: test_client_v4_mapped.py HAIRFILTERD WEIGHTS_DIR
"""
import os
import socket
import struct
import sys
import tempfile

from rawwire import BUSY, ERROR, check, connect, finish, read_frame, ready_ports, \
    require_started, start, stop_and_clean, v4_mapped_unavailable

HAIRFILTERD, WEIGHTS = sys.argv[1:3]


def main():
    why = v4_mapped_unavailable()
    if why:
        print("SKIP: no IPv6 socket bound to a v4-mapped address here (%s)" % why)
        return 77
    w = tempfile.mkdtemp(prefix="hfv4mapped-")
    proc = None
    try:
        # Silent connections need no token; the listeners want one all the same.
        token = os.path.join(w, "token")
        with open(os.open(token, os.O_WRONLY | os.O_CREAT, 0o600), "w") as f:
            f.write("s3cret\n")
        proc, sock = start(HAIRFILTERD, w,
                           ["--weights", os.path.join(WEIGHTS, "small.safetensors"),
                            "--listen", "tcp:[::ffff:127.0.0.1]:0",
                            "--listen", "tcp:127.0.0.1:0", "--auth-token-file", token,
                            "--max-handshakes", "8", "--max-handshakes-per-address", "1",
                            "--handshake-timeout-ms", "30000"])
        require_started(sock)
        p6, p4 = ready_ports(w, "tcp")
        first = socket.create_connection(("127.0.0.1", p6), timeout=20)
        # The daemon has accepted the first once it answers on the Unix
        # socket: its accepts and the Unix client's requests share one loop.
        connect(sock).close()
        second = socket.create_connection(("127.0.0.1", p4), timeout=20)
        first.settimeout(10)
        try:
            t, _, p = read_frame(first)
        except (OSError, EOFError) as e:
            t, p = None, repr(e).encode()
        code, fatal, _, n = struct.unpack("<IBBH", p[:8]) if t == ERROR else (0, 0, 0, 0)
        msg = p[8:8 + n].decode(errors="replace") if t == ERROR else p.decode(errors="replace")
        check(t == ERROR and code == BUSY and fatal and
              "from address 127.0.0.1 (--max-handshakes-per-address 1)" in msg,
              "the silent connection to the v4-mapped listener is closed when the same "
              "address opens another to the IPv4 one: one client (%s %s)" % (t, msg))
        first.close()
        second.close()
    finally:
        stop_and_clean(proc, w)
    finish()
    return 0


if __name__ == "__main__":
    sys.exit(main())
