#!/usr/bin/env python3
"""The PCIe copy time of one frame's bytes, the floor of end-to-end time.

Times, with CUDA events, copies between pinned host memory and the GPU
through PyTorch: host-to-device of --in-bytes (the request's features) and
device-to-host of --out-bytes (its result), median of --iters after a
warm-up, on the first CUDA device. Prints one tab-separated line:
  PCIE in_bytes out_bytes h2d_ms d2h_ms h2d_GBps d2h_GBps
or `PCIE none <reason>` when PyTorch sees no GPU (a dry run).
"""
import argparse
import statistics
import sys


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--in-bytes", type=int, required=True)
    ap.add_argument("--out-bytes", type=int, required=True)
    ap.add_argument("--iters", type=int, default=20)
    a = ap.parse_args()
    try:
        import torch
    except ImportError as e:
        print(f"PCIE\tnone\tno torch: {e}")
        return 0
    if not torch.cuda.is_available():
        print("PCIE\tnone\tPyTorch sees no CUDA device")
        return 0
    host_in = torch.empty(a.in_bytes, dtype=torch.uint8).pin_memory()
    host_out = torch.empty(a.out_bytes, dtype=torch.uint8).pin_memory()
    host_in.random_(0, 255)   # not zeros
    dev_in = torch.empty(a.in_bytes, dtype=torch.uint8, device="cuda")
    dev_out = torch.empty(a.out_bytes, dtype=torch.uint8, device="cuda").random_(0, 255)

    def timed(fn):
        times = []
        for i in range(a.iters + 3):
            e0 = torch.cuda.Event(enable_timing=True)
            e1 = torch.cuda.Event(enable_timing=True)
            e0.record()
            fn()
            e1.record()
            e1.synchronize()
            if i >= 3:
                times.append(e0.elapsed_time(e1))
        return statistics.median(times)

    h2d = timed(lambda: dev_in.copy_(host_in, non_blocking=True))
    d2h = timed(lambda: host_out.copy_(dev_out, non_blocking=True))
    print(f"PCIE\t{a.in_bytes}\t{a.out_bytes}\t{h2d:.4f}\t{d2h:.4f}\t"
          f"{a.in_bytes / h2d / 1e6:.2f}\t{a.out_bytes / d2h / 1e6:.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
