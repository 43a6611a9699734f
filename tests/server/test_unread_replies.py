#!/usr/bin/env python3
"""Replies a client does not read cost the daemon a bounded amount of memory
per connection, also the replies outside --max-memory-mb (STATS_REPLY,
VARIANTS, ERROR).

Clients that send STATS after STATS without reading the answers: the
daemon stops reading from each once 64 KiB of such replies wait to be
written (PROTOCOL.md, "Flow control"), and serves everyone else. Before,
only the count of waiting replies stopped it (256): with 10 variants a
STATS_REPLY is 4.7 KiB, so each such connection held 1.2 MiB in the
daemon, 64 variants 8.5 MiB, and --max-connections (256) of them gigabytes.

usage: test_unread_replies.py HAIRFILTERD WEIGHTS_DIR
"""
import os
import shutil
import sys
import tempfile
import time

from rawwire import (STATS, STATS_REPLY, check, connect, finish, frame, read_frame, require_started,
                     start, stop_and_clean)

HAIRFILTERD, WEIGHTS = sys.argv[1:3]
VARIANTS = 10     # copies of one weights file, served under as many names
CONNECTIONS = 40  # clients that never read


def rss_kib(pid):
    for line in open("/proc/%d/status" % pid):
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def main():
    w = tempfile.mkdtemp(prefix="hfunread-")
    proc = None
    try:
        args = []
        for i in range(VARIANTS):
            f = os.path.join(w, "v%02d.safetensors" % i)
            shutil.copy(os.path.join(WEIGHTS, "small.safetensors"), f)
            args += ["--weights", "Variant%02d=%s" % (i, f)]
        # Under AddressSanitizer freed memory waits in its quarantine (256
        # MiB) and would count as growth: off here, so RSS is what is held.
        env = dict(os.environ)
        env["ASAN_OPTIONS"] = ":".join(filter(None, [env.get("ASAN_OPTIONS"),
                                                     "quarantine_size_mb=0",
                                                     "thread_local_quarantine_size_kb=0"]))
        proc, sock = start(HAIRFILTERD, w, args, env=env)
        require_started(sock)
        probe = connect(sock)
        probe.sendall(frame(STATS))
        t, _, p = read_frame(probe)
        check(t == STATS_REPLY and len(p) > 4000,
              "a STATS_REPLY of %d variants is over 4000 bytes (%d)" % (VARIANTS, len(p)))
        before = rss_kib(proc.pid)
        # Each client sends 1000 STATS (16 KB) and reads nothing: the
        # daemon reads as many as its limits let it answer.
        flood = []
        for _ in range(CONNECTIONS):
            s = connect(sock)
            s.setblocking(False)
            try:
                s.send(frame(STATS) * 1000)
            except BlockingIOError:
                pass
            flood.append(s)
        peak, t_end = before, time.time() + 1.5
        while time.time() < t_end:
            peak = max(peak, rss_kib(proc.pid))
            time.sleep(0.05)
        grew = (peak - before) / 1024
        # 40 connections: 64 KiB of replies and one more each (under 3 MiB
        # in all) and the allocator's rounding; 48 MiB before.
        print("daemon grew by %.1f MiB" % grew)
        check(grew < 16, "%d connections sending STATS unread grew the daemon by %.1f MiB, not "
              "under 16 MiB" % (CONNECTIONS, grew))
        # Everyone else is served meanwhile.
        t0 = time.time()
        probe.sendall(frame(STATS))
        t, _, _ = read_frame(probe)
        check(t == STATS_REPLY, "another client's STATS is answered (type %d)" % t)
        check(time.time() - t0 < 2, "in %.2f s, under 2 s" % (time.time() - t0))
        for s in flood:
            s.close()
        probe.close()
    finally:
        stop_and_clean(proc, w)
    finish()


if __name__ == "__main__":
    main()
