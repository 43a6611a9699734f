#!/bin/bash
# Memory of hairfilterd under a load of large frames, one daemon binary
# beside another in the same run (docs/SERVER.md, "Memory").
#
#   bench/daemon_memory.sh BUILD_DIR WEIGHTS VARIANT SIZE SECONDS HAIRFILTERD \
#       [HAIRFILTERD ...] [-- daemon options]
#
# For each daemon binary: starts it on a Unix socket with WEIGHTS (one
# safetensors file holding VARIANT) and the daemon options, runs
# hairfilter-load (from
# BUILD_DIR) with 4 connections x 1 frame of SIZE in flight for SECONDS,
# then waits 2 s. Prints one table row per daemon: frames served and
# refused BUSY, resident memory at start, its peak (VmHWM, from
# /proc/PID/status) and what stays resident 2 s after the load.
set -euo pipefail
if [ $# -lt 6 ]; then
  sed -n '2,14p' "$0" >&2
  exit 2
fi
build=$1 weights=$2 variant=$3 size=$4 seconds=$5
shift 5
daemons=()
while [ $# -gt 0 ] && [ "$1" != "--" ]; do daemons+=("$1"); shift; done
[ "${1:-}" = "--" ] && shift
opts=("$@")
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
kb() { awk -v k="$1:" '$1 == k {print $2}' "/proc/$2/status"; }

echo "\$ $0 $build $weights $variant $size $seconds ${daemons[*]} -- ${opts[*]}"
echo "$(lscpu | sed -n 's/^Model name: *//p'), $(nproc) cores, $(date -u +%Y-%m-%d)"
echo
echo "| daemon | frames served | BUSY | RSS at start (MiB) | peak RSS (MiB) | RSS after (MiB) |"
echo "|---|---:|---:|---:|---:|---:|"
for d in "${daemons[@]}"; do
  sock=$work/s.sock ready=$work/ready
  rm -f "$sock" "$ready"
  "$d" --listen "unix:$sock" --weights "$weights" --ready-file "$ready" "${opts[@]}" \
    2> "$work/daemon.log" &
  pid=$!
  for _ in $(seq 600); do [ -f "$ready" ] && break; sleep 0.1; done
  if [ ! -f "$ready" ]; then
    cat "$work/daemon.log" >&2
    exit 1
  fi
  start=$(kb VmRSS $pid)
  "$build/hairfilter-load" --server "unix:$sock" --variant "$variant" --size "$size" \
    --connections 4 --inflight 1 --seconds "$seconds" --warmup 0 > "$work/load.txt" 2>&1 || true
  sleep 2
  peak=$(kb VmHWM $pid) after=$(kb VmRSS $pid)
  kill -TERM $pid
  wait $pid || true
  frames=$(sed -n 's/.*frames \([0-9]*\).*/\1/p' "$work/load.txt" | head -1)
  busy=$(sed -n 's/.*busy \([0-9]*\).*/\1/p' "$work/load.txt" | head -1)
  printf '| %s | %s | %s | %.0f | %.0f | %.0f |\n' "$d" "${frames:-?}" "${busy:-?}" \
    "$(echo "$start / 1024" | bc -l)" "$(echo "$peak / 1024" | bc -l)" \
    "$(echo "$after / 1024" | bc -l)"
done
