#!/usr/bin/env python3
"""A FILTER refused BUSY says which limit it met and what to do: over the
connection's window, the ERROR names HELLO_OK's max_inflight (the client's
own limit, --max-inflight on the server) and says to read a reply first,
where it said "too many requests in flight on this connection" alone.

usage: test_busy_messages.py HAIRFILTERD WEIGHTS_DIR
"""
import os
import socket
import struct
import sys
import tempfile

from rawwire import (BUSY, ERROR, FILTER, HELLO, HELLO_OK, RESULT, check, finish, frame, read_frame,
                     require_started, start, stop_and_clean)

HAIRFILTERD, WEIGHTS = sys.argv[1:3]


def small_filter(rid, w, h):
    """A FILTER of Small (4 spp) of w x h, f32, its features all 0.25."""
    fixed = struct.pack("<HHIIHBB", 5, 0, w, h, 4, 0, 0) + struct.pack("<9f", *[0.5] * 9)
    return frame(FILTER, fixed + b"Small" + struct.pack("<f", 0.25) * (w * h * 4 * 6), rid)


def main():
    w = tempfile.mkdtemp(prefix="hfbusy-")
    proc = None
    try:
        proc, sock = start(HAIRFILTERD, w, ["--weights", os.path.join(WEIGHTS, "small.safetensors"),
                                            "--max-inflight", "1"])
        require_started(sock)
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.settimeout(30)
        s.connect(sock)
        s.sendall(frame(HELLO, struct.pack("<HHHH", 1, 3, 4, 0) + b"test"))
        t, _, _ = read_frame(s)
        check(t == HELLO_OK, "HELLO_OK (type %d)" % t)
        # A frame that runs for a good while (hundreds of milliseconds on
        # the cpu backend), and a small one right behind it, read long
        # before the first is done: the second is over a window of 1.
        s.sendall(small_filter(1, 512, 384) + small_filter(2, 8, 8))
        answers = {}
        for _ in range(2):
            t, rid, p = read_frame(s)
            answers[rid] = (t, p)
        t, p = answers.get(2, (None, b""))
        check(t == ERROR, "request 2 over the window of 1 is refused with an ERROR (type %s)" % t)
        if t == ERROR:
            code, fatal, _, n = struct.unpack("<IBBH", p[:8])
            msg = p[8:8 + n].decode()
            check(code == BUSY and fatal == 0, "a non-fatal BUSY (code %d fatal %d)" % (code, fatal))
            check("max_inflight" in msg and "--max-inflight" in msg and "read a reply" in msg,
                  "the BUSY names HELLO_OK's max_inflight, --max-inflight and what to do: %r" % msg)
        check(answers.get(1, (None,))[0] == RESULT, "request 1 gets its RESULT")
        s.close()
    finally:
        stop_and_clean(proc, w)
    finish()


if __name__ == "__main__":
    main()
