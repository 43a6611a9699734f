#!/usr/bin/env python3
"""A client that reads its replies, but slower than --min-recv-rate, is
closed, and the memory its unread RESULTs held serves other clients again.

RESULTs waiting to be written are charged to --max-memory-mb until the
client reads them (docs/SERVER.md, "Memory"). Before, only a client that
read none of its waiting replies for --stall-timeout-ms was closed: one
that read a few KiB a second kept its connection, and with frames sent
behind one another and their results left queued it held the whole budget
for as long as it liked, every other client's frame of the announced size
refused BUSY. Now the rate at which a client takes its waiting replies is
held to --min-recv-rate, over the same windows as a frame's upload.

A Unix socket lets the daemon write again only once the client has read
most of its socket buffer (about 200 KiB): the slow reader takes 40 KiB a
second, enough to free it within every 6 s window (so the rule for a
client that reads nothing never closes it) and under 64 KiB/s.

usage: test_slow_reader.py HAIRFILTERD WEIGHTS_DIR
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
WINDOW_MS = 6000          # --stall-timeout-ms: the rate's window
TRICKLE = 10240           # bytes the slow reader reads every 0.25 s: 40 KiB/s, under 64


def small_filter(rid, w, h, composite):
    """A FILTER of Small (4 spp) of w x h, f16 in, f32 out, features 0.25."""
    fixed = struct.pack("<HHIIHBB", 5, 1 if composite else 0, w, h, 4, 1, 0)
    fixed += struct.pack("<9f", *[0.5] * 9)
    return frame(FILTER, fixed + b"Small" + b"\x00\x34" * (w * h * 4 * 6), rid)


def connect(path):
    """A connection past HELLO_OK, and the HELLO_OK's max width, height."""
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(30)
    s.connect(path)
    s.sendall(frame(HELLO, struct.pack("<HHHH", 1, 3, 4, 0) + b"test"))
    t, _, p = read_frame(s)
    if t != HELLO_OK:
        raise RuntimeError("no HELLO_OK (type %d)" % t)
    return s, struct.unpack("<II", p[4:12])


def main():
    w = tempfile.mkdtemp(prefix="hfslow-")
    proc = None
    try:
        proc, sock = start(HAIRFILTERD, w, [
            "--weights", os.path.join(WEIGHTS, "small.safetensors"), "--max-memory-mb", "64",
            "--stall-timeout-ms", str(WINDOW_MS)])
        require_started(sock)

        # The slow reader: frames of the announced size with a composite,
        # one every 0.25 s (40 of them), and 10 KiB of the replies read in
        # that time.
        slow, (mw, mh) = connect(sock)
        big = small_filter(1, mw, mh, True)
        closed_after = None
        t0 = time.time()
        first_reply = None   # when the first reply bytes came: its window starts then
        rid = 1
        while time.time() - t0 < 5 * WINDOW_MS / 1000:
            try:
                if rid <= 40:
                    slow.sendall(big[:8] + struct.pack("<I", rid) + big[12:])
                    rid += 1
                if not slow.recv(TRICKLE):
                    raise EOFError("end of stream")
                if first_reply is None:
                    first_reply = time.time()
            except (OSError, EOFError):
                closed_after = time.time() - t0
                break
            time.sleep(0.25)
        check(closed_after is not None,
              "the daemon closed the client reading at 40 KiB/s within 5 windows")
        # In the first window: the first RESULT (megabytes, more than 64
        # KiB/s over a window) is not counted as read when its window
        # starts. It was, so a slow reader outlived a whole window more
        # (about 2 windows after its first reply, against 1 and the sweep's
        # second; half a window of margin for a loaded machine).
        if closed_after is not None and first_reply is not None:
            since = t0 + closed_after - first_reply
            check(since < 1.5 * WINDOW_MS / 1000,
                  "closed within the first window after the first reply (%.1f s after it)"
                  % since)
        slow.close()
        log = open(os.path.join(w, "daemon.log")).read()
        check("under the minimum of 64 KiB/s (--min-recv-rate); closing" in log,
              "the log says the replies were read under --min-recv-rate")

        # Its results' memory serves others again: a frame of the announced
        # size is filtered (it was BUSY as long as the slow reader held it).
        honest, _ = connect(sock)
        status = None
        deadline = time.time() + 10
        while time.time() < deadline:
            honest.sendall(small_filter(7, mw, mh, True))
            t, r, p = read_frame(honest)
            status = ("RESULT", struct.unpack("<H", p[:2])[0]) if t == RESULT else \
                     ("ERROR", struct.unpack("<I", p[:4])[0])
            if status == ("RESULT", 0):
                break
            time.sleep(0.2)
        check(status == ("RESULT", 0),
              "a frame of the announced size is served after the slow reader is gone (%s)"
              % (status,))
        honest.close()
    finally:
        stop_and_clean(proc, w)
    finish()


if __name__ == "__main__":
    main()
