#!/usr/bin/python3
"""PyTorch timings of the hairfilter network, for `hairfilter bench --torch`.

Runs weights/hfnet.py's HairNet on the given safetensors files (the same
weights the C backends ran) and prints one tab-separated ROW line per
(mode, variant, size, batch), timed like the C side: per iteration the wall
time of one forward pass of a batch (input already in memory, output
transforms and crop included), after warm-up; median and 90th percentile
over the iterations, divided by the batch.

Modes: on CPU, fp32 NCHW ("torch-cpu") and fp32 channels_last
("torch-cpu-cl"), with every core (torch.set_num_threads(os.cpu_count())).
On CUDA, fp16 channels_last with cudnn.benchmark, eager ("torch-cuda") and
replayed as a CUDA graph ("torch-cuda-graph").

Output line format (all on one line, tab-separated):
  ROW mode variant WxH batch precision median_ms p90_ms fps device_bytes iters cpu_ms
cpu_ms: the median of the process's CPU time per forward pass (every
thread's, time.process_time), divided by the batch.
"""
import argparse
import os
import sys
import time

import torch

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "weights"))
import hfnet  # noqa: E402


def parse_size(s):
    w, h = s.lower().split("x")
    return int(w), int(h)


def p90(sorted_vals):
    """Nearest rank, as the C side: the value at index ceil(0.9 n) - 1."""
    return sorted_vals[max(0, (9 * len(sorted_vals) + 9) // 10 - 1)]


def feature_input(cfg, batch, w, h, device, dtype, seed):
    """Feature-like values: colour, highlight, alpha, depth in [0, 1],
    tangents in [-1, 1], and for a configuration with an estimate its 3
    channels after them in [0, 1]; the values do not change the timing, but
    denormals or NaNs would, so they are kept in range."""
    spp = cfg["spp"]
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(batch, spp, len(hfnet.FEATURES), h, w, generator=g)
    x[:, :, 4:] = 2 * x[:, :, 4:] - 1
    x = x.view(batch, spp * len(hfnet.FEATURES), h, w)
    extra = cfg["in_channels"] - x.shape[1]
    if extra:
        x = torch.cat([x, torch.rand(batch, extra, h, w, generator=g)], 1)
    return x.to(device=device, dtype=dtype)


def time_loop(fn, iters, warmup, sync):
    """Sorted wall times of iters calls after warmup ones, and the median
    of their process CPU times."""
    for _ in range(warmup):
        fn()
    sync()
    times, cpu = [], []
    for _ in range(iters):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        sync()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return sorted(times), median(sorted(cpu))


def median(sorted_vals):
    n = len(sorted_vals)
    return sorted_vals[n // 2] if n % 2 else 0.5 * (sorted_vals[n // 2 - 1] + sorted_vals[n // 2])


def emit(mode, variant, w, h, batch, precision, timed, device_bytes, iters):
    times, cpu = timed
    med_ms = 1e3 * median(times) / batch
    p90_ms = 1e3 * p90(times) / batch
    fps = 1e3 / med_ms if med_ms > 0 else 0.0
    print(f"ROW\t{mode}\t{variant}\t{w}x{h}\t{batch}\t{precision}\t{med_ms:.3f}\t"
          f"{p90_ms:.3f}\t{fps:.2f}\t{device_bytes}\t{iters}\t{1e3 * cpu / batch:.3f}",
          flush=True)


def bench_cpu(net, cfg, sizes, batches, iters, warmup):
    for w, h in sizes:
        for b in batches:
            for mode, fmt in (("torch-cpu", torch.contiguous_format),
                              ("torch-cpu-cl", torch.channels_last)):
                m = net.to(memory_format=fmt)
                x = feature_input(cfg, b, w, h, "cpu", torch.float32, 1)
                x = x.contiguous(memory_format=fmt)
                with torch.inference_mode():
                    times = time_loop(lambda: m(x), iters, warmup, lambda: None)
                emit(mode, cfg["name"], w, h, b, "fp32", times, 0, iters)


def bench_cuda(net, cfg, sizes, batches, iters, warmup):
    torch.backends.cudnn.benchmark = True
    net = net.to("cuda", dtype=torch.float16, memory_format=torch.channels_last)
    sync = torch.cuda.synchronize
    for w, h in sizes:
        for b in batches:
            x = feature_input(cfg, b, w, h, "cuda", torch.float16, 1)
            x = x.contiguous(memory_format=torch.channels_last)
            with torch.inference_mode():
                torch.cuda.reset_peak_memory_stats()
                times = time_loop(lambda: net(x), iters, warmup, sync)
                emit("torch-cuda", cfg["name"], w, h, b, "fp16", times,
                     torch.cuda.max_memory_allocated(), iters)
                # CUDA graph: warm up on a side stream, capture once, replay.
                static_x = x.clone()
                s = torch.cuda.Stream()
                s.wait_stream(torch.cuda.current_stream())
                with torch.cuda.stream(s):
                    for _ in range(3):
                        net(static_x)
                torch.cuda.current_stream().wait_stream(s)
                graph = torch.cuda.CUDAGraph()
                with torch.cuda.graph(graph):
                    static_y = net(static_x)  # noqa: F841 (kept alive by the graph)
                times = time_loop(graph.replay, iters, warmup, sync)
                emit("torch-cuda-graph", cfg["name"], w, h, b, "fp16", times,
                     torch.cuda.max_memory_allocated(), iters)
                del graph, static_x


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("weights", nargs="+", help="safetensors files (one per variant)")
    ap.add_argument("--sizes", default="256x256,512x512,1024x1024")
    ap.add_argument("--batch", default="1")
    ap.add_argument("--iters", type=int, default=20)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    ap.add_argument("--labels", default="",
                    help="comma-separated variant column of each weights file, in order "
                    "(default: the variant name in the file)")
    ap.add_argument("--threads", type=int, default=os.cpu_count(),
                    help="CPU threads (default: every core)")
    a = ap.parse_args()
    if a.iters < 1 or a.warmup < 0:
        ap.error("--iters must be >= 1 and --warmup >= 0")
    torch.set_num_threads(a.threads)
    sizes = [parse_size(s) for s in a.sizes.split(",") if s]
    batches = [int(b) for b in a.batch.split(",") if b]
    if a.device == "cuda" and not torch.cuda.is_available():
        print("bench_torch: CUDA is not available to this PyTorch", file=sys.stderr)
        return 3
    print(f"INFO\ttorch {torch.__version__}, {torch.get_num_threads()} threads, "
          f"device {a.device}", flush=True)
    labels = a.labels.split(",") if a.labels else []
    if labels and len(labels) != len(a.weights):
        ap.error(f"--labels has {len(labels)} labels for {len(a.weights)} weights files")
    for i, path in enumerate(a.weights):
        cfg, sd = hfnet.load_safetensors(path)
        if labels:
            cfg["name"] = labels[i]
        net = hfnet.HairNet(cfg)
        net.load_state_dict(sd)
        net.eval()
        if a.device == "cuda":
            bench_cuda(net, cfg, sizes, batches, a.iters, a.warmup)
        else:
            bench_cpu(net, cfg, sizes, batches, a.iters, a.warmup)
    return 0


if __name__ == "__main__":
    sys.exit(main())
