#!/usr/bin/env python3
"""Summary of a one-call GPU run (tools/gpu-run/run.sh): reads the step logs
in LOGDIR and prints what the run answered, section by section, then the
performance goals (Base at 1024x1024 on an H100 or H200) computed from the
same numbers, then what the next GPU run must still show (the section of
docs/GPU.md). Missing logs are reported as
missing, never guessed.

usage: summarize.py LOGDIR ROOT
"""
import collections
import glob
import os
import re
import sys


def read(logdir, name):
    try:
        with open(os.path.join(logdir, name), errors="replace") as f:
            return f.read()
    except OSError:
        return None


def section(title):
    print()
    print(f"== {title}")


def table_rows(text):
    """The bench table's data rows, as lists of cells."""
    rows = []
    for line in (text or "").splitlines():
        if line.startswith("| ") and not line.startswith("| backend") and "---" not in line:
            rows.append([c.strip() for c in line.strip().strip("|").split("|")])
    return rows


def find_row(rows, backend, size, batch):
    for r in rows:
        if len(r) > 6 and r[0] == backend and r[2] == size and r[3] == str(batch):
            return r
    return None


def load_report(text):
    """hairfilter load's header, throughput line and percentile table
    (p50, p90, p99, p99.9, max per field)."""
    if not text:
        return None, {}
    lines = [l for l in text.splitlines() if l.strip()]
    pct = {}
    for l in lines:
        # p50 p90 p95 p99 p99.9 max (before p95 was added: p50 p90 p99 p99.9 max)
        m = re.match(r"\s+(\w+)((?:\s+[0-9.]+){5,6})$", l)
        if m:
            v = [float(x) for x in m.group(2).split()]
            pct[m.group(1)] = v if len(v) == 5 else v[:2] + v[3:]
    return lines, pct


