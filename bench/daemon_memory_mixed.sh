#!/bin/bash
# Memory of hairfilterd under a mixed load: every variant of a weights
# directory at once, each at its own size, one daemon binary beside another
# in the same run (docs/SERVER.md, "Memory"; docs/PERFORMANCE.md).
#
#   bench/daemon_memory_mixed.sh BUILD_DIR WEIGHTS_DIR MAX_MEMORY_MB SECONDS \
#       HAIRFILTERD [HAIRFILTERD ...]
#
# For each daemon binary: starts it on a Unix socket with --weights-dir
# WEIGHTS_DIR, --backend cpu (OMP_WAIT_POLICY=passive) and --max-memory-mb
# MAX_MEMORY_MB, then runs one BUILD_DIR/hairfilter-load per variant at
# once, each with 2 connections x 1 frame in flight for SECONDS, the
# variants' sizes taken in turn from 128x128, 256x256, 384x256, 512x512,
# 640x360 and 768x432 and every other one in float16. Prints one row per
# daemon: frames served and refused BUSY over all variants, resident
# memory once the models are loaded, its peak (VmHWM) less that, the limit,
# and what stays resident 2 s after the load.
set -euo pipefail
if [ $# -lt 5 ]; then
  sed -n '2,18p' "$0" >&2
  exit 2
fi
build=$1 weights=$2 limit=$3 seconds=$4
shift 4
. "$(dirname "$0")/common.sh"
kb() { awk -v k="$1:" '$1 == k {print $2}' "/proc/$2/status"; }
sizes=(128x128 256x256 384x256 512x512 640x360 768x432)

echo "\$ $0 $build $weights $limit $seconds $*"
echo "$(lscpu | sed -n 's/^Model name: *//p'), $(nproc) cores, $(date -u '+%Y-%m-%d %H:%M UTC'), load average $(cut -d' ' -f1-3 /proc/loadavg)"
echo
echo "| daemon | variants | frames served | BUSY | RSS loaded (MiB) | peak - loaded (MiB) | limit (MiB) | RSS after (MiB) |"
echo "|---|---:|---:|---:|---:|---:|---:|---:|"
for d in "$@"; do
  sock=$work/s.sock ready=$work/ready
  rm -f "$sock" "$ready"
  OMP_WAIT_POLICY=passive "$d" --listen "unix:$sock" --weights-dir "$weights" --backend cpu \
    --max-memory-mb "$limit" --ready-file "$ready" 2> "$work/daemon.log" &
  pid=$!
  bench_wait_ready "$ready" "$work/daemon.log" || exit 1
  "$build/hairfilter" filter --server "unix:$sock" --list > "$work/list.txt" 2>&1 || true
  mapfile -t variants < <(awk 'NR > 1 && NF {print $1}' "$work/list.txt")
  start=$(kb VmRSS $pid)
  echo 5 > "/proc/$pid/clear_refs" # VmHWM from here
  loads=()
  i=0
  for v in "${variants[@]}"; do
    size=${sizes[$((i % ${#sizes[@]}))]}
    f16=()
    [ $((i % 2)) = 1 ] && f16=(--f16)
    "$build/hairfilter-load" --server "unix:$sock" --variant "$v" --size "$size" "${f16[@]}" \
      --connections 2 --inflight 1 --seconds "$seconds" --warmup 0 > "$work/load.$i.txt" 2>&1 &
    loads+=($!)
    i=$((i + 1))
  done
  for l in "${loads[@]}"; do wait "$l" || true; done
  peak=$(kb VmHWM $pid)
  sleep 2
  after=$(kb VmRSS $pid)
  kill -TERM $pid
  wait $pid || true
  pid=
  frames=0 busy=0
  for f in "$work"/load.*.txt; do
    n=$(sed -n 's/.*frames \([0-9]*\).*/\1/p' "$f" | head -1)
    b=$(sed -n 's/.*busy \([0-9]*\).*/\1/p' "$f" | head -1)
    frames=$((frames + ${n:-0})) busy=$((busy + ${b:-0}))
  done
  printf '| %s | %d | %d | %d | %.0f | %.0f | %d | %.0f |\n' "$d" "${#variants[@]}" "$frames" "$busy" \
    "$(echo "$start / 1024" | bc -l)" "$(echo "($peak - $start) / 1024" | bc -l)" "$limit" \
    "$(echo "$after / 1024" | bc -l)"
  rm -f "$work"/load.*.txt
done
