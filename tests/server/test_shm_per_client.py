#!/usr/bin/env python3
"""One local client, a process, holds at most its part of the shared memory
(--max-shm-mb-per-client) however many connections it opens, and another
process still gets its segments.

The part was a connection's only (--max-shm-mb-per-connection): an engine
that opened N connections held N parts, and with four it could take the
whole --max-shm-mb and leave every other local client BUSY. The daemon
now counts a process's connections together, by the pid the kernel gives
for a Unix socket's peer (SO_PEERCRED).

usage: test_shm_per_client.py HAIRFILTERD WEIGHTS_DIR
"""
import multiprocessing
import os
import struct
import sys
import time

from rawwire import (BUSY, SHM_DESTROY, STATS, STATS_REPLY, TOO_LARGE, check, connect, expect_error,
                     finish, frame, read_frame, shm_create, shm_ok, with_daemon)

HAIRFILTERD, WEIGHTS = sys.argv[1:3]
MIB = 1 << 20


def other_client(sock, sizes, pipe):
    """Another process: two connections, a segment of each size in turn on
    them; sends back what each got, then holds them until told to go."""
    conns = [connect(sock), connect(sock)]
    got = []
    for i, n in enumerate(sizes):
        r = shm_create(conns[i % 2], n)
        got.append(r[0] if r[0] == "ok" else "error %d: %s" % (r[1][0], r[1][2]))
    pipe.send(got)
    pipe.recv()
    for c in conns:
        c.close()


def run(args, body):
    with_daemon(HAIRFILTERD, "hfshmclient-",
                ["--weights", os.path.join(WEIGHTS, "small.safetensors"), "--max-size", "100x100"] + args, body)


def parts(sock, fds, w):
    """--max-shm-mb 16, 6 per client, 4 per connection: three connections
    of this process hold 6 MiB in all; another process gets its 6 too."""
    a, b, c = connect(sock), connect(sock), connect(sock)
    seg = shm_ok(shm_create(a, 4 * MIB), fds, "connection A's 4 MiB")
    shm_ok(shm_create(b, 2 * MIB), fds, "connection B's 2 MiB (6 for the client)")
    expect_error(shm_create(b, 1), BUSY, "B's next byte, over the client's 6 MiB",
           "--max-shm-mb-per-client")
    expect_error(shm_create(c, 1 * MIB), BUSY, "a third connection's 1 MiB, over the client's 6 MiB",
           "--max-shm-mb-per-client")
    expect_error(shm_create(c, 5 * MIB), TOO_LARGE, "a 5 MiB segment, over a connection's 4",
           "--max-shm-mb-per-connection")
    # Another process is another client, with a part of its own.
    here, there = multiprocessing.Pipe()
    p = multiprocessing.Process(target=other_client, args=(sock, [2 * MIB, 4 * MIB, 1], there))
    p.start()
    got = here.recv() if here.poll(30) else ["nothing"]
    check(got[:2] == ["ok", "ok"],
          "another process gets its 2 and 4 MiB while this one holds its 6 (%s)" % got)
    check(len(got) == 3 and "--max-shm-mb-per-client" in got[2],
          "and is held to its own part (%s)" % got)
    here.send("go")
    p.join(30)
    # The client's part comes back as its segments go: A's destroyed,
    # then a connection closed.
    a.sendall(frame(SHM_DESTROY, struct.pack("<I", seg)) + frame(STATS))
    check(read_frame(a)[0] == STATS_REPLY, "STATS_REPLY after SHM_DESTROY")
    shm_ok(shm_create(c, 4 * MIB), fds, "C's 4 MiB once A's segment is destroyed")
    b.close()
    deadline, got = time.time() + 10, None
    while time.time() < deadline:
        got = shm_create(a, 2 * MIB)
        if got[0] == "ok":
            break
        time.sleep(0.05)
    shm_ok(got, fds, "A's 2 MiB once B closed")
    a.close()
    c.close()
    log = open(os.path.join(w, "daemon.log")).read()
    check("shared memory 16 MiB (6 MiB per client, 4 MiB per connection)" in log,
          "the start line says what a client and a connection may hold: %r" % log)


def client_smaller(sock, fds, w):
    """A client's part below a connection's: a segment over it is
    TOO_LARGE naming --max-shm-mb-per-client."""
    a = connect(sock)
    expect_error(shm_create(a, 3 * MIB), TOO_LARGE, "a 3 MiB segment, over a client's 2",
           "--max-shm-mb-per-client")
    shm_ok(shm_create(a, 2 * MIB), fds, "a 2 MiB segment")
    a.close()


def main():
    run(["--max-shm-mb", "16", "--max-shm-mb-per-client", "6",
         "--max-shm-mb-per-connection", "4"], parts)
    run(["--max-shm-mb", "16", "--max-shm-mb-per-client", "2",
         "--max-shm-mb-per-connection", "4"], client_smaller)
    finish()


if __name__ == "__main__":
    main()
