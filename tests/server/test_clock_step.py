#!/usr/bin/env python3
"""The wall clock steps while hairfilterd serves (NTP correcting a clock
that was off at boot, a virtual machine resumed): a day forward, through
an LD_PRELOAD shim (clock_step.c) that moves the daemon's CLOCK_REALTIME
alone.

  * hairfilterd_variant_loaded_timestamp_seconds of a variant loaded after
    the step is the wall clock of its load; it was derived from the
    start's wall clock and the monotonic clock, so it stayed a day behind
    and an alert on weights loaded too long ago fired on fresh ones;
  * frames are still served, and the deadlines (monotonic) cut nothing.

usage: test_clock_step.py HAIRFILTERD LOAD_CLIENT CLOCK_STEP_SO WEIGHTS_DIR
"""
import os
import shutil
import signal
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from opsdaemon import (Daemon, check, cleanup, finish, load_result, run_load,  # noqa: E402
                       sample, workdir)

HAIRFILTERD, LOAD_CLIENT, SHIM, WEIGHTS = sys.argv[1:5]
DAY = 86400


def loaded(d):
    samples, _ = d.metrics()
    return sample(samples, "hairfilterd_variant_loaded_timestamp_seconds", variant="Small")


def main():
    w = workdir()
    os.makedirs(os.path.join(w, "weights"))
    small = os.path.join(w, "weights", "small.safetensors")
    shutil.copy(os.path.join(WEIGHTS, "small.safetensors"), small)
    step = os.path.join(w, "step")
    with open(step, "w") as f:
        f.write("0\n")
    # (A sanitizer build's runtime must come first among the libraries;
    # the shim is preloaded before it, which it accepts when told to.)
    asan = os.environ.get("ASAN_OPTIONS", "")
    env = {"LD_PRELOAD": SHIM, "HF_TEST_CLOCK_STEP_FILE": step,
           "ASAN_OPTIONS": (asan + ":" if asan else "") + "verify_asan_link_order=0"}
    d = Daemon(HAIRFILTERD, ["--config", "none", "--listen", "unix:%s/s.sock" % w,
                             "--http", "tcp:127.0.0.1:0", "--backend", "cpu-ref",
                             "--weights-dir", os.path.join(w, "weights"),
                             "--handshake-timeout-ms", "5000"], w, env=env)
    try:
        t = loaded(d)
        check(abs(t - time.time()) < 60, "loaded at start: %.0f, now %.0f" % (t, time.time()))

        with open(step, "w") as f:
            f.write("%d\n" % DAY)
        # A new version of Small, loaded after the step.
        shutil.copy(small, small + ".new")
        os.utime(small + ".new", (time.time() + 5, time.time() + 5))
        os.rename(small + ".new", small)
        d.signal(signal.SIGHUP)
        deadline = time.time() + 20
        while time.time() < deadline and "replaced=1" not in d.log_text():
            time.sleep(0.05)
        check("replaced=1" in d.log_text(), "the reload replaced Small:\n" + d.log_text())
        t = loaded(d)
        check(abs(t - (time.time() + DAY)) < 60,
              "loaded after a step of a day: %.0f, the daemon's clock %.0f (a day behind: "
              "derived from the start)" % (t, time.time() + DAY))

        proc = run_load(LOAD_CLIENT, d.urls["unix"], "Small", 4, connections=2, inflight=2,
                        count=20)
        res = load_result(proc)
        check(res.get("status", {}).get("OK") == 20 and res.get("answered") == 20,
              "frames served after the step: %s" % res)
    finally:
        rc = d.stop()
        check(rc == 0, "stopped with 0 (%s)" % rc)
        cleanup(w)
    finish()


main()
