#!/bin/bash
# A bounded soak of hairfilterd (docs/PERFORMANCE.md, "Soak"): closed-loop
# load at one concurrency for a fixed time, the daemon's resident memory
# sampled as it runs, then one more request after the load.
#
#   bench/load_soak.sh BUILD_DIR CONCURRENCY SECONDS [WEIGHTS [VARIANT [SIZE [TRANSPORT]]]]
#
# Starts BUILD_DIR/hairfilterd (--backend cpu, OMP_WAIT_POLICY=passive) on
# a Unix socket with WEIGHTS (default weights/base.safetensors, variant
# Base), runs `hairfilter load --concurrency-range CONCURRENCY --trials N
# --window 10s` (N windows making SECONDS, after a 10 s warm-up) at SIZE
# (default 256x256) over TRANSPORT (unix, default, or shm), and samples
# VmRSS from /proc every 5 s. Prints the load's report, the RSS samples and
# a verdict: requests sent and answered (none may be lost), errors, the
# RSS range after the warm-up, and whether a request after the soak is
# answered. Exits 1 when a request was lost, one failed, or the last
# request was not answered.
set -euo pipefail
if [ $# -lt 3 ]; then
  sed -n '2,17p' "$0" >&2
  exit 2
fi
build=$1 conc=$2 seconds=$3
weights=${4:-weights/base.safetensors} variant=${5:-Base} size=${6:-256x256}
transport=${7:-unix}
. "$(dirname "$0")/common.sh"
rss_kb() { awk '$1 == "VmRSS:" {print $2}' "/proc/$pid/status"; }

echo "\$ $0 $*"
echo "$(lscpu | sed -n 's/^Model name: *//p'), $(nproc) cores, $(date -u '+%Y-%m-%d %H:%M UTC'), load average $(cut -d' ' -f1-3 /proc/loadavg)"
OMP_WAIT_POLICY=passive "$build/hairfilterd" --listen "unix:$work/s.sock" --weights "$weights" \
  --backend cpu --ready-file "$work/ready" 2> "$work/daemon.log" &
pid=$!
bench_wait_ready "$work/ready" "$work/daemon.log" 600 || exit 1
extra=()
[ "$transport" = shm ] && extra=(--shm)
common=(--server "unix:$work/s.sock" --variant "$variant" --size "$size" "${extra[@]}")
windows=$(((seconds + 9) / 10))
echo "\$ hairfilter load ${common[*]} --concurrency-range $conc --warmup 10s --window 10s --trials $windows --verbose"
echo "daemon RSS at start: $(rss_kb) KiB"
"$build/hairfilter" load "${common[@]}" --concurrency-range "$conc" --warmup 10s --window 10s \
  --trials "$windows" --verbose --quiet > "$work/load.txt" 2>&1 &
load=$!
t0=$(date +%s)
: > "$work/rss"
while kill -0 "$load" 2> /dev/null; do
  echo "$(($(date +%s) - t0)) $(rss_kb)" >> "$work/rss"
  sleep 5
done
rc=0
wait "$load" || rc=$?
cat "$work/load.txt"
echo
echo "RSS samples (s since start, KiB):"
awk '{printf "%s%s:%s", (NR > 1 ? "  " : "  "), $1, $2} NR % 8 == 0 {print ""} END {print ""}' "$work/rss"
# After the 10 s warm-up.
read -r lo hi < <(awk '$1 >= 10 {if (!n++ || $2 < lo) lo = $2; if ($2 > hi) hi = $2} END {print lo, hi}' "$work/rss")
echo "RSS after the warm-up: $((lo / 1024)) to $((hi / 1024)) MiB"
# The point's own lines: its "requests sent ... answered ... unanswered"
# line and its "answered by outcome" line; the warm-up's requests are on a
# line of their own ("warm-up: requests sent W  ok ...  errors E"), counted
# apart.
point=$(grep -v 'warm-up:' "$work/load.txt" || true)
sent=$(sed -n 's/^ *requests sent \([0-9]*\) .*/\1/p' <<< "$point" | tail -1)
answered=$(sed -n 's/^ *requests sent .* answered \([0-9]*\)  unanswered.*/\1/p' <<< "$point" | tail -1)
unanswered=$(sed -n 's/^ *requests sent .* unanswered \([0-9]*\).*/\1/p' <<< "$point" | tail -1)
# Errors among every answer to the point's requests, in any window or
# after the last ("answered by outcome: ok O  busy B  errors E  (...)",
# expired X before errors with --deadline).
errors=$(sed -n 's/^ *answered by outcome: .* errors \([0-9]*\) .*/\1/p' <<< "$point" | tail -1)
wsent=$(sed -n 's/.*warm-up: requests sent \([0-9]*\) .*/\1/p' "$work/load.txt" | tail -1)
werrors=$(sed -n 's/.*warm-up: .* errors \([0-9]*\).*/\1/p' "$work/load.txt" | tail -1)
echo "load exit status $rc; requests sent ${sent:-?}, answered ${answered:-?}, unanswered ${unanswered:-?}, errors ${errors:-?}; warm-up: requests sent ${wsent:-?}, errors ${werrors:-?}"
echo "\$ hairfilter load ${common[*]} --seconds 2s --warmup 0"
"$build/hairfilter" load "${common[@]}" --seconds 2s --warmup 0 --quiet > "$work/after.txt" 2>&1 || rc=1
after=$(sed -n 's/.*frames \([0-9]*\) .*/\1/p' "$work/after.txt" | head -1)
echo "after the soak: ${after:-0} frames answered in 2 s"
if [ "$rc" -ne 0 ] || [ -z "$sent" ] || [ "${answered:-0}" -ne "$sent" ] ||
   [ "${unanswered:-1}" -ne 0 ] || [ "${errors:-1}" -ne 0 ] || [ "${werrors:-0}" -ne 0 ] ||
   [ "${after:-0}" -lt 1 ]; then
  echo "soak FAILED"
  exit 1
fi
echo "soak passed: no request lost or failed, the daemon still serves"
