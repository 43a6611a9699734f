#!/bin/bash
# The one-call GPU run: everything one lease of a GPU machine must answer
# about the cudnn backend, time-boxed, in one command (docs/GPU.md, "The
# one-call GPU run"). On this machine first:
#
#   tools/gpu-run/pack.sh                                   # builds .gpu-carry/
#
# then, through the device tool, from the repository root:
#
#   run  command: bash tools/gpu-run/run.sh    carry: [".gpu-carry"]    timeout_s: 600
#
# Dry run anywhere, against the CPU reference (small frames, PyTorch on CPU):
#
#   BACKEND=cpu-ref BIG=64x64 tools/gpu-run/run.sh
#
# Every step has a time cap and may fail; the next one runs anyway, and
# steps that no longer fit before DEADLINE (seconds, default 450) are
# skipped. Nothing else waits without a bound either: a daemon gets until
# DEADLINE to be ready and STOP_GRACE seconds (default 15) to stop on
# SIGTERM before it is killed, so the run ends near DEADLINE and packs its
# results itself (the device tool kills a command that outlives its limit,
# and then nothing is packed). Whatever happens, $OUT (default ./gpu-out) gets summary.txt (also
# printed last), logs.tgz (every step's output) and devprop.json (cuDNN's
# description of the device, for tests/data/cudnn/). The last thing printed
# is what the next run must still show.
set -u
cd "$(dirname "$0")/../.."
ROOT=$PWD
OUT=${OUT:-$ROOT/gpu-out}
BACKEND=${BACKEND:-cudnn}
BIG=${BIG:-1024x1024}
DEADLINE=${DEADLINE:-450}
CARRY=${CARRY:-$ROOT/.gpu-carry}
# pack.sh packs the binaries and libraries into carry.tar.xz: unpacked here
# into a folder of our own, beside the MANIFEST.
if [ -f "$CARRY/carry.tar.xz" ]; then
  X=$(mktemp -d)
  tar -xJf "$CARRY/carry.tar.xz" -C "$X" 2>/dev/null ||
    python3 -c 'import sys, tarfile; tarfile.open(sys.argv[1]).extractall(sys.argv[2])' \
      "$CARRY/carry.tar.xz" "$X"
  cp "$CARRY/MANIFEST" "$X/" 2>/dev/null
  CARRY=$X
fi
B=$CARRY/bin
WEIGHTS=$ROOT/weights/base.safetensors
mkdir -p "$OUT"
R=$(mktemp -d)
START=$(date +%s)
export PYTHONUNBUFFERED=1
PY=python3   # the Python with PyTorch, found below

if [ "$BACKEND" = cudnn ]; then TDEV=cuda; else TDEV=cpu; fi
# Load seconds per measurement; a dry run on cpu-ref needs fewer.
SECS=${SECS:-4}

left() { echo $((DEADLINE - ($(date +%s) - START))); }

# step NAME CAP CMD...: runs CMD with stdout+stderr to $R/NAME.log, at most
# CAP seconds (less when the deadline is nearer); rc and wall time go to
# $R/steps.txt.
step() {
  local name=$1 cap=$2
  shift 2
  local l
  l=$(left)
  if [ "$l" -lt 10 ]; then
    printf '%-22s skipped (deadline)\n' "$name" >> "$R/steps.txt"
    return
  fi
  [ "$cap" -gt "$l" ] && cap=$l
  local t0
  t0=$(date +%s%N)
  echo "== $name ($(date -u +%H:%M:%S), cap ${cap}s)"
  timeout -k 5 "$cap" "$@" > "$R/$name.log" 2>&1
  local rc=$?
  local ms=$((($(date +%s%N) - t0) / 1000000))
  printf '%-22s rc=%-4s %7s s%s\n' "$name" "$rc" "$(awk -v t="$ms" 'BEGIN {printf "%.1f", t / 1000}')" \
    "$([ "$rc" = 124 ] || [ "$rc" = 137 ] && echo '  (timed out)')" >> "$R/steps.txt"
}

