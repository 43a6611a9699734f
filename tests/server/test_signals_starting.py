#!/usr/bin/env python3
"""Signals while hairfilterd starts (its models loading, --warm plans being
built: minutes on a GPU), before its event loop handles them:

  * SIGHUP and SIGUSR1 do not kill it (they did, with their default
    action: a reload or a statistics request sent during a start, by hand
    or from a log rotation's postrotate, was an outage); once it serves,
    the reload runs and the statistics are logged;
  * SIGTERM stops it without serving, exit status 0, saying so (it was
    killed by the signal, status 143, without a word).

Each signal is sent once the start is under way and before the daemon
listens; a machine too fast for that (the log says "listening" already)
makes the case say so and pass, as nothing could be checked.

usage: test_signals_starting.py HAIRFILTERD WEIGHTS_DIR
"""
import os
import signal
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rawwire import check, finish  # noqa: E402

HAIRFILTERD, WEIGHTS = sys.argv[1:3]


def start(w, tag):
    """The daemon with every bundled variant and --warm shapes on cpu,
    which keeps it starting for a second or more: (process, log path)."""
    log = os.path.join(w, tag + ".log")
    with open(log, "w") as f:
        proc = subprocess.Popen(
            [HAIRFILTERD, "--config", "none", "--listen", "unix:%s/%s.sock" % (w, tag),
             "--weights-dir", WEIGHTS, "--backend", "cpu", "--max-size", "2048x2048",
             "--warm", "2048x2048,2048x1024,1024x1024,512x512",
             "--ready-file", os.path.join(w, tag + ".ready")],
            stdout=f, stderr=subprocess.STDOUT)
    return proc, log


def send_while_starting(proc, log, sig):
    """Sends sig once the start is under way (a variant loaded) and before
    the daemon listens: True, or False when it listened first."""
    deadline = time.time() + 60
    while time.time() < deadline and "variant " not in open(log).read():
        time.sleep(0.01)
    if "listening on" in open(log).read():
        return False
    proc.send_signal(sig)
    return "listening on" not in open(log).read()


def wait_for(path, text, timeout=60):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if os.path.exists(path) and text in open(path).read():
            return True
        time.sleep(0.05)
    return False


def main():
    w = tempfile.mkdtemp(prefix="hfsigstart-")
    procs = []
    try:
        for sig, after in ((signal.SIGHUP, "reload done:"), (signal.SIGUSR1, "statistics: uptime=")):
            name = sig.name
            proc, log = start(w, name)
            procs.append(proc)
            sent = send_while_starting(proc, log, sig)
            if not sent:
                print("%s: the daemon listened before the signal could be sent; not checked" % name)
            else:
                ok = wait_for(os.path.join(w, name + ".ready"), "unix:")
                check(ok and proc.poll() is None,
                      "%s during the start: the daemon lives and serves (status %s):\n%s"
                      % (name, proc.poll(), open(log).read()))
                # (Said as "came during the start" unless the signal landed
                # just as the loop took over; handled either way.)
                check(wait_for(log, after),
                      "%s during the start: handled once serving:\n%s" % (name, open(log).read()))
            proc.send_signal(signal.SIGTERM)
            check(proc.wait(60) == 0, "%s case: stopped with 0" % name)

        proc, log = start(w, "SIGTERM")
        procs.append(proc)
        if not send_while_starting(proc, log, signal.SIGTERM):
            print("SIGTERM: the daemon listened before the signal could be sent; not checked")
        else:
            rc = proc.wait(60)
            text = open(log).read()
            # Stopped before listening when it came while the models
            # loaded; one that came after that is handled once the loop
            # runs, as a drain.
            before = ("SIGTERM during the start: stopping before serving" in text
                      and "listening on" not in text)
            after = "SIGTERM came during the start: handled now" in text and "stopped:" in text
            check(rc == 0 and (before or after),
                  "SIGTERM during the start: status %s (want 0), stopped:\n%s" % (rc, text))
            check(not os.path.exists(os.path.join(w, "SIGTERM.ready")),
                  "SIGTERM during the start: no ready file left")
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
        for f in sorted(os.listdir(w)):
            os.unlink(os.path.join(w, f))
        os.rmdir(w)
    finish()


main()
