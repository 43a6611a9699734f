#!/usr/bin/env python3
"""A v4-mapped loopback listener is loopback (docs/SERVER.md,
"Authentication").

tcp:[::ffff:127.0.0.1]:PORT is 127.0.0.1 as an IPv6 socket names it: it
takes connections from 127.0.0.1 only. It was taken for a non-loopback
address: --no-auth was refused on it, and with a token the daemon warned
at start that the token and the frames cross the network unencrypted.

Here the daemon starts with --no-auth on tcp:[::ffff:127.0.0.1]:0; a
client from 127.0.0.1 gets HELLO_OK without a token; the log has no
plain-TCP warning and says "no auth, loopback". A v4-mapped address off
loopback (::ffff:10.0.0.1) is still refused with --no-auth, before
anything loads.

usage: test_loopback_v4_mapped.py HAIRFILTERD WEIGHTS_DIR
"""
import os
import socket
import struct
import subprocess
import sys
import tempfile

from rawwire import ERROR, HELLO, HELLO_OK, check, finish, frame, read_frame, ready_ports, \
    require_started, start, stop, stop_and_clean, v4_mapped_unavailable

HAIRFILTERD, WEIGHTS = sys.argv[1:3]
LISTEN = "tcp:[::ffff:127.0.0.1]:0"


def main():
    why = v4_mapped_unavailable()
    if why:
        print("SKIP: no IPv6 socket bound to a v4-mapped address here (%s)" % why)
        return 77
    weights = os.path.join(WEIGHTS, "small.safetensors")
    w = tempfile.mkdtemp(prefix="hfv4loop-")
    proc = None
    try:
        proc, sock = start(HAIRFILTERD, w, ["--weights", weights, "--listen", LISTEN,
                                            "--no-auth"])
        require_started(sock)
        c = socket.create_connection(("127.0.0.1", ready_ports(w, "tcp")[0]), timeout=20)
        c.sendall(frame(HELLO, struct.pack("<HHHH", 1, 3, 4, 0) + b"test"))
        t, _, p = read_frame(c)
        c.close()
        why = ""
        if t == ERROR:
            n = struct.unpack("<H", p[6:8])[0]
            why = p[8:8 + n].decode(errors="replace")
        check(t == HELLO_OK, "HELLO without a token on %s with --no-auth: HELLO_OK "
              "(type %d %s)" % (LISTEN, t, why))
        log = stop(proc, w)
        proc = None
        check("plain TCP on a non-loopback address" not in log,
              "no plain-TCP warning for %s:\n%s" % (LISTEN, log))
        check("(no auth, loopback)" in log,
              "the listening line says no auth, loopback:\n%s" % log)

        # Off loopback, v4-mapped or not, --no-auth is still refused.
        off = "tcp:[::ffff:10.0.0.1]:0"
        r = subprocess.run([HAIRFILTERD, "--config", "none", "--weights", weights,
                            "--backend", "cpu", "--listen", off, "--no-auth"],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=60)
        out = r.stdout.decode(errors="replace")
        check(r.returncode == 2 and "--no-auth is only allowed on loopback" in out,
              "--no-auth on %s refused at start, status 2 (%d: %s)" % (off, r.returncode, out))
    finally:
        stop_and_clean(proc, w)
    finish()
    return 0


if __name__ == "__main__":
    sys.exit(main())