# Packs whatever there is, whenever the script ends.
pack() {
  trap - EXIT
  # Daemons a stopped run left behind would go on writing their logs.
  for f in "$R"/*.pid; do [ -f "$f" ] && kill -KILL "$(cat "$f")" 2>/dev/null; done
  "$PY" "$ROOT/tools/gpu-run/summarize.py" "$R" "$ROOT" > "$OUT/summary.txt" 2>&1 ||
    echo "summarize.py failed" >> "$OUT/summary.txt"
  [ -f "$R/devprop.json" ] && cp "$R/devprop.json" "$OUT/"
  for f in "$R"/cudnn_*.log; do
    [ -f "$f" ] && tail -c 4M "$f" > "$f.tail" && mv "$f.tail" "$f"
  done
  tar czf "$OUT/logs.tgz" -C "$R" --exclude='*.sock' . 2>/dev/null
  # The device tool brings back no file over 16 MiB: rather every log's
  # last MiB than no log at all.
  if [ "$(stat -c %s "$OUT/logs.tgz" 2>/dev/null || echo 0)" -gt $((15 << 20)) ]; then
    for f in "$R"/*.log; do
      [ -f "$f" ] && tail -c 1M "$f" > "$f.tail" && mv "$f.tail" "$f"
    done
    tar czf "$OUT/logs.tgz" -C "$R" --exclude='*.sock' . 2>/dev/null
    echo "logs.tgz was over 15 MiB, more than the device tool brings back: every log in it" \
      "is cut to its last MiB" >> "$OUT/summary.txt"
  fi
  cat "$OUT/summary.txt"
  rm -rf "$R"
}
trap pack EXIT

# ---- 0. environment: the device, the libraries found, the binaries -----------
# The Python with PyTorch: $PYTHON, else the first of python3 and
# /usr/bin/python3 that imports torch (on the GPU machine, python3).
for p in ${PYTHON:-} python3 /usr/bin/python3; do
  if timeout 60 "$p" -c 'import torch' > /dev/null 2>&1; then PY=$p; break; fi
done
# cuDNN, NVRTC and cuBLASLt come from that Python's packages (CUDA 13
# wheels keep NVRTC and cuBLAS in nvidia/cu13/lib, cuDNN in
# nvidia/cudnn/lib); the carried libraries come after them.
LIBS=$("$PY" - <<'PY'
import glob, os, site, sys
roots = [p for p in dict.fromkeys(site.getsitepackages() + sys.path) if p and os.path.isdir(p)]
dirs = []
for r in roots:
    for pat in ("libcudnn.so.9*", "libnvrtc.so.*", "libnvrtc-builtins.so.*", "libcublasLt.so.*"):
        for f in glob.glob(os.path.join(r, "nvidia", "*", "lib", pat)):
            if os.path.dirname(f) not in dirs:
                dirs.append(os.path.dirname(f))
print(":".join(dirs))
PY
)
export LD_LIBRARY_PATH="${LIBS}${LIBS:+:}$CARRY/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
env_report() {
  echo "backend $BACKEND, frames $BIG, deadline ${DEADLINE}s, started $(date -u +%Y-%m-%dT%H:%M:%SZ)"
  echo "python $PY"
  echo "LD_LIBRARY_PATH=$LD_LIBRARY_PATH"
  cat "$CARRY/MANIFEST" 2>/dev/null || echo "no $CARRY/MANIFEST: run tools/gpu-run/pack.sh first"
  timeout 20 nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm,clocks.sm,pcie.link.gen.current,pcie.link.width.current --format=csv 2>&1
  lscpu | sed -n 's/^Model name: *//p'
  nproc
  for d in ${LIBS//:/ }; do echo "$d: $(ls "$d" | grep -E 'cudnn|nvrtc|cublas' | tr '\n' ' ')"; done
  for b in "$B"/*; do
    echo "ldd $(basename "$b"): $(ldd "$b" | grep -E 'not found|cudnn|cudart|libcuda\.' | tr -s ' \t' ' ' | tr '\n' ';')"
  done
  timeout 60 "$PY" -c 'import torch; print("torch", torch.__version__, "cuda", torch.version.cuda, "cudnn", torch.backends.cudnn.version(), "device", torch.cuda.get_device_name(0) if torch.cuda.is_available() else "none")'
  # The backend's own account of the device and the cuDNN found at run
  # time (cudnnGetVersion), or why it cannot run.
  timeout 60 "$B/test_cudnn_backend" fallback
}
# A shell function, so not through step (timeout runs programs): each
# command in it has its own cap.
env_report > "$R/env.log" 2>&1
printf '%-22s rc=%-4s\n' env $? >> "$R/steps.txt"

# ---- 1. cuDNN's description of this device; every layer graph against it ------
if [ "$BACKEND" = cudnn ]; then
  step devprop 30 "$B/test_cudnn_backend" devprop "$R/devprop.json"
fi
DP=$R/devprop.json
[ -s "$DP" ] || DP=$ROOT/tests/data/cudnn/sm90.json
step graph 90 "$B/test_cudnn_graph" "$DP"
step kernels_host 30 "$B/test_cudnn_kernels"

# ---- 2. in-process: Base at BIG through hf_model_run, and PyTorch -------------
# The plan log (HF_CUDNN_VERBOSE) says which form and engine each layer got,
# with notes, finalize and tuned times, and how long the plan took to build.
BENCH=("$B/hairfilter" bench --backend "$BACKEND" --variants Base --sizes "$BIG")
step bench 180 env HF_CUDNN_VERBOSE=1 CUDNN_LOGLEVEL_DBG=2 CUDNN_LOGDEST_DBG="$R/cudnn_bench.log" \
  "${BENCH[@]}" --batch 1,4 --iters 30 --warmup 3 --torch --torch-device "$TDEV" --python "$PY"
step bench_f16 90 "${BENCH[@]}" --batch 1 --iters 30 --warmup 3 --io f16
step bench_pipe 90 "${BENCH[@]}" --batch 1 --iters 30 --warmup 3 --io f16 --pipeline
step bench_pipe_f32 90 "${BENCH[@]}" --batch 1 --iters 30 --warmup 3 --pipeline
# The default variant, KernelMix (Kernel reading the alpha-corrected estimate:
# 27 input channels, its frames interleaved on the host; its kernel weighs both
# sums), beside KernelAC and Kernel.
step bench_kernel_ac 90 "$B/hairfilter" bench --backend "$BACKEND" --sizes "$BIG" --batch 1 \
  --iters 20 --warmup 3 \
  --weights "$ROOT/weights/kernel_mix.safetensors,$ROOT/weights/kernel_ac.safetensors,$ROOT/weights/kernel.safetensors"

# The host's work on a frame's input, which the runs so far found to be most
# of the end-to-end time: the input statistics, the out-of-contract check and
# the threaded pass that does both in hf_model_run, each beside a memcpy of
# the same frame, FP32 and FP16 (docs/PERFORMANCE.md "Input statistics",
# "Data checks").
step host_input 90 "${BENCH[@]}" --batch 1 --iters 20 --warmup 2 --input-stats --input-check
# Frames in registered memory, in process: uploaded by DMA and checked on the
# device, beside the same with the check on the host's cores.
step bench_pinned_f16 60 "${BENCH[@]}" --batch 1 --iters 30 --warmup 3 --io f16 --pinned
step bench_pinned_f16_hostcheck 60 env HF_CUDNN_HOST_CHECK=1 "${BENCH[@]}" --batch 1 --iters 30 \
  --warmup 3 --io f16 --pinned

# ---- 3. end to end: hairfilterd over the Unix socket and shared memory --------
# serve TAG [VAR=value...] [-- daemon options]: hairfilterd with $WEIGHTS (Base) on
# $R/TAG.sock, the plan for BIG built before it is ready. Batch 1: two
# frames in flight then measure the two request slots (pipelining), not a
# batch of two (batches are timed in process by bench).
serve() {
  local tag=$1
  shift
  local envs=() opts=()
  while [ $# -gt 0 ] && [ "$1" != -- ]; do envs+=("$1"); shift; done
  [ $# -gt 0 ] && shift
  opts=("$@")
  env HF_CUDNN_VERBOSE=1 CUDNN_LOGLEVEL_DBG=2 CUDNN_LOGDEST_DBG="$R/cudnn_$tag.log" "${envs[@]}" \
    "$B/hairfilterd" --listen "unix:$R/$tag.sock" --weights "$WEIGHTS" --backend "$BACKEND" \
    --max-batch 1 --warm "$BIG" --ready-file "$R/$tag.ready" "${opts[@]}" \
    > "$R/server_$tag.log" 2>&1 &
  echo $! > "$R/$tag.pid"
  # Up to 120 s for the warmed plan, never past the deadline.
  local waited=0 most=240
  [ $((2 * ($(left) - 10))) -lt $most ] && most=$((2 * ($(left) - 10)))
  while [ ! -s "$R/$tag.ready" ]; do
    sleep 0.5
    waited=$((waited + 1))
    if ! kill -0 "$(cat "$R/$tag.pid")" 2>/dev/null || [ $waited -gt $most ]; then
      echo "server $tag did not become ready" >> "$R/steps.txt"
      stop "$tag"
      return 1
    fi
  done
  printf '%-22s ready after %s s\n' "server_$tag" "$(awk -v t="$waited" 'BEGIN {printf "%.1f", t / 2}')" >> "$R/steps.txt"
}
# stop TAG: SIGTERM, then SIGKILL after STOP_GRACE seconds: a daemon that
# hangs on its way out is a finding, and must not hold up the steps after it.
stop() {
  local pid
  pid=$(cat "$R/$1.pid")
  kill "$pid" 2>/dev/null
  local i=0
  while kill -0 "$pid" 2>/dev/null && [ $i -lt $((4 * ${STOP_GRACE:-15})) ]; do
    sleep 0.25
    i=$((i + 1))
  done
  if kill -0 "$pid" 2>/dev/null; then
    printf '%-22s did not stop in %s s after SIGTERM: killed\n' "server_$1" "${STOP_GRACE:-15}" \
      >> "$R/steps.txt"
    kill -KILL "$pid" 2>/dev/null
  fi
  wait "$pid" 2>/dev/null
  rm -f "$R/$1.pid"
}
load() {  # load NAME TAG [hairfilter-load options]
  local name=$1 tag=$2
  shift 2
  step "$name" 40 "$B/hairfilter-load" --server "unix:$R/$tag.sock" --variant "${VARIANT:-Base}" \
    --size "$BIG" \
    --seconds "$SECS" --warmup 1 "$@"
}
if [ "$(left)" -gt 120 ] && serve e2e; then
  load load_sock_f32 e2e
  load load_sock_f16 e2e --f16
  load load_shm_f32 e2e --shm
  load load_shm_f16 e2e --shm --f16
  load load_shm_f16_k2 e2e --shm --f16 --inflight 2
  load load_shm_f32_k2 e2e --shm --inflight 2
  # The same as load_shm_f16 beside a client that creates and destroys
  # 192 MiB segments in a loop, each pinned off the event loop: its p99
  # against load_shm_f16's says whether other connections wait for it.
  timeout -k 5 $((SECS + 40)) "$PY" "$ROOT/tools/gpu-run/shm_churn.py" "unix:$R/e2e.sock" \
    --mib 192 --seconds $((SECS + 2)) > "$R/shm_churn.log" 2>&1 &
  CHURN_PID=$!
  load load_shm_f16_churn e2e --shm --f16
  wait "$CHURN_PID"
  stop e2e
fi
# KernelAC end to end: the estimate on the wire (protocol version 3).
if [ "$(left)" -gt 100 ] && WEIGHTS=$ROOT/weights/kernel_ac.safetensors serve kac; then
  VARIANT=KernelAC load load_kac_shm_f16 kac --shm --f16
  VARIANT=KernelAC load load_kac_sock_f32 kac
  stop kac
fi

# ---- 4. correctness: every variant against cpu-ref on this device --------------
# Odd sizes, batches 1 and 4, every decoder form and switch, pipelined and
# registered runs, prepared plans (tests/gpu/test_cudnn_backend.c).
if [ "$BACKEND" = cudnn ]; then
  step device 240 env CUDNN_LOGLEVEL_DBG=2 CUDNN_LOGDEST_DBG="$R/cudnn_device.log" \
    "$B/test_cudnn_backend" device
fi

# ---- 5. what the speed-ups are worth, one at a time ----------------------------
# Each decoder form alone; shared memory staged instead of pinned; the
# input checked on the host instead of the device; one run at a time
# instead of two in flight.
for f in bwd-data d2s phase shuffle; do
  step "form_$f" 45 env HF_CUDNN_DECONV=$f HF_CUDNN_VERBOSE=1 "${BENCH[@]}" --batch 1 --iters 20 \
    --warmup 2
done
if [ "$(left)" -gt 60 ] && serve staged HF_CUDNN_NO_REGISTER=1; then
  load load_staged_shm_f16_k2 staged --shm --f16 --inflight 2
  stop staged
fi
# The out-of-contract check and the statistics on the host's cores before
# the upload, as before the device check (HF_CUDNN_HOST_CHECK): against
# load_shm_f16 and load_shm_f32, what checking on the device is worth.
if [ "$(left)" -gt 60 ] && serve hostcheck HF_CUDNN_HOST_CHECK=1; then
  load load_hostcheck_shm_f16 hostcheck --shm --f16
  load load_hostcheck_shm_f32 hostcheck --shm
  stop hostcheck
fi
if [ "$(left)" -gt 60 ] && serve depth1 -- --pipeline-depth 1; then
  load load_depth1_shm_f16_k2 depth1 --shm --f16 --inflight 2
  stop depth1
fi
# The floor: copying one frame's bytes over PCIe (FP16 in, FP16 out, and
# FP32 both ways), pinned, with CUDA events.
W=${BIG%x*}
H=${BIG#*x}
step pcie_f16 30 "$PY" "$ROOT/tools/gpu-run/pcie.py" --in-bytes $((W * H * 24 * 2)) \
  --out-bytes $((W * H * 3 * 2))
step pcie_f32 30 "$PY" "$ROOT/tools/gpu-run/pcie.py" --in-bytes $((W * H * 24 * 4)) \
  --out-bytes $((W * H * 3 * 4))
printf 'total %d s\n' "$(($(date +%s) - START))" >> "$R/steps.txt"
