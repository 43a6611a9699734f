#!/usr/bin/env python3
"""hairfilterd and its open files: a connection past the limit always gets
the documented refusal, never a close without a word.

  * segments: a Unix-socket client that asks for segment after segment
    without reading the answers holds one descriptor in the daemon at a
    time (its SHM_CREATED waits to be written), not one per segment: 16
    per connection would let a few dozen clients exhaust the open-file
    limit, and every new connection would then be dropped unseen;
  * --max-connections above what the open-file limit allows: the daemon
    raises its soft limit up to the hard one, and past the hard one lowers
    --max-connections with a warning, so that every connection over it gets
    the fatal BUSY naming the limit (libuv drops a connection it cannot get
    a descriptor for without telling anyone);
  * a hard limit that leaves nothing for connections stops the start
    (exit 1), naming the limit and the fix.

usage: test_descriptors.py HAIRFILTERD WEIGHTS_DIR
"""
import os
import resource
import shutil
import socket
import struct
import sys
import tempfile
import time

import rawwire
from rawwire import (BUSY, FILTER, RESULT, SHM_CREATE, check, failures, finish, frame, hello,
                     recvn, stop)

HAIRFILTERD, WEIGHTS = sys.argv[1:3]


def start(w, args, nofile):
    """Small's hairfilterd (rawwire.start) under RLIMIT_NOFILE nofile
    (soft, hard)."""
    def limit():
        resource.setrlimit(resource.RLIMIT_NOFILE, nofile)

    return rawwire.start(HAIRFILTERD, w, ["--weights", os.path.join(WEIGHTS, "small.safetensors")]
                         + args, preexec_fn=limit)


def fds(pid):
    return len(os.listdir("/proc/%d/fd" % pid))


def segments_one_at_a_time(w):
    proc, sock = start(w, [], (1024, 1024))
    check(sock is not None, "segments: the daemon started")
    if not sock:
        print(stop(proc, w))
        return
    try:
        kind, s = hello(sock)
        check(kind == "ok", "segments: HELLO_OK, not %s %s" % (kind, s))
        if kind != "ok":
            return
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        # A result far larger than any socket buffer, left unread, keeps
        # what follows it waiting in the daemon.
        w_, h_, spp = 256, 256, 4
        fixed = struct.pack("<HHIIHBB", 5, 0, w_, h_, spp, 0, 0) + struct.pack("<9f", *[0.5] * 9)
        tensor = b"\0" * (w_ * h_ * spp * 6 * 4)
        s.sendall(frame(FILTER, fixed + b"Small" + tensor, rid=1))
        _, t, _, _, _ = struct.unpack("<IHHII", recvn(s, 16))
        check(t == RESULT, "segments: the FILTER's RESULT starts (type %d)" % t)
        before = fds(proc.pid)
        s.sendall(frame(SHM_CREATE, struct.pack("<Q", 4096)) * 16)
        time.sleep(0.5)
        grew = fds(proc.pid) - before
        check(grew <= 1, "segments: 16 SHM_CREATE behind an unread reply hold %d descriptors in "
              "the daemon, not at most 1" % grew)
        s.close()
    finally:
        log = stop(proc, w)
        if any("segments" in f for f in failures):
            print(log)


def connections_over_the_limit(w, nofile, want_limit, opened):
    """Opens `opened` connections to a daemon told --max-connections 100
    under RLIMIT_NOFILE nofile: the first want_limit get HELLO_OK, every
    other one the fatal BUSY naming want_limit."""
    proc, sock = start(w, ["--max-connections", "100"], nofile)
    what = "RLIMIT_NOFILE %s" % (nofile,)
    check(sock is not None, "%s: the daemon started" % what)
    if not sock:
        print(stop(proc, w))
        return
    held, answers = [], {}
    try:
        for i in range(opened):
            kind, x = hello(sock)
            if kind == "ok":
                held.append(x)
                key = "ok"
            elif kind == "error":
                key = "error %d fatal %d: %s" % x
            else:
                key = "closed without an ERROR (%s)" % x
            answers[key] = answers.get(key, 0) + 1
        busy = "error %d fatal 1: connection limit (%d) reached" % (BUSY, want_limit)
        check(answers == {"ok": want_limit, busy: opened - want_limit},
              "%s: %d connections: %d HELLO_OK and %d '%s', not %s"
              % (what, opened, want_limit, opened - want_limit, busy, answers))
    finally:
        for s in held:
            s.close()
        log = stop(proc, w)
    return log


def main():
    w = tempfile.mkdtemp(prefix="hffds-")
    try:
        segments_one_at_a_time(w)
        # Soft limit low, hard limit high: raised, the limit stands.
        log = connections_over_the_limit(w, (64, 4096), 100, 110)
        check("open-file limit raised from 64 to" in log,
              "the raised soft limit is logged: %r" % log)
        # Hard limit low: --max-connections lowered to what it holds,
        # (120 - 64 - 1 listener) / 2 descriptors each, and said.
        log = connections_over_the_limit(w, (120, 120), 27, 110)
        check("warning: --max-connections lowered from 100 to 27: the open-file limit is 120" in log
              and "LimitNOFILE=" in log, "the lowered limit is a warning naming the fix: %r" % log)
        # Nothing left for a connection: no start.
        proc, sock = start(w, [], (60, 60))
        log = stop(proc, w)
        check(sock is None and proc.returncode == 1,
              "open-file limit 60: exit status 1 before ready, not %s" % proc.returncode)
        check("error: the open-file limit (60) leaves no descriptor for a connection" in log,
              "open-file limit 60: the reason is logged: %r" % log)
    finally:
        shutil.rmtree(w, ignore_errors=True)
    finish()


if __name__ == "__main__":
    main()
