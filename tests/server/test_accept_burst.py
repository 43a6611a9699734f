#!/usr/bin/env python3
"""A flood of connections does not hold the event loop: the daemon accepts
at most 64 in a turn of its loop, then serves its other connections' I/O
before it accepts more.

libuv accepts from a listener until its backlog is empty, with no other
I/O in between. Peers that connect as fast as the daemon can accept and
refuse them (no HELLO, no token needed) kept it in that loop: a client
already connected got no answer for as long as they kept at it. Here two
processes connect and close for a few seconds while a connected client
sends STATS after STATS: it waited the whole flood before (10 s of a 10 s
flood on a 2-core machine), and is answered within milliseconds now.

usage: test_accept_burst.py HAIRFILTERD WEIGHTS_DIR
"""
import multiprocessing
import os
import shutil
import socket
import sys
import tempfile
import time

from rawwire import (STATS, STATS_REPLY, check, connect, failures, finish, frame, read_frame,
                     require_started, start, stop)

FLOOD_S = 4          # how long the flood lasts
FLOODERS = 2         # processes connecting


def flooder(path, seconds):
    """Connects (without a word) as fast as it can, keeping 100 open."""
    kept = []
    end = time.time() + seconds
    while time.time() < end:
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.setblocking(False)
        try:
            s.connect(path)
        except OSError:
            pass   # the backlog is full: the daemon is behind, which is the point
        kept.append(s)
        if len(kept) > 100:
            kept.pop(0).close()
    for s in kept:
        s.close()


def main():
    hairfilterd, weights = sys.argv[1:3]
    w = tempfile.mkdtemp(prefix="hfaccept-")
    proc = None
    flood = []
    try:
        proc, sock = start(hairfilterd, w, ["--weights", os.path.join(weights, "small.safetensors"),
                                            "--max-connections", "16"])
        require_started(sock)
        client = connect(sock)
        client.settimeout(FLOOD_S * 4)
        flood = [multiprocessing.Process(target=flooder, args=(sock, FLOOD_S))
                 for _ in range(FLOODERS)]
        for p in flood:
            p.start()
        time.sleep(0.5)
        slowest, answered = 0.0, 0
        end = time.time() + FLOOD_S - 1
        while time.time() < end:
            t0 = time.time()
            client.sendall(frame(STATS))
            t, _, _ = read_frame(client)
            slowest = max(slowest, time.time() - t0)
            answered += t == STATS_REPLY
            time.sleep(0.05)
        check(answered >= 10, "STATS answered during the flood (%d)" % answered)
        check(slowest < 1.0, "each STATS answered within 1 s during the flood (slowest %.2f s)"
              % slowest)
        client.close()
    finally:
        for p in flood:
            p.join()
        log = stop(proc, w) if proc else ""
        if failures:
            print(log[-3000:])
        shutil.rmtree(w, ignore_errors=True)
    finish()


if __name__ == "__main__":
    main()
