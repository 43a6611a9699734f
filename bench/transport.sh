#!/bin/bash
# Frames through hairfilterd against the socket floor, float16 against
# float32 end to end, on every path (docs/PERFORMANCE.md, "Transport,
# receive buffers and float16").
#
#   bench/transport.sh BUILD_DIR [WEIGHTS [VARIANT [SIZES [ITERS [-- daemon options]]]]]
#
# Starts BUILD_DIR/hairfilterd (--backend cpu, OMP_WAIT_POLICY=passive) on
# a Unix socket and a loopback TCP port with WEIGHTS (default
# weights/small.safetensors, variant Small: the network's time does not
# enter the transport), --max-batch 1 and --warm SIZES, then runs
# BUILD_DIR/hf-transport-bench over SIZES (default 256x256,1024x1024) with
# ITERS frames each (default 10), which prints its table with the command,
# the CPU model and the date. HAIRFILTERD names another daemon binary (an
# older build, for a before/after).
set -euo pipefail
if [ $# -lt 1 ]; then
  sed -n '2,17p' "$0" >&2
  exit 2
fi
build=$1
weights=${2:-weights/small.safetensors} variant=${3:-Small}
sizes=${4:-256x256,1024x1024} iters=${5:-10}
shift $(($# < 5 ? $# : 5))
[ "${1:-}" = "--" ] && shift
opts=("$@")
. "$(dirname "$0")/common.sh"

echo "\$ $0 $build $weights $variant $sizes $iters -- ${opts[*]}"
echo "load average $(cut -d' ' -f1-3 /proc/loadavg)"
daemon=${HAIRFILTERD:-$build/hairfilterd}
echo "daemon: $daemon"
OMP_WAIT_POLICY=passive "$daemon" --listen "unix:$work/s.sock" --listen tcp:127.0.0.1:0 \
  --no-auth --weights "$weights" --backend cpu --max-batch 1 --warm "$sizes" \
  --ready-file "$work/ready" "${opts[@]}" 2> "$work/daemon.log" &
pid=$!
bench_wait_ready "$work/ready" "$work/daemon.log" 1200 || exit 1
tcp=$(grep -m1 '^tcp:' "$work/ready")
OMP_WAIT_POLICY=passive "$build/hf-transport-bench" "unix:$work/s.sock" "$tcp" "$variant" "$sizes" "$iters"
