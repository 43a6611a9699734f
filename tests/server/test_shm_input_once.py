#!/usr/bin/env python3
"""The daemon reads a shared-memory frame's input once: what it checks
(FEATURES.md's out-of-contract rule, RESULT flag bit 2) is what the
network computes, whatever the client writes in its segment meanwhile.

The backend checks a frame's features in one pass and runs the network
on them in another. A frame in a shared segment used to be read by both
straight from the segment, which its client can write at any time: a
value rewritten to NaN between the two reached the network unchecked, and
its RESULT said nothing was sanitised. The daemon now copies the frame
out of the segment first, and both passes read the copy.

A thread flips one feature between 0 and NaN for as long as the frames
run. Each frame is then either clean when copied, and its result is
exactly that of the clean frame with flag bit 2 clear, or has the NaN,
and has flag bit 2 set. The size, 60x60, needs padding, so the cpu
backend checks the frame in a pass of its own before the network.

usage: test_shm_input_once.py HAIRFILTERD WEIGHTS_DIR
"""
import math
import mmap
import os
import struct
import sys
import tempfile
import threading

from rawwire import (FILTER, RESULT, check, connect, finish, frame, read_frame, require_started,
                     shm_create, start, stop_and_clean)

HAIRFILTERD, WEIGHTS = sys.argv[1:3]
W, H, SPP = 60, 60, 4
IN_BYTES = W * H * SPP * 6 * 4   # Small, f32 features
OUT_BYTES = W * H * 3 * 4        # f32 result
SANITISED = 0x04                 # RESULT flag bit 2
TRIES = 60


def filter_frame(s, seg, rid):
    """(flags, result floats) of one frame in the segment, or None."""
    fixed = struct.pack("<HHIIHBB", 5, 2, W, H, SPP, 0, 0) + struct.pack("<9f", *[0.5] * 9)
    ref = struct.pack("<IIQQQ", seg, 0, 0, IN_BYTES, 0)
    s.sendall(frame(FILTER, fixed + b"Small" + ref, rid))
    t, r, p = read_frame(s)
    if t != RESULT or r != rid or struct.unpack("<H", p[:2])[0] != 0:
        check(False, "frame %d: RESULT of status 0 (type %d, %r)" % (rid, t, p[:8]))
        return None
    return p[3]


def main():
    w = tempfile.mkdtemp(prefix="hfshmonce-")
    proc, fd = None, None
    try:
        proc, sock = start(HAIRFILTERD, w, ["--weights", os.path.join(WEIGHTS, "small.safetensors"),
                                            "--max-batch", "1"])
        require_started(sock)
        s = connect(sock)
        got = shm_create(s, IN_BYTES + OUT_BYTES)
        check(got[0] == "ok", "SHM_CREATED (%s)" % (got,))
        seg, fd = got[1]
        mm = mmap.mmap(fd, IN_BYTES + OUT_BYTES)   # features: zeros

        flags = filter_frame(s, seg, 1)
        clean = bytes(mm[IN_BYTES:])
        check(flags is not None and not flags & SANITISED, "the clean frame is not sanitised")
        vals = struct.unpack("<%df" % (W * H * 3), clean)
        check(all(math.isfinite(v) for v in vals), "the clean frame's result is finite")

        stop = threading.Event()
        zero, nan = struct.pack("<f", 0.0), struct.pack("<f", float("nan"))

        def flip():
            while not stop.is_set():
                for _ in range(1000):
                    mm[0:4] = nan
                    mm[0:4] = zero

        t = threading.Thread(target=flip)
        t.start()
        seen = {0: 0, SANITISED: 0}
        try:
            for rid in range(2, 2 + TRIES):
                flags = filter_frame(s, seg, rid)
                if flags is None:
                    break
                out = bytes(mm[IN_BYTES:])
                seen[flags & SANITISED] += 1
                if flags & SANITISED:
                    vals = struct.unpack("<%df" % (W * H * 3), out)
                    check(all(math.isfinite(v) for v in vals),
                          "frame %d, sanitised: its result is finite" % rid)
                else:
                    check(out == clean, "frame %d, not sanitised: its result is the clean frame's "
                          "(a NaN reached the network unchecked)" % rid)
        finally:
            stop.set()
            t.join()
        print("frames not sanitised: %d, sanitised: %d" % (seen[0], seen[SANITISED]))
        mm.close()
        s.close()
    finally:
        if fd is not None:
            os.close(fd)
        stop_and_clean(proc, w)
    finish()


if __name__ == "__main__":
    main()
