#!/usr/bin/env python3
"""Peers that connect and close at once are not counted as protocol errors.

In a storm of bare connect-and-close peers the daemon accepts a burst
before it reads their closes, so the connections before HELLO exceed
--max-handshakes and the oldest is pushed out with a fatal BUSY: but that
one has almost always hung up already. Each was counted in STATS
`protocol_errors` (57,385 of 57,454 connections in a 3-second storm) and
its ERROR written to a dead socket, so the counter said nothing about real
client faults. A peer that has hung up is now closed without a word and
not counted. Two threads connect and close for two seconds; then STATS
must show protocol_errors under 1% of the connections (and a client that
says HELLO is still served).

usage: test_storm_counts.py HAIRFILTERD WEIGHTS_DIR
"""
import os
import socket
import struct
import sys
import tempfile
import threading
import time

from rawwire import (STATS, STATS_REPLY, check, connect, finish, frame, read_frame,
                     require_started, start, stop_and_clean)

HAIRFILTERD, WEIGHTS = sys.argv[1:3]
STORM_S = 2.0


def storm(path, end, counts, i):
    n = 0
    while time.time() < end:
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            s.connect(path)
            n += 1
        except OSError:
            pass
        s.close()
    counts[i] = n


def protocol_errors(path):
    s = connect(path)
    s.sendall(frame(STATS))
    t, _, p = read_frame(s)
    s.close()
    check(t == STATS_REPLY, "a STATS_REPLY (type %d)" % t)
    return struct.unpack("<Q", p[28:36])[0] if t == STATS_REPLY else None


def main():
    w = tempfile.mkdtemp(prefix="hfstorm-")
    proc = None
    try:
        proc, sock = start(HAIRFILTERD, w,
                           ["--weights", os.path.join(WEIGHTS, "small.safetensors")])
        require_started(sock)
        before = protocol_errors(sock)
        counts = [0, 0]
        end = time.time() + STORM_S
        threads = [threading.Thread(target=storm, args=(sock, end, counts, i)) for i in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        time.sleep(0.5)   # the loop reads the last closes
        after = protocol_errors(sock)
        total = sum(counts)
        print("%d connections in %.1f s; protocol_errors %s -> %s" % (total, STORM_S, before,
                                                                    after))
        check(total >= 1000, "the storm made 1000 connections or more (%d)" % total)
        if before is not None and after is not None:
            check(after - before <= max(10, total // 100),
                  "protocol_errors grew by %d for %d connect-and-close peers (at most 1%%)" %
                  (after - before, total))
    finally:
        stop_and_clean(proc, w)
    finish()


main()
