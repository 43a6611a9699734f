#!/bin/bash
# hairfilter filter of one feature EXR through hairfilterd, float32 against
# float16, runs interleaved (docs/PERFORMANCE.md, "Reading a feature EXR as
# float16").
#
#   bench/filter_exr.sh BUILD_DIR FEATURES.exr [SIZE [WEIGHTS [VARIANT [RUNS]]]]
#
# Starts BUILD_DIR/hairfilterd (--backend cpu, --max-batch 1, --warm SIZE,
# default 1024x1024, the EXR's size) on a Unix socket with WEIGHTS (default
# weights/small.safetensors, variant Small), then runs BUILD_DIR/hairfilter
# filter RUNS times (default 5) with and without --f16, alternating which
# goes first. Per run: "read", the CLI's own time from the EXR to the
# request's features; "request", hfc_filter's total; "process", the wall
# time of the whole command (start, connect, read, request, result EXR
# written and verified). Prints every run, then the medians, with the
# command, the CPU model and the date. HAIRFILTER names another CLI binary.
set -euo pipefail
if [ $# -lt 2 ]; then
  sed -n '2,16p' "$0" >&2
  exit 2
fi
build=$1 exr=$2 size=${3:-1024x1024}
weights=${4:-weights/small.safetensors} variant=${5:-Small} runs=${6:-5}
. "$(dirname "$0")/common.sh"
cli=${HAIRFILTER:-$build/hairfilter}
echo "\$ $0 $*"
echo "$(date -u '+%Y-%m-%d %H:%M:%S UTC'), $(lscpu | sed -n 's/^Model name: *//p'), $(nproc) CPUs"
echo "load average $(cut -d' ' -f1-3 /proc/loadavg)"
OMP_WAIT_POLICY=passive "$build/hairfilterd" --listen "unix:$work/s.sock" --no-auth \
  --weights "$weights" --backend cpu --max-batch 1 --warm "$size" \
  --ready-file "$work/ready" 2> "$work/daemon.log" &
pid=$!
bench_wait_ready "$work/ready" "$work/daemon.log" 1200 || exit 1
one() {  # one run of dtype $1: prints "dtype read request process"
  local flag=
  [ "$1" = f16 ] && flag=--f16
  local t0 t1
  t0=$(date +%s%N)
  OMP_WAIT_POLICY=passive "$cli" filter --server "unix:$work/s.sock" --variant "$variant" \
    --in "$exr" --out "$work/result.exr" $flag > "$work/out.txt"
  t1=$(date +%s%N)
  echo "$1 $(awk '$1 == "read" {print $2}' "$work/out.txt") \
$(awk '$1 == "total" {print $2}' "$work/out.txt") $(((t1 - t0) / 1000))" |
    awk '{printf "%s %.2f %.2f %.2f\n", $1, $2, $3, $4 / 1000}'
}
echo "run dtype read_ms request_ms process_ms"
for i in $(seq "$runs"); do
  if [ $((i % 2)) = 1 ]; then order="f32 f16"; else order="f16 f32"; fi
  for d in $order; do echo "$i $(one "$d")"; done
done | tee "$work/runs"
median() { sort -n | awk '{v[NR] = $1} END {print NR % 2 ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2}'; }
echo
echo "| dtype | read ms | request ms | process ms | runs |"
echo "|---|---:|---:|---:|---:|"
for d in f32 f16; do
  r=$(awk -v d=$d '$2 == d {print $3}' "$work/runs" | median)
  q=$(awk -v d=$d '$2 == d {print $4}' "$work/runs" | median)
  p=$(awk -v d=$d '$2 == d {print $5}' "$work/runs" | median)
  echo "| $d | $r | $q | $p | $runs |"
done
