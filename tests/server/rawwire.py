"""The wire of protocol/PROTOCOL.md at its lowest, for the server tests that
must send what no client library would (a FILTER past the window, replies
left unread, SHM_CREATE behind an unread reply): message types, frames,
HELLO, starting and stopping the daemon, the ports of its ready file, and
the tests' check/finish."""
import array
import os
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import time

MAGIC = 0x31504648
HELLO, HELLO_OK, FILTER, RESULT, ERROR = 1, 2, 5, 6, 7
STATS, STATS_REPLY, SHM_CREATE, SHM_CREATED, SHM_DESTROY = 8, 9, 10, 11, 12
TOO_LARGE, BUSY = 4, 6   # ERROR codes

failures = []


def check(cond, what):
    """Records a failed check (the test goes on, to report them all)."""
    if not cond:
        failures.append(what)
        print("FAIL:", what)


def finish():
    """Exits 1 when a check failed."""
    if failures:
        print("%d check(s) failed" % len(failures))
        sys.exit(1)
    print("all checks passed")


def frame(t, payload=b"", rid=0):
    """One message: the 16-byte header (magic, type, flags 0, id, length)
    and its payload."""
    return struct.pack("<IHHII", MAGIC, t, 0, rid, len(payload)) + payload


def recvn(s, n):
    b = b""
    while len(b) < n:
        c = s.recv(n - len(b))
        if not c:
            raise EOFError("the daemon closed after %d of %d bytes" % (len(b), n))
        b += c
    return b


def read_frame(s):
    """(type, id, payload) of the next message."""
    _, t, _, rid, n = struct.unpack("<IHHII", recvn(s, 16))
    return t, rid, recvn(s, n)


def shm_create(s, nbytes):
    """Asks for a segment of nbytes: ("ok", (segment id, descriptor)), or
    ("error", (code, fatal, message))."""
    s.sendall(frame(SHM_CREATE, struct.pack("<Q", nbytes)))
    head, anc, _, _ = s.recvmsg(16, socket.CMSG_SPACE(4 * 4))
    fds = array.array("i")
    for level, kind, data in anc:
        if level == socket.SOL_SOCKET and kind == socket.SCM_RIGHTS:
            fds.frombytes(data[:len(data) - len(data) % fds.itemsize])
    if not head:
        raise EOFError("the daemon closed instead of answering SHM_CREATE")
    _, t, _, _, n = struct.unpack("<IHHII", head + recvn(s, 16 - len(head)))
    p = recvn(s, n)
    if t == SHM_CREATED and len(fds) == 1:
        return "ok", (struct.unpack("<I", p[:4])[0], fds[0])
    for fd in fds:
        os.close(fd)
    if t != ERROR:
        raise RuntimeError("SHM_CREATE answered by type %d" % t)
    code, fatal, _, m = struct.unpack("<IBBH", p[:8])
    return "error", (code, fatal, p[8:8 + m].decode())


def hello(path):
    """A connection to the Unix socket path and what the daemon answered
    its HELLO (versions 1..3, 4 in flight): ("ok", socket), ("error",
    (code, fatal, message)), or ("nothing", why) when it closed without
    an ERROR."""
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(10)
    s.connect(path)
    try:
        s.sendall(frame(HELLO, struct.pack("<HHHH", 1, 3, 4, 0) + b"test"))
    except OSError:
        pass  # refused at once: the ERROR is still there to read
    try:
        t, _, p = read_frame(s)
    except (OSError, EOFError) as e:
        s.close()
        return "nothing", repr(e)
    if t == HELLO_OK:
        return "ok", s
    s.close()
    code, fatal, _, n = struct.unpack("<IBBH", p[:8])
    return "error", (code, fatal, p[8:8 + n].decode())


def connect(path):
    """A connection past its HELLO_OK; RuntimeError otherwise."""
    kind, s = hello(path)
    if kind != "ok":
        raise RuntimeError("no HELLO_OK: %s %s" % (kind, s))
    return s


