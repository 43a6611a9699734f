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
run. Each frame is then either clean when read, and its result is
exactly that of the clean frame with flag bit 2 clear, or has the NaN,
and has flag bit 2 set. The size, 60x60, needs padding, so the cpu
backend checks Small's frame in a pass of its own before the network
(the daemon copies it out of the segment first); KernelAC's samples and
estimate are interleaved into a copy, each value read once and checked
there (no copy first). Both hold.

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
OUT_BYTES = W * H * 3 * 4        # f32 result
SANITISED = 0x04                 # RESULT flag bit 2
SHM, ESTIMATE = 0x02, 0x04       # FILTER flag bits 1 and 2
TRIES = 60
# (variant, weights file, FILTER flags, input bytes: f32 features, and
# with ESTIMATE the estimate's colour, highlight and alpha after them)
VARIANTS = [("Small", "small.safetensors", SHM, W * H * SPP * 6 * 4),
            ("KernelAC", "kernel_ac.safetensors", SHM | ESTIMATE,
             W * H * SPP * 6 * 4 + W * H * 3 * 4)]


def filter_frame(s, seg, rid, variant, flags, in_bytes):
    """RESULT flags of one frame in the segment, or None."""
    name = variant.encode()
    fixed = (struct.pack("<HHIIHBB", len(name), flags, W, H, SPP, 0, 0) +
             struct.pack("<9f", *[0.5] * 9))
    ref = struct.pack("<IIQQQ", seg, 0, 0, in_bytes, 0)
    s.sendall(frame(FILTER, fixed + name + ref, rid))
    t, r, p = read_frame(s)
    if t != RESULT or r != rid or struct.unpack("<H", p[:2])[0] != 0:
        check(False, "frame %d: RESULT of status 0 (type %d, %r)" % (rid, t, p[:8]))
        return None
    return p[3]


def race(s, variant, flags, in_bytes, rid0):
    """Frames of variant in a fresh segment while a thread flips its first
    feature between 0 and NaN: each not sanitised is the clean frame's."""
    got = shm_create(s, in_bytes + OUT_BYTES)
    check(got[0] == "ok", "%s: SHM_CREATED (%s)" % (variant, got))
    if got[0] != "ok":
        return
    seg, fd = got[1]
    try:
        mm = mmap.mmap(fd, in_bytes + OUT_BYTES)   # features: zeros
        flags_got = filter_frame(s, seg, rid0, variant, flags, in_bytes)
        clean = bytes(mm[in_bytes:])
        check(flags_got is not None and not flags_got & SANITISED,
              "%s: the clean frame is not sanitised" % variant)
        vals = struct.unpack("<%df" % (W * H * 3), clean)
        check(all(math.isfinite(v) for v in vals), "%s: the clean frame's result is finite" % variant)

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
            for rid in range(rid0 + 1, rid0 + 1 + TRIES):
                flags_got = filter_frame(s, seg, rid, variant, flags, in_bytes)
                if flags_got is None:
                    break
                out = bytes(mm[in_bytes:])
                seen[flags_got & SANITISED] += 1
                if flags_got & SANITISED:
                    vals = struct.unpack("<%df" % (W * H * 3), out)
                    check(all(math.isfinite(v) for v in vals),
                          "%s frame %d, sanitised: its result is finite" % (variant, rid))
                else:
                    check(out == clean, "%s frame %d, not sanitised: its result is the clean "
                          "frame's (a NaN reached the network unchecked)" % (variant, rid))
        finally:
            stop.set()
            t.join()
        print("%s: frames not sanitised: %d, sanitised: %d" % (variant, seen[0], seen[SANITISED]))
        mm.close()
    finally:
        os.close(fd)


def main():
    w = tempfile.mkdtemp(prefix="hfshmonce-")
    proc = None
    try:
        args = []
        for _, f, _, _ in VARIANTS:
            args += ["--weights", os.path.join(WEIGHTS, f)]
        proc, sock = start(HAIRFILTERD, w, args + ["--max-batch", "1"])
        require_started(sock)
        s = connect(sock)
        for i, (variant, _, flags, in_bytes) in enumerate(VARIANTS):
            race(s, variant, flags, in_bytes, 1 + i * (TRIES + 1))
        s.close()
    finally:
        stop_and_clean(proc, w)
    finish()


if __name__ == "__main__":
    main()
