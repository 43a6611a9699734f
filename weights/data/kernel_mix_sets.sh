#!/bin/sh
# The training sets of the bundled KernelMix (weights/kernel_mix.md,
# "Data"; 301 frames), each into OUT/<set>: KernelAC's eight
# (kernel_ac_sets.sh), the two models written apart of data/apart-train
# (weights/kernel_ac.md, "Deep frames of other models of the same kinds")
# and the four sets of strands 1 to 6 pixels wide (regimes256x2,
# regimes256o2 of KernelAC's "Twice the opaque strands"; regimes256o3,
# regimes256x3 of KernelMix's step 2). Then the 68 frames of smooth grooms
# that a retraining adds (docs/QUALITY.md, "Smooth plaits the generator
# draws"): all eight styles as regimes crops, half of them smooth
# (smoothmix256), and opaque smooth braided and ponytail frames framed
# whole and as crops (smooth-braided256, smooth-ponytail256,
# smooth-crops256). 369 frames in all.
#
# Every command takes up where a stopped run left off (`render dataset
# --resume`; kernel_ac_sets.sh and train256.sh keep the frames they
# find), so the script is run again until it ends.
#
# Usage: weights/data/kernel_mix_sets.sh build/hairfilter data/kmtrain [render options]
# The render options go to every `render dataset` and `render frame`: only
# options both read (--gt-ss, --platform, --max-fragments, ...).
#
# The option strings below hold no spaces and are split on purpose:
# shellcheck disable=SC2086
set -e
if [ $# -lt 2 ]; then
  echo "usage: weights/data/kernel_mix_sets.sh BUILD/hairfilter OUT_DIR [render options] (the script's header says more)" >&2
  exit 2
fi
HF=$1; OUT=$2
shift 2
HERE=$(cd "$(dirname "$0")" && pwd)
"$HERE/kernel_ac_sets.sh" "$HF" "$OUT" "$@"
# The models are written by a script of their own, each file once.
A="$OUT/apart-train"
mkdir -p "$A"
if [ ! -f "$A/wavy_zup_cm.hair" ] || [ ! -f "$A/long_yup_m.hair" ]; then
  (cd "$A" && /usr/bin/python3 "$HERE/../experiments/models_written_apart.py" --seed 7 a b)
fi
C="--regimes --size 256x256 --frame-sizes 256,1024 --spp 1,2,4 --half --alpha-corrected --resume"
T="--width-px 0.01,0.3 --count 6"
"$HF" render dataset $C $T --hair-files "$A/wavy_zup_cm.hair" --up z --units cm --seed 301 \
    "$@" --out "$A/wavy256"
"$HF" render dataset $C $T --hair-files "$A/long_yup_m.hair" --up y --units m --seed 302 \
    "$@" --out "$A/long256"
S=straight,wavy,curly,coily,ponytail,spiky,fur
"$HF" render dataset $C --styles $S --count 4 --width-px 1,6 --seed 206 "$@" --out "$OUT/regimes256x2"
"$HF" render dataset $C --styles $S --count 4 --width-px 1,6 --opacity-range 1,1 --seed 207 \
    "$@" --out "$OUT/regimes256o2"
"$HF" render dataset $C --styles $S --count 4 --width-px 1,6 --opacity-range 1,1 --seed 208 \
    "$@" --out "$OUT/regimes256o3"
"$HF" render dataset $C --styles $S --count 4 --width-px 0.7,3 --seed 209 "$@" --out "$OUT/regimes256x3"
# Smooth grooms: every strand in its bundle, no frizz, no clumping.
"$HF" render dataset $C --styles $S,braided --count 3 --smooth-share 0.5 --gather-range 0,1 \
    --seed 410 "$@" --out "$OUT/smoothmix256"
W="--size 256x256 --spp 1,2,4 --half --alpha-corrected --resume --strands 16000"
O="--smooth-share 1 --opacity-range 1,1 --gather-range 0,1"
"$HF" render dataset $W $O --styles braided --count 24 --seed 420 "$@" --out "$OUT/smooth-braided256"
"$HF" render dataset $W $O --styles ponytail --count 4 --seed 421 "$@" --out "$OUT/smooth-ponytail256"
"$HF" render dataset $W $O --regimes --frame-sizes 256,1024 --styles braided,ponytail --count 8 \
    --seed 422 "$@" --out "$OUT/smooth-crops256"
echo "$OUT: KernelMix's sets are complete"
