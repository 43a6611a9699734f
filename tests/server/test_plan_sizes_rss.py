#!/usr/bin/env python3
"""Frames of many sizes do not grow the daemon past what it counts.

The cpu backend keeps a plan per frame size, counted in --max-memory-mb and
freed when the budget needs the room. oneDNN kept each plan's primitives and
their generated code in a cache of its own (1024 entries) after the plan was
freed: a client sending frames of ever new sizes took a daemon under
--max-memory-mb 48 from 25 to 85 MiB resident over 1500 sizes while its
/metrics counted 8 MiB of plans. The backend now bounds that cache
(src/backend_cpu_onednn.c, od_primitive_cache_bound): resident memory levels
off once it is full. Here, 900 sizes of Small: the growth from the 300th to
the 900th size is held under 8 MiB (2-core AMD EPYC, 2026-12-07: 3.2 MiB
bounded; 34.7 MiB with HF_TEST_ONEDNN_CACHE=1024).

usage: test_plan_sizes_rss.py HAIRFILTERD WEIGHTS_DIR [SANITIZERS]

HF_TEST_BACKEND (default cpu) runs the daemon on another backend and
HF_TEST_SIZES (default 900) sends that many sizes, measured from the
third: on a GPU machine, `HF_TEST_BACKEND=cudnn HF_TEST_SIZES=150` asks
the same of what cuDNN keeps (docs/GPU.md, "What the next GPU run must
show"). HF_TEST_ONEDNN_CACHE=N gives the daemon
ONEDNN_PRIMITIVE_CACHE_CAPACITY=N, to measure another size of that cache
(1024, oneDNN's default, fails the test).

With SANITIZERS (the tree's HF_SANITIZE) the test is skipped (status 77):
AddressSanitizer keeps freed memory in its quarantine, so resident memory
says nothing of what the daemon keeps.
"""
import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..",
                                "client", "python"))
import hairfilter  # noqa: E402
from rawwire import check, finish, require_started, start, stop  # noqa: E402

SIZES = int(os.environ.get("HF_TEST_SIZES", "900"))
FIRST = SIZES // 3   # at 900, oneDNN's cache is full by then, bounded or not at 1024
GROWTH_MIB = 8       # allowed from FIRST to SIZES (cpu, 900: bounded 3.2; at 1024 34.7)
BACKEND = os.environ.get("HF_TEST_BACKEND", "cpu")


def rss_kib(pid):
    """The process's resident set (VmRSS) in KiB."""
    with open("/proc/%d/status" % pid) as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise RuntimeError("no VmRSS for %d" % pid)


def main():
    hairfilterd, weights = sys.argv[1:3]
    if len(sys.argv) > 3 and sys.argv[3]:
        print("skipped: built with -fsanitize=%s, whose allocator keeps freed memory resident"
              % sys.argv[3])
        sys.exit(77)
    w = tempfile.mkdtemp(prefix="hfplans-")
    env = dict(os.environ)
    # The operator's setting would be kept by the backend: this test is of
    # the default.
    env.pop("ONEDNN_PRIMITIVE_CACHE_CAPACITY", None)
    env.pop("DNNL_PRIMITIVE_CACHE_CAPACITY", None)
    if os.environ.get("HF_TEST_ONEDNN_CACHE"):
        env["ONEDNN_PRIMITIVE_CACHE_CAPACITY"] = os.environ["HF_TEST_ONEDNN_CACHE"]
    proc, sock = start(hairfilterd, w, ["--weights", os.path.join(weights, "small.safetensors"),
                                        "--max-memory-mb", "48", "--backend", BACKEND], env=env)
    try:
        require_started(sock)
        rng = np.random.default_rng(1)
        at_first = None
        with hairfilter.Client("unix:" + sock, timeout=60) as hf:
            n = 0
            for h in range(24, 200):
                for wd in range(24, 200, 7):
                    if n == SIZES:
                        break
                    f = rng.random((h, wd, 24), dtype=np.float32)
                    f[..., 2::6] = (f[..., 2::6] > 0.5) * 0.5   # alpha of the covered samples
                    hf.filter("Small", f)
                    n += 1
                    if n == FIRST:
                        at_first = rss_kib(proc.pid)
            at_end = rss_kib(proc.pid)
        grew = (at_end - at_first) / 1024
        print("%s backend, resident memory: %.1f MiB after %d sizes, %.1f MiB after %d "
              "(grew %.1f MiB)" % (BACKEND, at_first / 1024, FIRST, at_end / 1024, n, grew))
        check(n == SIZES, "%d sizes sent, %d meant" % (n, SIZES))
        check(grew < GROWTH_MIB,
              "resident memory grew %.1f MiB from the %dth to the %dth frame size (at most %d): "
              "something outside the budget keeps what each size made" % (grew, FIRST, n,
                                                                         GROWTH_MIB))
    finally:
        stop(proc, w)
    finish()


if __name__ == "__main__":
    main()