def main():
    if len(sys.argv) != 3:
        print(__doc__)
        return 2
    logdir, root = sys.argv[1], sys.argv[2]
    print("hairfilter: one-call GPU run, summary")

    section("steps (exit status, wall time)")
    print(read(logdir, "steps.txt") or "no steps.txt")

    section("machine and libraries")
    env = read(logdir, "env.log")
    if env:
        for l in env.splitlines():
            if l.startswith(("backend ", "commit ", "built ", "name,", "torch ", "ldd ", "  cudnn",
                             "  auto")) or "NVIDIA" in l or "cudnn unavailable" in l:
                print("  " + l.strip())
    else:
        print("  no env.log")

    section("descriptors: every layer graph through cuDNN (test_cudnn_graph)")
    g = read(logdir, "graph.log")
    print("\n".join("  " + l for l in (g or "no graph.log").splitlines()
                    if l.startswith(("cuDNN", "FAIL", "PASSED", "SKIP", "total")) or "graphs built" in l))
    k = read(logdir, "kernels_host.log")
    print("  element-wise kernels on the CPU: " +
          ("PASSED" if k and "PASSED" in k else "see kernels_host.log" if k else "not run"))

    section("correctness against cpu-ref on the GPU (test_cudnn_backend device)")
    d = read(logdir, "device.log")
    if d is None:
        print("  not run (no GPU, or the deadline)")
    else:
        rels = [float(x) for x in re.findall(r"rel(?:ative)? L2 ([0-9.e+-]+)", d)]
        nan = len(re.findall(r"nan|inf", d, re.I))
        same = d.count("bit-identical")
        differ = d.count("differs")
        print(f"  {len(rels)} comparisons, worst relative L2 "
              f"{max(rels):.2e}" if rels else "  no comparison completed")
        print(f"  second runs: {same} bit-identical, {differ} differing (within 1e-4)")
        worst = {}
        for m in re.finditer(r"^\s+(\w+)\s+batch (\d+)\s+(\d+x\d+)\s+rel L2 ([0-9.e+-]+)", d, re.M):
            v, rel = m.group(1), float(m.group(4))
            n, w = worst.get(v, (0, 0.0))
            worst[v] = (n + 1, max(w, rel))
        for v, (n, w) in worst.items():
            print(f"  {v}: {n} comparisons (presets), worst relative L2 {w:.2e}")
        for l in d.splitlines():
            if l.strip().startswith("segment "):   # what pinning a segment costs
                print("  " + l.strip())
        for l in d.splitlines():
            if re.search(r"\[  (PASSED|FAILED|  OK|  ERROR|  SKIPPED) |\[==========\]|FAILED|"
                         r"Failure|SKIP:|error", l):
                print("  " + l.strip())
        if nan:
            print(f"  lines mentioning NaN/Inf: {nan} (see device.log)")

    section(f"plans of Base (bench, HF_CUDNN_VERBOSE): form and engine per layer")
    b = read(logdir, "bench.log")
    if b:
        for l in b.splitlines():
            if re.search(r"hfcore cudnn: (plan |[a-z]+[0-9]+: form |.*capture failed|.*unavailable|"
                         r".*no engine)", l) or l.startswith("hairfilter: using"):
                print("  " + l.replace("hfcore cudnn: ", ""))
    else:
        print("  no bench.log")

    section("in-process timings (hairfilter bench; ms per frame; net = CUDA events)")
    rows = []
    for name in ["bench", "bench_f16", "bench_pipe", "bench_pipe_f32", "bench_kernel_ac",
                 "bench_pinned_f16", "bench_pinned_f16_hostcheck"] + \
            [f"form_{f}" for f in ("bwd-data", "d2s", "phase", "shuffle")]:
        t = read(logdir, name + ".log")
        r = table_rows(t)
        if name.startswith("form_"):
            for x in r:
                x[0] = f"{x[0]} ({name[5:]})"
        if name.endswith("_hostcheck"):
            for x in r:
                x[0] = f"{x[0]} (input checked on the host)"
        rows += r
        if t is not None and not r:
            print(f"  {name}: no table (see {name}.log)")
    if rows:
        print("  | backend | variant | size | batch | precision | median | p90 | in / net / out |"
              " frames/s | device MiB |")
        for r in rows:
            print("  | " + " | ".join(r[:10]) + " |")

    section("host work on the input (bench --input-stats --input-check; ms per frame)")
    h = read(logdir, "host_input.log")
    if h is None:
        print("  not run")
    else:
        # The tables after bench's own (their header rows start "| size").
        tables = [l for l in h.splitlines() if l.startswith("| ") and not l.startswith("| backend")
                  and not (l.startswith("| cpu") or l.startswith("| cudnn"))]
        print("\n".join("  " + l for l in tables) if tables else "  no table (see host_input.log)")

    section("end to end through hairfilterd (hairfilter-load; p50 ms, total also p99)")
    loads = {}
    for f in sorted(glob.glob(os.path.join(logdir, "load_*.log"))):
        name = os.path.basename(f)[5:-4]
        lines, pct = load_report(read(logdir, os.path.basename(f)))
        loads[name] = pct
        head = next((l for l in lines or [] if " via " in l), "")
        m = re.search(r"\(([^)]*)\): (?:closed loop, )?(\d+) connection\(s\) x (\d+) in flight", head)
        tp = next((re.search(r"throughput ([0-9.]+)", l).group(1) for l in lines or []
                   if "throughput" in l), "?")
        if "total" not in pct:
            print(f"  {name:24s} no result (see load_{name}.log)")
            continue
        p = {k: v[0] for k, v in pct.items()}
        print(f"  {name:24s} {tp:>8s} frames/s  total {p['total']:9.3f} (p99 {pct['total'][2]:.3f})"
              f"  server {p.get('server', 0):.3f}  queue {p.get('queue', 0):.3f}"
              f"  input {p.get('input', 0):.3f}  infer {p.get('infer', 0):.3f}"
              f"  output {p.get('output', 0):.3f}" + (f"  [{m.group(1)}]" if m else ""))

    churn = read(logdir, "shm_churn.log")
    if churn is not None:
        line = next((l for l in churn.splitlines() if l.startswith("CHURN")), None)
        if line:
            f = line.split("\t")
            print(f"  beside shm_f16_churn: {f[1]} segments of {f[2]} MiB created and destroyed in "
                  f"{f[3]} s, creation p50 {f[4]} ms, max {f[5]} ms")
        else:
            print("  shm_churn: no result (see shm_churn.log)")

    section("PCIe floor (pinned copies of one frame's bytes, CUDA events)")
    pcie = {}
    for name in ("pcie_f16", "pcie_f32"):
        t = read(logdir, name + ".log") or ""
        m = re.search(r"PCIE\t(\d+)\t(\d+)\t([0-9.]+)\t([0-9.]+)\t([0-9.]+)\t([0-9.]+)", t)
        if m:
            pcie[name] = (float(m.group(3)), float(m.group(4)))
            print(f"  {name}: in {int(m.group(1)) / 1e6:.1f} MB {m.group(3)} ms ({m.group(5)} GB/s), "
                  f"out {int(m.group(2)) / 1e6:.1f} MB {m.group(4)} ms ({m.group(6)} GB/s)")
        else:
            print(f"  {name}: " + (t.strip().replace("\t", " ") or "not run"))

    section("goals (H100/H200, Base at 1024x1024)")
    brows = table_rows(read(logdir, "bench.log"))
    size = None
    for r in brows:
        if r[0] == "cudnn":
            size = r[2]
            break
    ours = find_row(brows, "cudnn", size, 1) if size else None
    torch_eager = find_row(brows, "torch-cuda", size, 1) if size else None
    torch_graph = find_row(brows, "torch-cuda-graph", size, 1) if size else None
    net = None
    if ours:
        try:
            net = float(ours[7].split("/")[1])
        except (ValueError, IndexError):
            pass
    if net is not None:
        print(f"  network GPU time, {size} batch 1: {net:.3f} ms (goal <= 0.25 ms): "
              f"{'met' if net <= 0.25 else 'NOT met'}")
    else:
        print("  network GPU time: no cudnn row")
    for label, t in (("PyTorch eager fp16", torch_eager), ("PyTorch CUDA graph fp16", torch_graph)):
        if t and net:
            tm = float(t[5])
            print(f"  {label}: {tm:.3f} ms per frame (network, output transforms and crop, input "
                  f"on the GPU); cudnn network alone is {tm / net:.2f}x as fast"
                  + (" (goal >= 2x: " + ("met" if tm / net >= 2 else "NOT met") + ")"
                     if "eager" in label else ""))
        elif not t:
            print(f"  {label}: no row")
    shm = loads.get("shm_f16", {}).get("total")
    floor = pcie.get("pcie_f16")
    if shm and floor:
        f = floor[0] + floor[1]
        print(f"  end to end, shared memory, f16 I/O, one in flight: p50 {shm[0]:.3f} ms against "
              f"{f:.3f} ms of PCIe copies ({shm[0] / f:.2f}x; goal <= 1.5x: "
              f"{'met' if shm[0] / f <= 1.5 else 'NOT met'})")
    else:
        print("  end to end against PCIe: " + ("no shm_f16 load" if not shm else "no PCIe figure"))

    section("cuDNN errors and warnings (CUDNN_LOGLEVEL_DBG=2), by message")
    msgs = collections.Counter()
    for f in glob.glob(os.path.join(logdir, "cudnn_*.log")):
        with open(f, errors="replace") as fh:
            for l in fh:
                m = re.match(r"\s*[ew]! +(Error|Warning): (.*)", l)
                if m:
                    msgs[f"{m.group(1)}: {m.group(2).strip()[:160]}"] += 1
    for m, n in msgs.most_common(20):
        print(f"  {n:6d}  {m}")
    if not msgs:
        print("  none logged")

    section("what the next GPU run must still show (docs/GPU.md)")
    try:
        with open(os.path.join(root, "docs", "GPU.md")) as f:
            doc = f.read()
        m = re.search(r"^## What the next GPU run must show\n(.*?)(?=^## |\Z)", doc, re.M | re.S)
        print(m.group(1).strip() if m else "  (section missing from docs/GPU.md)")
    except OSError as e:
        print(f"  {e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
