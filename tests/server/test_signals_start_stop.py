#!/usr/bin/env python3
"""A stop while hairfilterd loads its models, as it starts or in a reload,
does not wait for the loads to end.

Loading every model and building every --warm plan takes minutes on a GPU;
a SIGTERM or SIGINT then (systemctl stop, a pod deleted) used to be acted
on only once all of it was done, and systemd or the kubelet kill a daemon
that takes that long to stop. Here each weights file takes half a second to
open (an LD_PRELOAD shim: the bundled ten load in a second on the cpu
backend otherwise), and the signal is sent once the first model is built:

  * SIGTERM and SIGINT: the daemon stops before the next file, status 0,
    with "SIGTERM during the start: stopping before serving", having
    loaded fewer files than it was given, never listening, and leaving no
    ready file, socket or file beside them (under a sanitizer build, its
    leak check at exit makes what the stop left unfreed a failure);
  * SIGHUP: as before, the start goes on with every file, the daemon
    serves, and the reload runs once it does;
  * SIGTERM in a reload that adds nine files: the drain gives up the
    reload's loads not done (it used to wait for all of them, its event
    loop stopped meanwhile), swaps none in, and the daemon exits 0.

usage: test_signals_start_stop.py HAIRFILTERD SLOW_WEIGHTS_SO WEIGHTS_DIR
"""
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rawwire import check, finish  # noqa: E402

HAIRFILTERD, SHIM, WEIGHTS = sys.argv[1:4]
FILES = len([n for n in os.listdir(WEIGHTS) if n.endswith(".safetensors")])
PER_FILE_MS = 500


def start(w, tag, weights=WEIGHTS, match=""):
    """The daemon with the variants of weights and --warm shapes on cpu,
    each weights file whose path holds match slowed down: (process, log
    path)."""
    log = os.path.join(w, tag + ".log")
    # A sanitizer build checks that its runtime is loaded first; the shim
    # comes before it. Its leak check still runs at exit, so a stop that
    # left what it built unfreed fails the exit status check.
    asan = os.environ.get("ASAN_OPTIONS", "")
    env = dict(os.environ, LD_PRELOAD=SHIM, HF_TEST_SLOW_WEIGHTS_MS=str(PER_FILE_MS),
               HF_TEST_SLOW_WEIGHTS_MATCH=match,
               ASAN_OPTIONS=(asan + ":" if asan else "") + "verify_asan_link_order=0")
    with open(log, "w") as f:
        proc = subprocess.Popen(
            [HAIRFILTERD, "--config", "none", "--listen", "unix:%s/%s.sock" % (w, tag),
             "--weights-dir", weights, "--backend", "cpu", "--warm", "512x512,256x256",
             "--ready-file", os.path.join(w, tag + ".ready")],
            stdout=f, stderr=subprocess.STDOUT, env=env)
    return proc, log


def read(path):
    return open(path).read() if os.path.exists(path) else ""


def wait_for(path, text, timeout=120):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if text in read(path):
            return True
        time.sleep(0.01)
    return False


def prepared_variants(text):
    return set(re.findall(r"variant (\S+): \d+x\d+ batch \d+ prepared in", text))


def stop_case(w, sig):
    name = sig.name
    proc, log = start(w, name)
    try:
        # The first model is built (its plans logged): the start is under
        # way, with FILES - 1 files still to open, half a second each.
        check(wait_for(log, "prepared in"), "%s: the start got under way:\n%s" % (name, read(log)))
        proc.send_signal(sig)
        rc = proc.wait(120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = read(log)
    check(rc == 0, "%s during the start: exit status %s, want 0:\n%s" % (name, rc, text))
    check("%s during the start: stopping before serving" % name in text,
          "%s during the start: the stop is logged:\n%s" % (name, text))
    check("listening on" not in text and "serving:" not in text,
          "%s during the start: stopped before listening:\n%s" % (name, text))
    m = re.search(r"stopping: (\d+) of (\d+) weights file\(s\) loaded", text)
    check(m is not None and int(m.group(2)) == FILES and int(m.group(1)) < FILES,
          "%s during the start: stopped before every file was loaded (%d given):\n%s"
          % (name, FILES, text))
    check(len(prepared_variants(text)) < FILES,
          "%s during the start: plans of fewer than %d variants built:\n%s" % (name, FILES, text))
    left = sorted(f for f in os.listdir(w) if not f.endswith(".log"))
    check(not left, "%s during the start: no ready file or socket left: %s" % (name, left))


def hup_case(w):
    proc, log = start(w, "SIGHUP")
    try:
        check(wait_for(log, "prepared in"), "SIGHUP: the start got under way:\n%s" % read(log))
        proc.send_signal(signal.SIGHUP)
        check(wait_for(os.path.join(w, "SIGHUP.ready"), "unix:") and proc.poll() is None,
              "SIGHUP during the start: the daemon serves (status %s):\n%s"
              % (proc.poll(), read(log)))
        check(wait_for(log, "reload done:"),
              "SIGHUP during the start: the reload runs once serving:\n%s" % read(log))
        text = read(log)
        check(len(prepared_variants(text)) == FILES and "stopping:" not in text,
              "SIGHUP during the start: every file loaded:\n%s" % text)
        proc.send_signal(signal.SIGTERM)
        check(proc.wait(120) == 0, "SIGHUP case: stopped with 0")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def reload_case(w):
    """SIGTERM while a reload loads nine new files (slowed; the one served
    since the start is not)."""
    d = tempfile.mkdtemp(prefix="hfsigreload-")
    try:
        shutil.copy(os.path.join(WEIGHTS, "small.safetensors"), d)
        proc, log = start(w, "reload", weights=d, match="slow-")
        try:
            check(wait_for(os.path.join(w, "reload.ready"), "unix:"),
                  "reload case: the daemon serves:\n%s" % read(log))
            new = [n for n in sorted(os.listdir(WEIGHTS))
                   if n.endswith(".safetensors") and n != "small.safetensors"]
            for n in new:
                shutil.copy(os.path.join(WEIGHTS, n), os.path.join(d, "slow-" + n))
            proc.send_signal(signal.SIGHUP)
            deadline = time.time() + 120
            while time.time() < deadline and not prepared_variants(read(log)) - {"Small"}:
                time.sleep(0.01)
            proc.send_signal(signal.SIGTERM)
            rc = proc.wait(120)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        text = read(log)
        check(rc == 0, "SIGTERM in a reload: exit status %s, want 0:\n%s" % (rc, text))
        m = re.search(r"reload: given up for the stop: (\d+) of (\d+) file\(s\) loaded", text)
        check(m is not None and int(m.group(2)) == len(new) and int(m.group(1)) < len(new),
              "SIGTERM in a reload: the reload was given up before every file was loaded "
              "(%d new):\n%s" % (len(new), text))
        check(len(prepared_variants(text) - {"Small"}) < len(new) and "reload done" not in text,
              "SIGTERM in a reload: fewer than %d new variants built, none swapped in:\n%s"
              % (len(new), text))
    finally:
        shutil.rmtree(d)


def main():
    w = tempfile.mkdtemp(prefix="hfsigstop-")
    try:
        for sig in (signal.SIGTERM, signal.SIGINT):
            stop_case(w, sig)
        hup_case(w)
        reload_case(w)
    finally:
        for f in sorted(os.listdir(w)):
            os.unlink(os.path.join(w, f))
        os.rmdir(w)
    finish()


main()
