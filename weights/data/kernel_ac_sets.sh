#!/bin/sh
# KernelAC's eight training sets (weights/kernel_ac.md, "Data") rendered
# with today's renderer at its default ground truth (8x8), each into
# OUT/<set>, with the stochastic-transparency estimate KernelAC reads.
# Every command takes up where a stopped run left off (`render dataset
# --resume`, weights/data/train256.sh keeps the frames it finds), so the
# script is run again until it ends; a set made over several sessions is
# the set made in one go, frame for frame (docs/RENDERING.md, "Taking up
# a stopped run").
#
# Whole rounds of styles: regimes256b and regimes256c hold 6 and 12
# frames here, where the sets of the bundled weights were runs stopped
# after 4 and 9 (their first frames, the same draws). regimes256c's 10th
# frame (ponytail_0001) is by far the costliest of all: 2.55 G fragments at
# 8x8, of which the transmittance cull keeps 2.14 G out of the A-buffer,
# 161 s on a 2-core AMD EPYC (40 min before the dense-truth changes of
# 2026-12-04; docs/RENDERING.md, "Dense ground truths", "Windows that draw
# only their segments", "The transmittance cull"); the whole set takes
# 3 min 47 s and 4.1 GB at its peak.
#
# Usage: weights/data/kernel_ac_sets.sh build/hairfilter data/g8train [render options]
# The render options go to `render dataset` and, for train256, `render
# frame`: only options both read (--gt-ss, --platform, --max-fragments,
# ...); render refuses one its mode does not read.
set -e
if [ $# -lt 2 ]; then
  echo "usage: weights/data/kernel_ac_sets.sh BUILD/hairfilter OUT_DIR [render options] (the script's header says more)" >&2
  exit 2
fi
HF=$1; OUT=$2
shift 2
HERE=$(dirname "$0")
mkdir -p "$OUT"
# The options every set shares (no spaces: expanded unquoted below).
C="--regimes --size 256x256 --frame-sizes 256,1024 --spp 1,2,4 --half --alpha-corrected --resume"
"$HF" render dataset $C --styles straight,wavy,curly,ponytail,spiky,fur --count 6 --seed 100 \
    "$@" --out "$OUT/regimes256"
"$HF" render dataset $C --styles straight,wavy,curly,ponytail,spiky,fur --count 1 --seed 101 \
    "$@" --out "$OUT/regimes256b"
"$HF" render dataset $C --styles straight,wavy,curly,ponytail,spiky,fur --count 2 --seed 102 \
    "$@" --out "$OUT/regimes256c"
"$HERE/train256.sh" "$HF" "$OUT/train256" "$@"
"$HF" render dataset $C --styles straight,wavy,curly,ponytail,spiky,fur --count 4 --width-px 0.3,4 \
    --seed 104 "$@" --out "$OUT/regimes256w"
"$HF" render dataset $C --styles ponytail,straight,wavy,curly --strands 40000 --count 8 \
    --width-px 0.01,0.5 --seed 105 "$@" --out "$OUT/deep256"
"$HF" render dataset $C --styles straight,wavy,curly,coily,ponytail,spiky,fur --count 4 \
    --width-px 1,6 --seed 106 "$@" --out "$OUT/regimes256x"
"$HF" render dataset $C --styles straight,wavy,curly,coily,ponytail,spiky,fur --count 3 \
    --width-px 1,6 --opacity-range 1,1 --seed 107 "$@" --out "$OUT/regimes256o"
echo "$OUT: the eight sets are complete"
