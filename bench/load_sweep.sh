#!/bin/bash
# Latency against throughput through hairfilterd, closed and open loop, over
# a Unix socket, loopback TCP and shared memory (docs/PERFORMANCE.md,
# "Through hairfilterd").
#
#   bench/load_sweep.sh BUILD_DIR OUT_DIR [WEIGHTS [VARIANT [SIZE ...]]]
#
# Starts BUILD_DIR/hairfilterd (--backend cpu, OMP_WAIT_POLICY=passive as
# in the backend's own tables) on a Unix socket and a loopback TCP port
# with WEIGHTS (default weights/base.safetensors, variant Base), then, for
# each SIZE (default 256x256 1024x1024) and each transport:
#
#   closed loop  hairfilter load --concurrency-range 1:7:2
#   open loop    --request-rate-range at 1/4, 1/2, 3/4, 1 and 5/4 of the
#                closed loop's highest throughput (that transport's
#                saturation), Poisson arrivals
#
# Each point: measurement windows (SWEEP_WINDOW, default 2s at 256x256,
# 4s above) until the last three agree within 10 % or SWEEP_TRIALS (default
# 4, at least 3) windows. SWEEP_TRANSPORTS ("unix tcp shm") runs fewer. Writes
# OUT_DIR/<size>-<transport>-<loop>.{txt,csv} and one PNG per size (client
# p50 and p99 against throughput, a panel per loop, a line per transport
# whose CSV is in OUT_DIR), and prints the sweep tables with the machine
# and the date.
set -euo pipefail
if [ $# -lt 2 ]; then
  sed -n '2,24p' "$0" >&2
  exit 2
fi
build=$1 out=$2
weights=${3:-weights/base.safetensors} variant=${4:-Base}
shift $(($# < 4 ? $# : 4))
sizes=("$@")
[ ${#sizes[@]} -gt 0 ] || sizes=(256x256 1024x1024)
trials=${SWEEP_TRIALS:-4}
mkdir -p "$out"
. "$(dirname "$0")/common.sh"

echo "\$ $0 $build $out $weights $variant ${sizes[*]}"
echo "$(lscpu | sed -n 's/^Model name: *//p'), $(nproc) cores, $(date -u '+%Y-%m-%d %H:%M UTC'), load average $(cut -d' ' -f1-3 /proc/loadavg)"

OMP_WAIT_POLICY=passive "$build/hairfilterd" --listen "unix:$work/s.sock" --listen tcp:127.0.0.1:0 \
  --no-auth --weights "$weights" --backend cpu --ready-file "$work/ready" 2> "$work/daemon.log" &
pid=$!
bench_wait_ready "$work/ready" "$work/daemon.log" 600 || exit 1
tcp=$(grep -m1 '^tcp:' "$work/ready")

# Column NAME of a CSV, one value a line.
column() { awk -F, -v n="$2" 'NR == 1 {for (i = 1; i <= NF; i++) if ($i == n) c = i; next} {print $c}' "$1"; }

for size in "${sizes[@]}"; do
  window=${SWEEP_WINDOW:-$([ "$size" = 256x256 ] && echo 2s || echo 4s)}
  for transport in ${SWEEP_TRANSPORTS:-unix tcp shm}; do
    case $transport in
      unix) url=unix:$work/s.sock extra=() ;;
      tcp) url=$tcp extra=() ;;
      shm) url=unix:$work/s.sock extra=(--shm) ;;
    esac
    common=(--server "$url" --variant "$variant" --size "$size" --window "$window"
            --max-trials "$trials" --quiet "${extra[@]}")
    base=$out/$size-$transport
    echo
    echo "\$ hairfilter load ${common[*]} --concurrency-range 1:7:2"
    "$build/hairfilter" load "${common[@]}" --concurrency-range 1:7:2 --csv "$base-closed.csv" \
      > "$base-closed.txt"
    sed -n '/sweep (client latency/,$p' "$base-closed.txt"
    sat=$(column "$base-closed.csv" throughput | sort -g | tail -1)
    q=$(echo "$sat / 4" | bc -l)
    # The end a little past 5 q, so that rounding keeps the fifth point.
    range=$(printf '%.2f:%.2f:%.2f' "$q" "$(echo "$q * 5.01" | bc -l)" "$q")
    echo
    echo "\$ hairfilter load ${common[*]} --request-rate-range $range --request-distribution poisson"
    "$build/hairfilter" load "${common[@]}" --request-rate-range "$range" \
      --request-distribution poisson --csv "$base-open.csv" > "$base-open.txt"
    sed -n '/sweep (client latency/,$p' "$base-open.txt"
  done
  if command -v gnuplot > /dev/null; then
    # One panel per loop; a colour per transport, p99 solid, p50 dashed.
    panels=""
    for loop in closed open; do
      plot="" colour=0
      for transport in unix tcp shm; do
        f=$out/$size-$transport-$loop.csv
        colour=$((colour + 1))
        [ -f "$f" ] || continue
        paste -d' ' <(column "$f" throughput) <(column "$f" total_p50_ms) \
          <(column "$f" total_p99_ms) > "$work/$transport-$loop.dat"
        plot="$plot${plot:+, }'$work/$transport-$loop.dat' using 1:3 with linespoints lc $colour pt 7 title '$transport p99'"
        plot="$plot, '$work/$transport-$loop.dat' using 1:2 with linespoints lc $colour dt 2 pt 6 title '$transport p50'"
      done
      panels="$panels
set title '$loop loop'
plot $plot"
    done
    gnuplot <<EOF
set terminal pngcairo size 1200,520 font ',10'
set output '$out/load-$size.png'
set multiplot layout 1,2 title "$variant $size f32 through hairfilterd (cpu backend): client latency against throughput" noenhanced
set xlabel 'throughput (frames/s)'
set ylabel 'client latency (ms)'
set logscale y
set grid
set key top left
$panels
unset multiplot
EOF
  fi
done
