#!/usr/bin/env python3
"""A shared segment's memory goes back when the daemon releases it
(SHM_DESTROY, or the connection closing), also while the client keeps its
descriptor.

The pages of a segment the worker touched (features the client never
wrote, read as zeros; the results written) are charged to the daemon. It
used to unmap the segment and close its own descriptor only, so the pages
stayed as long as the client kept its copy of the memfd: a client that made,
used and released segments in a loop, keeping each descriptor, grew the
daemon's memory without bound, outside --max-shm-mb (which gives the bytes
back on release). Now they are freed at the release (MADV_REMOVE): the
memfd's allocated blocks (st_blocks) drop to 0.

usage: test_shm_release.py HAIRFILTERD WEIGHTS_DIR
"""
import array
import os
import socket
import struct
import sys
import tempfile
import time

from rawwire import (FILTER, RESULT, SHM_CREATE, STATS, STATS_REPLY, check, connect, finish, frame,
                     read_frame, require_started, start, stop_and_clean)

HAIRFILTERD, WEIGHTS = sys.argv[1:3]
SHM_CREATED, SHM_DESTROY = 11, 12
W, H = 64, 64
IN_BYTES = W * H * 4 * 6 * 4     # Small: 4 spp, f32 features
OUT_BYTES = W * H * 3 * 4        # f32 result


def segment(s):
    """(id, descriptor) of a new segment large enough for one frame."""
    s.sendall(frame(SHM_CREATE, struct.pack("<Q", IN_BYTES + OUT_BYTES)))
    msg, anc, _, _ = s.recvmsg(16 + 12, socket.CMSG_SPACE(4 * 4))
    check(len(msg) == 28 and struct.unpack("<H", msg[4:6])[0] == SHM_CREATED,
          "SHM_CREATED (%d bytes)" % len(msg))
    fds = array.array("i")
    for level, kind, data in anc:
        if level == socket.SOL_SOCKET and kind == socket.SCM_RIGHTS:
            fds.frombytes(data[:len(data) - len(data) % fds.itemsize])
    check(len(fds) == 1, "one descriptor with SHM_CREATED (%d)" % len(fds))
    return struct.unpack("<I", msg[16:20])[0], fds[0]


def filter_in(s, seg, rid):
    """Filters a frame whose features are the segment's (never written by
    this client: zeros); 1 when it got a RESULT of status 0."""
    fixed = struct.pack("<HHIIHBB", 5, 2, W, H, 4, 0, 0) + struct.pack("<9f", *[0.5] * 9)
    ref = struct.pack("<IIQQQ", seg, 0, 0, IN_BYTES, 0)
    s.sendall(frame(FILTER, fixed + b"Small" + ref, rid))
    t, r, p = read_frame(s)
    return t == RESULT and r == rid and struct.unpack("<H", p[:2])[0] == 0


def blocks(fd):
    return os.fstat(fd).st_blocks


def main():
    w = tempfile.mkdtemp(prefix="hfshmrel-")
    proc = None
    fds = []
    try:
        proc, sock = start(HAIRFILTERD, w, ["--weights", os.path.join(WEIGHTS, "small.safetensors")])
        require_started(sock)

        # Released by SHM_DESTROY, the client keeping the descriptor.
        s = connect(sock)
        seg, fd = segment(s)
        fds.append(fd)
        check(filter_in(s, seg, 1), "a frame in the segment is filtered")
        check(blocks(fd) > 0, "the worker's pages are the segment's (%d blocks)" % blocks(fd))
        s.sendall(frame(SHM_DESTROY, struct.pack("<I", seg)) + frame(STATS))
        t, _, _ = read_frame(s)   # STATS is read after the SHM_DESTROY
        check(t == STATS_REPLY, "STATS_REPLY after SHM_DESTROY (type %d)" % t)
        check(blocks(fd) == 0,
              "after SHM_DESTROY the segment holds no memory, its descriptor still open "
              "(%d blocks)" % blocks(fd))

        # Released by the connection closing.
        seg, fd = segment(s)
        fds.append(fd)
        check(filter_in(s, seg, 2), "a frame in a second segment is filtered")
        check(blocks(fd) > 0, "the worker's pages are the second segment's")
        s.close()
        deadline = time.time() + 10
        while blocks(fd) and time.time() < deadline:
            time.sleep(0.05)
        check(blocks(fd) == 0,
              "after the connection closed its segment holds no memory (%d blocks)" % blocks(fd))

        # The daemon serves segments as before.
        s = connect(sock)
        seg, fd = segment(s)
        fds.append(fd)
        check(filter_in(s, seg, 3), "a new connection's segment is filtered in")
        s.close()
    finally:
        for fd in fds:
            os.close(fd)
        stop_and_clean(proc, w)
    finish()


if __name__ == "__main__":
    main()
