#!/usr/bin/env python3
"""A socket whose server is alive but does not accept (stopped with
SIGSTOP, frozen, or busy with a full backlog) is a live server: hairfilterd
says so and exits, rather than hang in connect() at its start.

  * --listen unix:PATH where such a socket listens: exit 1, "another
    server is listening there", within seconds;
  * --ready-file naming such a socket in a ready file: exit 1, "a running
    daemon wrote it", within seconds, the file left alone.

usage: test_socket_probe_full.py HAIRFILTERD WEIGHTS.safetensors
"""
import os
import socket
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from opsdaemon import check, cleanup, finish, workdir  # noqa: E402

HAIRFILTERD, WEIGHTS = sys.argv[1:3]


def full_listener(path):
    """A listening socket at path whose backlog is full: (listener, the
    connections that filled it)."""
    lst = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    lst.bind(path)
    lst.listen(0)
    held = []
    for _ in range(64):
        c = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        c.setblocking(False)
        try:
            c.connect(path)
        except BlockingIOError:
            c.close()
            return lst, held
        held.append(c)
    raise RuntimeError("the backlog of %s never filled" % path)


def run(args):
    """(status, stderr) of hairfilterd, or (None, '') when it hangs."""
    try:
        p = subprocess.run([HAIRFILTERD] + args, stdout=subprocess.DEVNULL,
                           stderr=subprocess.PIPE, timeout=20)
    except subprocess.TimeoutExpired:
        return None, ""
    return p.returncode, p.stderr.decode(errors="replace")


def main():
    w = workdir()
    try:
        path = os.path.join(w, "hf.sock")
        lst, held = full_listener(path)
        base = ["--config", "none", "--backend", "cpu-ref", "--weights", WEIGHTS]

        status, err = run(base + ["--listen", "unix:" + path])
        check(status == 1 and "another server is listening there" in err,
              "--listen on a live socket with a full backlog: exit 1, said (%s %r)"
              % (status, err))
        check(os.path.exists(path), "the live socket file is left alone")

        ready = os.path.join(w, "ready")
        with open(ready, "w") as f:
            f.write("unix:%s\n" % path)
        status, err = run(base + ["--listen", "unix:" + os.path.join(w, "other.sock"),
                                  "--ready-file", ready])
        check(status == 1 and "a running daemon wrote it" in err,
              "--ready-file of a live daemon with a full backlog: exit 1, said (%s %r)"
              % (status, err))
        check(os.path.exists(ready), "that daemon's ready file is left alone")
        for c in held:
            c.close()
        lst.close()
    finally:
        cleanup(w)
    finish()


if __name__ == "__main__":
    main()
