#!/usr/bin/env python3
"""A Unix socket file that goes away while the daemon serves (a cleaner of
its directory, a runtime directory another service removed, a hand that
thought the daemon gone):

  * /readyz says 503 naming the listener, hairfilterd_ready is 0, and the
    log has one error line that says what happened and what to do; the
    daemon said "ready" while no local client could reach it;
  * a second daemon started on the same path serves there, and the first
    one's stop leaves that daemon's socket alone (libuv unlinked the path
    it had bound when the listener closed, whatever the path was by then,
    so the second daemon lost its socket and said "ready");
  * a socket file that is the daemon's own is still removed at its stop;
  * under systemd (NOTIFY_SOCKET), STATUS= says it too, for `systemctl
    status`, where no readiness probe looks.

usage: test_socket_lost.py HAIRFILTERD WEIGHTS.safetensors
"""
import os
import socket
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from opsdaemon import Daemon, check, cleanup, finish, sample, workdir  # noqa: E402

HAIRFILTERD, WEIGHTS = sys.argv[1:3]


def connects(path):
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        s.connect(path)
        return True
    except OSError:
        return False
    finally:
        s.close()


def main():
    w = workdir()
    path = os.path.join(w, "hf.sock")
    args = ["--config", "none", "--listen", "unix:" + path, "--http", "tcp:127.0.0.1:0",
            "--backend", "cpu-ref", "--weights", WEIGHTS]
    os.makedirs(os.path.join(w, "a"))
    os.makedirs(os.path.join(w, "b"))
    notify_path = os.path.join(w, "notify")
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(notify_path)
    notify.settimeout(0.2)
    a = Daemon(HAIRFILTERD, args, os.path.join(w, "a"), env={"NOTIFY_SOCKET": notify_path})
    b = None
    try:
        status, body = a.get("/readyz")
        check(status == 200, "first daemon ready at start (%s %r)" % (status, body))

        os.unlink(path)
        status, body = a.get("/readyz")
        check(status == 503 and "unix:%s" % path in body and "restart" in body,
              "/readyz 503 naming the lost socket (%s %r)" % (status, body))
        samples, _ = a.metrics()
        check(sample(samples, "hairfilterd_ready") == 0, "hairfilterd_ready 0 with the socket gone")
        deadline = time.time() + 5
        while time.time() < deadline and "socket file was removed" not in a.log_text():
            time.sleep(0.1)
        log = a.log_text()
        check(log.count("error: --listen unix:%s: the socket file was removed" % path) == 1,
              "one error line for the lost socket:\n" + log)
        said = []
        deadline = time.time() + 5
        while time.time() < deadline and not any("not ready: unix:%s" % path in m for m in said):
            try:
                said.append(notify.recv(4096).decode())
            except socket.timeout:
                pass
        check(any("STATUS=not ready: unix:%s: the socket file is gone" % path in m for m in said),
              "STATUS= says the socket is gone: %r" % said)

        b = Daemon(HAIRFILTERD, args, os.path.join(w, "b"))
        check(b.get("/readyz")[0] == 200, "second daemon ready on the same path")
        check(a.get("/readyz")[0] == 503, "first daemon still not ready: the path is another's")
        rc = a.stop()
        check(rc == 0, "first daemon stopped with 0 (%s)" % rc)
        check(os.path.exists(path) and connects(path),
              "the second daemon's socket survives the first one's stop")
        check(b.get("/readyz")[0] == 200, "second daemon still ready after the first stopped")
        rc = b.stop()
        check(rc == 0, "second daemon stopped with 0 (%s)" % rc)
        check(not os.path.exists(path), "a daemon's own socket file removed at its stop")
    finally:
        for d in (a, b):
            if d is not None and d.proc.poll() is None:
                d.proc.kill()
                d.proc.wait()
        notify.close()
        cleanup(w)
    finish()


main()
