#!/bin/bash
# Per-primitive times of the cpu backend, from oneDNN's verbose log.
#
#   bench/profile_cpu.sh BUILD_DIR [hairfilter bench options]
#
# Runs `hairfilter bench --backend cpu` with ONEDNN_VERBOSE=1 and prints, for
# each oneDNN primitive in execution order, its implementation, its shape and
# the fastest of its executions in ms (the minimum, so that a run preempted by
# other work on the machine does not hide the primitive's own cost). The
# backend's own loops (tap sums, concat copies) are not oneDNN primitives and
# do not appear: compare the sum with the bench's "net" column.
set -euo pipefail
if [ $# -lt 1 ] || [ ! -x "$1/hairfilter" ]; then
  echo "usage: $0 BUILD_DIR [bench options]" >&2
  exit 2
fi
build=$1
shift
ONEDNN_VERBOSE=1 DNNL_VERBOSE=1 "$build/hairfilter" bench --backend cpu "$@" 2>/dev/null |
  awk -F, '/^(onednn|dnnl)_verbose,exec,cpu,/ {
      n = split($0, a, ",")
      key = sprintf("%-14s %-26s %s", $4, $5, a[n - 1])
      t = a[n] + 0
      if (!(key in best) || t < best[key]) best[key] = t
      if (!(key in order)) order[key] = ++count
    }
    END {
      for (k in best) printf "%3d  %s  %9.3f ms\n", order[k], k, best[k]
    }' | sort -n
