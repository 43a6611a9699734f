#!/bin/bash
# What a render costs, one hairfilter binary beside another in the same run
# (docs/RENDERING.md, "Timings"): wall time, the ground truth's share
# of it, peak memory, and whether the binaries wrote the same files.
#
#   bench/render_truth.sh HAIRFILTER [HAIRFILTER ...] -- RENDER ARGS
#
# RENDER ARGS are `hairfilter render` arguments without --out (frame mode:
# the EXR; dataset mode: the directory), run once per binary, one after the
# other. Prints the command, the machine and the date, then one Markdown row
# per binary: wall seconds and peak RSS (GNU time), the ground truth's
# milliseconds and fragments (frame mode: the summary line; dataset mode:
# the frames' whole render_ms and their fragments, from the manifest), and
# the bytes of its output against the first binary's (cmp; dataset mode:
# every EXR).
set -euo pipefail
bins=()
while [ $# -gt 0 ] && [ "$1" != "--" ]; do bins+=("$1"); shift; done
if [ ${#bins[@]} -lt 1 ] || [ "${1:-}" != "--" ] || [ $# -lt 2 ]; then
  sed -n '2,15p' "$0" >&2
  exit 2
fi
shift
args=("$@")
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
mode=${args[0]}

echo "\$ $0 ${bins[*]} -- ${args[*]}"
echo "$(date -u '+%Y-%m-%d %H:%M UTC'), $(nproc) CPUs, $(awk -F': ' '/model name/ {print $2; exit}' /proc/cpuinfo), load average $(cut -d' ' -f1-3 /proc/loadavg)"
echo
echo "| binary | wall s | ground truth ms (dataset: frames ms) | fragments | peak RSS MiB | output |"
echo "|---|---:|---:|---:|---:|---|"
i=0
for b in "${bins[@]}"; do
  out=$work/out$i
  [ "$mode" = dataset ] || out=$out.exr
  /usr/bin/time -v -o "$work/time$i" "$b" render "${args[@]}" --out "$out" > "$work/log$i" 2>&1 || {
    echo "| $b | failed: $(tail -1 "$work/log$i") | | | | |"
    i=$((i + 1))
    continue
  }
  wall=$(awk -F': ' '/Elapsed \(wall clock\)/ {n = split($2, t, ":"); s = 0; for (k = 1; k <= n; k++) s = s * 60 + t[k]; printf "%.1f", s}' "$work/time$i")
  rss=$(awk -F': ' '/Maximum resident set size/ {printf "%.0f", $2 / 1024}' "$work/time$i")
  gt=$(sed -n 's/.*ground truth \([0-9]*\) ms (\([0-9]*\) fragments.*/\1 \2/p' "$work/log$i" | tail -1)
  if [ "$mode" = dataset ]; then
    # The manifest times whole frames (render_ms): the truth's share is in
    # the log of each frame only in frame mode.
    gt=$(/usr/bin/python3 -c '
import json, sys
fr = json.load(open(sys.argv[1]))["frames"]
print("%.0f %d" % (sum(f["render_ms"] for f in fr), sum(f["gt_fragments"] for f in fr)))' \
      "$out/manifest.json" 2> /dev/null || echo "- -")
  fi
  same="(reference)"
  if [ $i -gt 0 ]; then
    if [ "$mode" = dataset ]; then
      same=identical
      for f in "$work/out0"/*.exr; do
        cmp -s "$f" "$out/$(basename "$f")" || same="differs: $(basename "$f")"
      done
    else
      cmp -s "$work/out0.exr" "$out" && same=identical || same=differs
    fi
  fi
  echo "| $b | $wall | ${gt% *} | ${gt#* } | $rss | $same |"
  i=$((i + 1))
done
