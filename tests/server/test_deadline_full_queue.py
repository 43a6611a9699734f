#!/usr/bin/env python3
"""A full queue whose frames' budgets have all passed takes a new frame:
the dead frames are answered EXPIRED and give their places back, while
the worker is still busy with a long run.

The worker checked budgets only before it formed a batch. While it ran a
long frame, a queue full of frames already past their budget (protocol
version 4, FILTER flag DEADLINE) refused every new frame with BUSY (or
pushed out a live one with a BUSY RESULT) until the run ended, though
those frames could no longer be of use to anyone. Nor may a connection at
its share of the queue, or at its in-flight limit, be refused for frames
of its own that have expired there.

usage: test_deadline_full_queue.py HAIRFILTERD WEIGHTS_DIR
"""
import os
import socket
import struct
import sys
import tempfile
import time

from rawwire import (ERROR, FILTER, HELLO, HELLO_OK, RESULT, check, finish, frame, read_frame,
                     require_started, start, stop_and_clean)

HAIRFILTERD, WEIGHTS = sys.argv[1:3]
SPP, DEADLINE, EXPIRED = 4, 8, 13


def hello_v4(path):
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(120)
    s.connect(path)
    s.sendall(frame(HELLO, struct.pack("<HHHH", 4, 4, 4, 0) + b"full"))
    t, _, p = read_frame(s)
    if t != HELLO_OK:
        raise RuntimeError("no HELLO_OK (type %d)" % t)
    return s


def filt(rid, side, budget=None):
    flags = DEADLINE if budget else 0
    p = (struct.pack("<HHIIHBB", 5, flags, side, side, SPP, 0, 0) +
         struct.pack("<9f", *([0.5] * 9)) + b"Small")
    if budget:
        p += struct.pack("<I", budget)
    return frame(FILTER, p + bytes(side * side * SPP * 6 * 4), rid)


def reply(s):
    """(type, id, status or ERROR code)."""
    t, rid, p = read_frame(s)
    return t, rid, struct.unpack("<H" if t == RESULT else "<I", p[:2 if t == RESULT else 4])[0]


def main():
    w = tempfile.mkdtemp(prefix="hffullqueue-")
    proc = None
    try:
        proc, sock = start(HAIRFILTERD, w,
                           ["--weights", os.path.join(WEIGHTS, "small.safetensors"),
                            "--max-batch", "1", "--queue-size", "2",
                            # the reference backend: its runs are long enough
                            # at sizes that arrive at once (Small on cpu ran a
                            # 1800x1800 frame, the largest sent, in 0.3 s)
                            "--backend", "cpu-ref",
                            # the connections below are one process's, each
                            # standing for a client of its own
                            "--queue-share-by", "connection"])
        require_started(sock)
        big, a, b, c = (hello_v4(sock) for _ in range(4))
        # A frame that runs for about 2 s here, sized from one of 256x256
        # timed once its plan is made: the first frame of a size also builds
        # the plan, which took as long as the run on a busy machine and sized
        # the long frame to a tenth of its mark (the expired frames then ran
        # before their budget passed).
        big.sendall(filt(1, 256))
        reply(big)
        t0 = time.time()
        big.sendall(filt(1, 256))
        reply(big)
        per_pixel = max(time.time() - t0, 1e-3) / (256 * 256)
        side = int(min(1800, max(64, (2.0 / per_pixel) ** 0.5)))
        big.sendall(filt(2, side))
        time.sleep(0.3)
        # Two frames of 1 ms fill the queue behind it and expire there.
        a.sendall(filt(10, 2, budget=1000))
        b.sendall(filt(10, 2, budget=1000))
        time.sleep(0.1)
        sent = time.time()
        c.sendall(filt(20, 2))
        got = reply(c)
        waited = time.time() - sent
        check(got[0] == RESULT and got[2] == 0,
              "a frame without a budget is served, not refused, when the queue is full of "
              "expired frames (got type %d code %d)" % (got[0], got[2]))
        for s, what in ((a, "first"), (b, "second")):
            r = reply(s)
            check(r[0] == RESULT and r[1] == 10 and r[2] == EXPIRED,
                  "the %s expired frame is answered EXPIRED (%s)" % (what, r))
        r = reply(big)
        check(r[0] == RESULT and r[2] == 0, "the long frame is served (%s)" % (r,))
        # One connection at its share of the queue (the long frame running,
        # one frame queued behind it), the queued one past its budget: a
        # new frame of that connection is served, not refused BUSY ("holds
        # its share") for the place the dead frame holds.
        # Frame 3 as long as frame 2, running still when 31 arrives.
        big.sendall(filt(3, side))
        time.sleep(0.1)
        big.sendall(filt(30, 2, budget=1000))
        time.sleep(0.05)
        big.sendall(filt(31, 2))
        got = {}
        for _ in range(3):
            r = reply(big)
            got[r[1]] = r
        check(got.get(30, (0, 0, 0))[0] == RESULT and got[30][2] == EXPIRED,
              "the frame past its budget is answered EXPIRED (%s)" % (got.get(30),))
        check(got.get(31, (0, 0, 0))[0] == RESULT and got[31][2] == 0,
              "a connection at its share whose queued frame has expired has its new frame "
              "served, not refused (%s)" % (got.get(31),))
        check(got.get(3, (0, 0, 0))[0] == RESULT and got[3][2] == 0,
              "the second long frame is served (%s)" % (got.get(3),))
        print("the long frame was %dx%d (a 256x256 frame ran in %.3f s); the new frame was "
              "answered %.2f s after it was sent" % (side, side, per_pixel * 256 * 256, waited))
    finally:
        stop_and_clean(proc, w)
    finish()


main()
