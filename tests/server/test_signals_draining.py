#!/usr/bin/env python3
"""Signals while the daemon drains:

  * SIGUSR1's statistics: a FILTER refused with SHUTTING_DOWN counts as
    `unavailable`, apart from `errors`, as /metrics puts it in class
    "unavailable" and the stop line in "refused while draining". Every
    rolling restart refuses what clients send meanwhile; the line counted
    those refusals as errors, so a drain looked like a failing server;
  * SIGHUP is ignored, and the log says so (it said nothing, and a reload
    sent by hand looked done);
  * the frames admitted before SIGTERM are answered, and the daemon exits 0.

usage: test_signals_draining.py HAIRFILTERD WEIGHTS.safetensors
"""
import os
import re
import signal
import struct
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rawwire import (ERROR, FILTER, RESULT, check, connect, finish, frame, read_frame,  # noqa: E402
                     require_started, start, stop_and_clean)

HAIRFILTERD, WEIGHTS = sys.argv[1:3]
SHUTTING_DOWN = 10


def small_filter(rid, w, h):
    """A FILTER of Small (4 spp) of w x h, f32, its features all 0.25."""
    fixed = struct.pack("<HHIIHBB", 5, 0, w, h, 4, 0, 0) + struct.pack("<9f", *[0.5] * 9)
    return frame(FILTER, fixed + b"Small" + struct.pack("<f", 0.25) * (w * h * 4 * 6), rid)


def main():
    w = tempfile.mkdtemp(prefix="hfsigdrain-")
    proc = None
    try:
        proc, sock = start(HAIRFILTERD, w, ["--weights", WEIGHTS, "--backend", "cpu-ref",
                                            "--drain-timeout-ms", "30000"])
        require_started(sock)
        busy = connect(sock)
        # Frames that keep the worker running while the daemon drains
        # (cpu-ref takes a second or more for each).
        for rid in range(1, 4):
            busy.sendall(small_filter(rid, 512, 512))
        time.sleep(0.3)
        proc.send_signal(signal.SIGTERM)
        time.sleep(0.3)
        # On the connection whose frames are running: an idle one is closed
        # when the drain starts.
        busy.sendall(small_filter(9, 8, 8))
        results = 0
        while True:
            t, rid, p = read_frame(busy)
            if t != RESULT:
                break
            results += 1
        code = struct.unpack("<I", p[:4])[0] if t == ERROR else None
        check(t == ERROR and rid == 9 and code == SHUTTING_DOWN,
              "a FILTER after SIGTERM refused SHUTTING_DOWN (type %d, id %d, code %s)"
              % (t, rid, code))
        check(results < 3, "frames still running when SIGUSR1 comes")
        proc.send_signal(signal.SIGUSR1)
        log_path = os.path.join(w, "daemon.log")
        line = None
        deadline = time.time() + 10
        while time.time() < deadline and line is None:
            m = re.search(r"statistics: variant=Small .*", open(log_path).read())
            line = m.group(0) if m else None
            time.sleep(0.05)
        check(line is not None, "SIGUSR1 logged the variant's statistics while draining")
        if line:
            check(" unavailable=1 " in line and " errors=0 " in line,
                  "the refusal counted as unavailable, not as an error: " + line)
        proc.send_signal(signal.SIGHUP)
        deadline = time.time() + 10
        while time.time() < deadline and "SIGHUP: ignored while draining" not in open(log_path).read():
            time.sleep(0.05)
        log = open(log_path).read()
        check("SIGHUP: ignored while draining" in log and "SIGHUP: reading" not in log,
              "SIGHUP while draining ignored, saying so")
        for _ in range(3 - results):
            t, rid, _ = read_frame(busy)
            check(t == RESULT and rid in (1, 2, 3),
                  "a frame admitted before SIGTERM answered (type %d, id %d)" % (t, rid))
        busy.close()
        check(proc.wait(60) == 0, "the daemon stopped with 0")
    finally:
        stop_and_clean(proc, w)
    finish()


main()