def start(binary, w, args, env=None, preexec_fn=None):
    """hairfilterd (binary) on a Unix socket in w with args, the cpu
    backend, its log in w/daemon.log: (process, socket path) once its
    ready file is there, or (process, None) when it exited or was not
    ready within 60 s."""
    sock = os.path.join(w, "s.sock")
    ready = os.path.join(w, "ready")
    for p in (sock, ready):
        if os.path.exists(p):
            os.unlink(p)
    with open(os.path.join(w, "daemon.log"), "w") as log:
        proc = subprocess.Popen([binary, "--config", "none", "--listen", "unix:" + sock,
                                 "--backend", "cpu", "--ready-file", ready] + args,
                                stdout=log, stderr=subprocess.STDOUT, env=env,
                                preexec_fn=preexec_fn)
    return proc, sock if wait_ready(proc, ready) else None


def wait_ready(proc, ready, seconds=60):
    """Waits for hairfilterd (proc) to write its ready file (path ready):
    True once it is there, False when the process exited first or seconds
    went by."""
    deadline = time.time() + seconds
    while time.time() < deadline and not os.path.exists(ready):
        if proc.poll() is not None:
            return False
        time.sleep(0.02)
    return os.path.exists(ready)


def ready_ports(w, scheme):
    """The ports of the lines of w/ready (the daemon's listeners) that
    start with scheme ("tcp", "tls"), in their order."""
    return [int(line.rsplit(":", 1)[1]) for line in open(os.path.join(w, "ready")).read().split()
            if line.startswith(scheme + ":")]


def v4_mapped_unavailable():
    """Why an IPv6 socket cannot be bound to a v4-mapped address here (the
    tests of such listeners are then skipped), or None when it can."""
    try:
        s = socket.socket(socket.AF_INET6)
        try:
            s.bind(("::ffff:127.0.0.1", 0))
        finally:
            s.close()
    except OSError as e:
        return str(e)
    return None


def stop(proc, w):
    """Stops hairfilterd (SIGTERM, then SIGKILL after 30 s) and returns
    its log, w/daemon.log."""
    if proc.poll() is None:
        proc.terminate()
    try:
        proc.wait(30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    path = os.path.join(w, "daemon.log")
    return open(path).read() if os.path.exists(path) else ""


def require_started(sock):
    """Checks that start gave a socket; raises RuntimeError when it did not
    (the caller's clean-up prints the daemon's log)."""
    check(sock is not None, "the daemon started")
    if sock is None:
        raise RuntimeError("hairfilterd did not start")   # its log follows


def stop_and_clean(proc, w):
    """A test's clean-up: stops hairfilterd (when start ran), prints its
    log when a check failed, removes the work directory w."""
    log = stop(proc, w) if proc else ""
    if failures:
        print(log)
    shutil.rmtree(w, ignore_errors=True)


def expect_error(got, code, what, words):
    """Checks that got (shm_create's answer) is a non-fatal ERROR of code
    whose message names words."""
    check(got[0] == "error" and got[1][0] == code and got[1][1] == 0 and words in got[1][2],
          "%s: non-fatal error %d naming %r (%s)" % (what, code, words, got))


def shm_ok(got, fds, what):
    """Checks that got (shm_create's answer) is SHM_CREATED; keeps its
    descriptor in fds (the caller closes them) and returns the segment's
    id, or 0."""
    check(got[0] == "ok", "%s: SHM_CREATED (%s)" % (what, got))
    if got[0] == "ok":
        fds.append(got[1][1])
        return got[1][0]
    return 0


def with_daemon(binary, prefix, args, body):
    """Runs body(sock, fds, w) against hairfilterd started with args in a
    new work directory w (named from prefix), then closes the descriptors
    body left in fds and stops the daemon."""
    w = tempfile.mkdtemp(prefix=prefix)
    proc, fds = None, []
    try:
        proc, sock = start(binary, w, args)
        require_started(sock)
        body(sock, fds, w)
    finally:
        for fd in fds:
            os.close(fd)
        stop_and_clean(proc, w)
