#!/usr/bin/env python3
"""At --max-handshakes, a burst of silent connections does not push out a
client whose HELLO is waiting to be read.

libuv accepts every connection waiting in the listen backlog in one turn
of the loop, before it reads from any of them, and the daemon refused the
oldest connection before its HELLO whenever one more arrived: in a burst,
a client that had sent its HELLO at once was the oldest and was told BUSY
with its HELLO unread, so a peer opening connections fast enough kept
real clients out without ever saying a word. Now the one refused is the
oldest whose HELLO has not arrived whole.

The burst is made by stopping the daemon (SIGSTOP) while the client
connects and sends its HELLO and three silent peers connect behind it,
then letting it go on: it accepts all four in one turn.

usage: test_handshake_burst.py HAIRFILTERD WEIGHTS_DIR
"""
import os
import signal
import socket
import struct
import sys
import tempfile

from rawwire import (BUSY, ERROR, HELLO, HELLO_OK, check, finish, frame, read_frame,
                     require_started, start, stop_and_clean)

HAIRFILTERD, WEIGHTS = sys.argv[1:3]


def raw(path):
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(20)
    s.connect(path)
    return s


def answer(s):
    """("HELLO_OK",), ("ERROR", code, fatal), or ("nothing", why)."""
    try:
        t, _, p = read_frame(s)
    except (OSError, EOFError) as e:
        return ("nothing", repr(e))
    if t == ERROR:
        code, fatal = struct.unpack("<IB", p[:5])
        return ("ERROR", code, fatal)
    return ("HELLO_OK",) if t == HELLO_OK else ("type", t)


def main():
    w = tempfile.mkdtemp(prefix="hfburst-")
    proc = None
    conns = []
    try:
        proc, sock = start(HAIRFILTERD, w, ["--weights", os.path.join(WEIGHTS, "small.safetensors"),
                                            "--max-handshakes", "2"])
        require_started(sock)
        os.kill(proc.pid, signal.SIGSTOP)
        # kill() only makes the stop pending: until every thread of the
        # daemon has stopped (reported to its parent), it may still accept
        # and read, and the burst would not be one.
        os.waitpid(proc.pid, os.WUNTRACED)
        try:
            client = raw(sock)
            client.sendall(frame(HELLO, struct.pack("<HHHH", 1, 3, 4, 0) + b"test"))
            silent = [raw(sock) for _ in range(3)]
            conns = [client] + silent
        finally:
            os.kill(proc.pid, signal.SIGCONT)
        a = answer(client)
        check(a == ("HELLO_OK",), "the client whose HELLO was waiting gets HELLO_OK (%s)" % (a,))
        # Four before their HELLO, two allowed: the two oldest silent ones go.
        for i in range(2):
            a = answer(silent[i])
            check(a == ("ERROR", BUSY, 1),
                  "silent peer %d, among the oldest, is refused with a fatal BUSY (%s)" % (i, a))
        silent[2].settimeout(1)
        try:
            got = silent[2].recv(16)
            left = "got %r" % got
        except socket.timeout:
            left = "open"
        check(left == "open", "the newest silent peer keeps its slot (%s)" % left)
    finally:
        for s in conns:
            s.close()
        stop_and_clean(proc, w)
    finish()


if __name__ == "__main__":
    main()
