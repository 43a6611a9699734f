#!/usr/bin/env python3
"""A client holds one share of the queue however many connections it
opens: one that floods on many connections cannot keep another client's
frames out (docs/SERVER.md, "Limits and backpressure").

The share was a connection's: a client that opened a connection per
frame held as many shares, filled the queue with one frame on each, none
over its connection's share, and another client's frame found no place
and no frame to push out: BUSY. Now a client is a process on a Unix
socket (SO_PEERCRED) and an IP address over TCP, and its connections'
frames are summed against one share.

Here, while a long frame runs with a small one queued behind it, this
process (the flooder) sends one small frame on each of 7 more connections
to a queue of 8: its ninth frame in all is refused, naming the client and
its share; then another process sends two frames, and both are admitted
and answered, the second by pushing out the flooder's newest queued frame
(a RESULT of status BUSY).
With --queue-share-by connection the old rule is back, and the other
client's frames are refused.

usage: test_queue_share_per_client.py HAIRFILTERD WEIGHTS_DIR
"""
import multiprocessing
import os
import struct
import sys
import tempfile
import time

from rawwire import (BUSY, ERROR, FILTER, RESULT, STATS, STATS_REPLY, check, connect, finish,
                     frame, read_frame, require_started, start, stop_and_clean)

HAIRFILTERD, WEIGHTS = sys.argv[1:3]
SPP = 4
QUEUE = 8
# Large frames up to this side fit the default memory budget; a faster
# machine than the one calibrated on gets the largest.
MAX_SIDE = 1536


def filt(rid, side, variant=b"Small"):
    p = (struct.pack("<HHIIHBB", len(variant), 0, side, side, SPP, 0, 0) +
         struct.pack("<9f", *([0.5] * 9)) + variant)
    return frame(FILTER, p + bytes(side * side * SPP * 6 * 4), rid)


def queue_depth(s):
    """STATS' queue_depth: admitted frames not yet running."""
    s.sendall(frame(STATS))
    t, _, p = read_frame(s)
    check(t == STATS_REPLY, "STATS answered by STATS_REPLY (type %d)" % t)
    return struct.unpack("<I", p[20:24])[0]


def reply(s):
    """(type, id, RESULT status or ERROR code, ERROR message or '')."""
    t, rid, p = read_frame(s)
    if t == RESULT:
        return t, rid, struct.unpack("<H", p[:2])[0], ""
    code, _, _, n = struct.unpack("<IBBH", p[:8])
    return t, rid, code, p[8:8 + n].decode(errors="replace")


def other_client(sock, pipe):
    """Another process, another client: one connection; on the word, two
    frames, and what they were answered goes back."""
    s = connect(sock)
    s.settimeout(120)
    pipe.recv()
    s.sendall(filt(1, 2))
    s.sendall(filt(2, 2))
    pipe.send(sorted(reply(s) for _ in range(2)))
    s.close()


def round_(share_by):
    """One daemon run with --queue-share-by share_by: (the flooder's
    immediate replies, the other client's replies, the flooder's other
    replies)."""
    w = tempfile.mkdtemp(prefix="hfqueueshare-")
    proc = None
    try:
        proc, sock = start(HAIRFILTERD, w,
                           ["--weights", os.path.join(WEIGHTS, "small.safetensors"),
                            "--weights", os.path.join(WEIGHTS, "large.safetensors"),
                            "--max-batch", "1", "--queue-size", str(QUEUE),
                            "--max-size", "%dx%d" % (MAX_SIDE, MAX_SIDE),
                            "--queue-share-by", share_by])
        require_started(sock)
        here, there = multiprocessing.Pipe()
        other = multiprocessing.Process(target=other_client, args=(sock, there))
        other.start()
        stats = connect(sock)
        conns = [connect(sock) for _ in range(QUEUE)]
        for s in [stats] + conns:
            s.settimeout(120)
        big = conns[0]
        # A frame of the slow variant that runs a few seconds here, sized
        # from one of 256x256, so that the queue stays full while the rest
        # happens; a small one behind it on its connection is queued once
        # it runs (STATS' queue_depth 1, twice in a row: the long one has
        # arrived and the worker holds it, whatever its bytes took).
        t0 = time.time()
        big.sendall(filt(1, 256, b"Large"))
        reply(big)
        per_pixel = max(time.time() - t0, 1e-3) / (256 * 256)
        side = int(min(MAX_SIDE, max(256, (3.0 / per_pixel) ** 0.5)))
        big.sendall(filt(2, side, b"Large") + filt(3, 2))
        seen = 0
        while seen < 2:
            seen = seen + 1 if queue_depth(stats) == 1 else 0
            time.sleep(0.05)
        # One frame on each other connection of this client: the queue
        # fills (QUEUE - 1 of them fit) and one is refused at once.
        for k, s in enumerate(conns[1:]):
            s.sendall(filt(100 + k, 2))
        until = time.time() + 30
        while queue_depth(stats) < QUEUE - 1 and time.time() < until:
            time.sleep(0.02)
        here.send("go")
        others = here.recv()
        other.join()
        rest = [reply(s) for s in conns for _ in range(2 if s is big else 1)]
        for s in [stats] + conns:
            s.close()
        print("--queue-share-by %s: the long frame %dx%d; the other client got %s"
              % (share_by, side, side, [(r[0], r[2]) for r in others]))
        return others, rest
    finally:
        stop_and_clean(proc, w)


def main():
    others, rest = round_("client")
    check([(r[0], r[2]) for r in others] == [(RESULT, 0), (RESULT, 0)],
          "another client's two frames are admitted and served while one client floods the "
          "queue on %d connections (%s)" % (QUEUE, others))
    refused = [r for r in rest if r[0] == ERROR]
    check(len(refused) == 1 and refused[0][2] == BUSY and
          "this client (pid %d, %d connection(s) together) holds its share of the queue "
          "(%d frame(s) of --queue-size %d" % (os.getpid(), QUEUE + 1, QUEUE, QUEUE)
          in refused[0][3],
          "the flooder's connections share one share: its frame past %d in all is refused, "
          "naming the client (%s)" % (QUEUE, refused))
    pushed = [r for r in rest if r[0] == RESULT and r[2] == BUSY]
    check(len(pushed) == 1, "one of the flooder's queued frames was pushed out, answered by a "
          "RESULT of status BUSY (%s)" % rest)
    others, rest = round_("connection")
    check(any(r[0] == ERROR and r[2] == BUSY for r in others),
          "with --queue-share-by connection each connection holds a share, and a frame on "
          "each of %d connections keeps the other client's frames out (%s)" % (QUEUE, others))
    finish()


if __name__ == "__main__":
    main()
