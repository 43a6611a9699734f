#!/usr/bin/env python3
"""One connection holds at most its part of the shared memory
(--max-shm-mb-per-connection), so it cannot leave the other local
clients BUSY by taking the whole --max-shm-mb.

A connection used to be held only to 16 segments and the server's whole
budget: one client asking for segments until it got BUSY took all of it,
and every other client's SHM_CREATE was refused as long as it kept them.

usage: test_shm_per_connection.py HAIRFILTERD WEIGHTS_DIR
"""
import os
import struct
import sys
import time

from rawwire import (BUSY, SHM_DESTROY, STATS, STATS_REPLY, TOO_LARGE, check, connect, expect_error,
                     finish, frame, read_frame, shm_create, shm_ok, with_daemon)

HAIRFILTERD, WEIGHTS = sys.argv[1:3]
MIB = 1 << 20


def run(args, body):
    with_daemon(HAIRFILTERD, "hfshmconn-",
                ["--weights", os.path.join(WEIGHTS, "small.safetensors")] + args, body)


def explicit(sock, fds, w):
    """--max-shm-mb 8 --max-shm-mb-per-connection 4: two connections get 4
    MiB each, neither more."""
    a, b = connect(sock), connect(sock)
    seg = shm_ok(shm_create(a, 3 * MIB), fds, "A's first 3 MiB")
    expect_error(shm_create(a, 2 * MIB), BUSY, "A's next 2 MiB, over its 4", "--max-shm-mb-per-connection")
    expect_error(shm_create(a, 5 * MIB), TOO_LARGE, "a 5 MiB segment, over a connection's 4",
           "--max-shm-mb-per-connection")
    shm_ok(shm_create(a, 1 * MIB), fds, "A's last 1 MiB")
    shm_ok(shm_create(b, 4 * MIB), fds, "B's 4 MiB while A holds its 4")
    expect_error(shm_create(b, 1), BUSY, "B's next byte", "--max-shm-mb-per-connection")
    # A released segment is A's to use again.
    a.sendall(frame(SHM_DESTROY, struct.pack("<I", seg)) + frame(STATS))
    check(read_frame(a)[0] == STATS_REPLY, "STATS_REPLY after SHM_DESTROY")
    shm_ok(shm_create(a, 3 * MIB), fds, "A's 3 MiB again after its SHM_DESTROY")
    # A closed connection's part goes back.
    b.close()
    c = connect(sock)
    deadline, got = time.time() + 10, None
    while time.time() < deadline:
        got = shm_create(c, 4 * MIB)
        if got[0] == "ok":
            break
        time.sleep(0.05)
    shm_ok(got, fds, "C's 4 MiB once B closed")
    a.close()
    c.close()


def default(sock, fds, w):
    """--max-shm-mb 16 at 200x200: a quarter, 4 MiB, is less than the
    segments of the largest frame (Small, 4 spp: features 3,840,000 bytes,
    result 480,000, composite 640,000), which one connection may still
    hold whole (and one client, a process, on all its connections)."""
    largest = 200 * 200 * (4 * 6 * 4 + 3 * 4 + 4 * 4)
    a, b = connect(sock), connect(sock)
    shm_ok(shm_create(a, largest), fds, "the largest frame's segments on one connection")
    expect_error(shm_create(a, 1), BUSY, "one byte more on it", "--max-shm-mb-per-connection")
    expect_error(shm_create(b, largest + 1), TOO_LARGE, "one byte over the largest frame's segments",
           "--max-shm-mb-per-connection")
    # Of the same process, whose part (--max-shm-mb-per-client) is the
    # same by default: test_shm_per_client.py has another process's.
    expect_error(shm_create(b, largest), BUSY, "the same on a second connection of this client",
           "--max-shm-mb-per-client")
    a.close()
    b.close()
    log = open(os.path.join(w, "daemon.log")).read()
    check("shared memory 16 MiB (5 MiB per client, 5 MiB per connection)" in log,
          "the start line says what a connection may hold: %r" % log)
    # Only this warning: a sanitizer's allocator adds one of its own.
    check("of shared segments, over what one connection may hold" not in log,
          "no warning of the per-connection part with the default: %r" % log)


def below_largest(sock, fds, w):
    """An operator's value below the largest frame's segments is warned
    about at start, naming the option and the frame."""
    log = open(os.path.join(w, "daemon.log")).read()
    check("warning: a frame of 200x200 needs 4.7 MiB of shared segments, over what one "
          "connection may hold (--max-shm-mb-per-connection 2)" in log,
          "the start warns that the largest frame does not fit a connection's part: %r" % log)


def main():
    run(["--max-shm-mb", "8", "--max-shm-mb-per-connection", "4"], explicit)
    run(["--max-shm-mb", "16", "--max-size", "200x200"], default)
    run(["--max-shm-mb", "16", "--max-size", "200x200", "--max-shm-mb-per-connection", "2"],
        below_largest)
    finish()


if __name__ == "__main__":
    main()
