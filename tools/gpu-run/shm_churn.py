#!/usr/bin/env python3
"""One client that creates and destroys shared-memory segments in a loop,
so that each creation makes hairfilterd pin a segment (cudaHostRegister
with the cudnn backend, milliseconds each): run beside `hairfilter-load`,
the load's latencies say whether other connections wait for the pinning
(docs/GPU.md, "What the next GPU run must show").

    shm_churn.py unix:/path/to.sock --mib 192 --seconds 4

Prints one tab-separated line:
  CHURN segments mib seconds create_p50_ms create_max_ms
"""
import argparse
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)),
                                "..", "..", "client", "python"))
from hairfilter.client import Client  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("server", help="unix:PATH of hairfilterd")
    ap.add_argument("--mib", type=int, default=192, help="segment size")
    ap.add_argument("--seconds", type=float, default=4.0)
    a = ap.parse_args()
    times = []
    with Client(a.server, client_name="shm-churn") as c:
        end = time.monotonic() + a.seconds
        while time.monotonic() < end:
            t0 = time.monotonic()
            seg = c.shared_memory(a.mib << 20)
            times.append((time.monotonic() - t0) * 1e3)
            seg.close()
    if not times:
        print("CHURN\t0\t%d\t%.1f\t-\t-" % (a.mib, a.seconds))
        return 0
    print("CHURN\t%d\t%d\t%.1f\t%.3f\t%.3f" % (len(times), a.mib, a.seconds,
                                            statistics.median(times), max(times)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
