#!/usr/bin/env python3
"""/metrics and SIGUSR1 after a drain has answered every frame, while the
daemon waits for clients to read their replies (--flush-timeout-ms): the
variants' request counters are still there, with every frame counted. The
worker had stopped and unloaded the models, and every per-variant series
(requests_total, the histograms, ...) vanished from the scrapes of that
window, and the statistics line with them.

usage: test_metrics_flush.py HAIRFILTERD WEIGHTS.safetensors
"""
import os
import signal
import struct
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from opsdaemon import Daemon, check, cleanup, finish, sample, workdir  # noqa: E402
from rawwire import FILTER, connect, frame  # noqa: E402

HAIRFILTERD, WEIGHTS = sys.argv[1:3]


def small_filter(rid, w, h):
    """A FILTER of Small (4 spp) of w x h, f32, its features all 0.25."""
    fixed = struct.pack("<HHIIHBB", 5, 0, w, h, 4, 0, 0) + struct.pack("<9f", *[0.5] * 9)
    return frame(FILTER, fixed + b"Small" + struct.pack("<f", 0.25) * (w * h * 4 * 6), rid)


def main():
    w = workdir()
    d = Daemon(HAIRFILTERD, ["--config", "none", "--listen", "unix:%s/s.sock" % w,
                             "--http", "tcp:127.0.0.1:0", "--backend", "cpu-ref",
                             "--weights", WEIGHTS, "--flush-timeout-ms", "20000"], w)
    s = None
    try:
        s = connect(d.urls["unix"].split(":", 1)[1])
        # Replies this client leaves unread: a small RESULT, written whole
        # into its socket and counted, then two of 256x256 (768 KiB each)
        # that fill it, so the daemon waits in the flush.
        s.sendall(small_filter(1, 16, 16))
        for rid in (2, 3):
            s.sendall(small_filter(rid, 256, 256))
        samples, _ = d.settled_metrics(
            [("hairfilterd_requests_total", {"variant": "Small", "status": "ok",
                                             "class": "ok"}, 1)], timeout=30)
        d.signal(signal.SIGTERM)
        # Every frame answered, the worker stopped: the daemon now only
        # waits for this client to read.
        deadline = time.time() + 30
        while time.time() < deadline and d.get("/metrics")[0] == 200:
            samples, text = d.metrics()
            if sample(samples, "hairfilterd_requests_in_flight") == 0:
                break
            time.sleep(0.05)
        time.sleep(0.5)
        samples, text = d.metrics()
        check(sample(samples, "hairfilterd_draining") == 1, "scraped while draining")
        check(sample(samples, "hairfilterd_requests_in_flight") == 0,
              "every frame answered when scraped")
        ok = sample(samples, "hairfilterd_requests_total",
                    **{"variant": "Small", "status": "ok", "class": "ok"})
        check(ok is not None and ok >= 1,
              "requests_total of Small still scraped in the flush (%s):\n%s" % (ok, text))
        check("hairfilterd_request_duration_seconds_count{variant=\"Small\"}" in text,
              "Small's histograms still scraped in the flush")
        d.signal(signal.SIGUSR1)
        deadline = time.time() + 10
        while time.time() < deadline and "statistics: variant=Small" not in d.log_text():
            time.sleep(0.05)
        check("statistics: variant=Small" in d.log_text(),
              "SIGUSR1 in the flush logs Small's line:\n" + d.log_text())
    finally:
        if s is not None:
            s.close()
        rc = d.stop()
        check(rc == 0, "stopped with 0 (%s)" % rc)
        cleanup(w)
    finish()


main()
