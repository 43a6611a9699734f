#!/bin/sh
# The 18 frames of the data set 'train256' that the 2026-11-30 weights were
# trained on beside data/regimes256 and data/regimes256b (weights/*.md):
# 256x256 frames of straight, wavy, curly, coily and ponytail hair, strand
# count 4000-60000, thickness scale 0.3-30, opacity 0.3-1, camera distance
# 1.3-5 and light drawn at random (seed 1), one `hairfilter render frame`
# each. Rendered with the renderer as it was before strands wider than a
# pixel became wide quads, so today's binary draws the thick ones wider.
# The ground truth is render's default (8x8 since 2026-12-03); the frames
# those weights were trained on had the 4x4 one: pass --gt-ss 4 for them.
# Usage: weights/data/train256.sh build/hairfilter data/train256 [render options]
set -e
if [ $# -lt 2 ]; then
  echo "usage: weights/data/train256.sh BUILD/hairfilter OUT_DIR [render options] (the script's header says more)" >&2
  exit 2
fi
HF=$1; OUT=$2
shift 2
mkdir -p "$OUT"
# A frame already there is kept (render writes each file whole under a
# temporary name and renames it), so a stopped run is taken up by running
# the script again.
frame() {
  f=$1
  shift
  if [ -f "$f" ]; then return 0; fi
  "$HF" render frame "$@" --out "$f"
}
frame "$OUT/wavy_0010000.exr" --style wavy --strands 18685 --hair-seed 936711 --opacity 0.641 --thickness-scale 12.0684 --size 256x256 --cam-distance 1.533 --cam-yaw 42.45 --cam-pitch 23.05 --light-yaw 170.01 --light-pitch 20.37 --light-distance 3.23 --alpha-r -8.05 --alpha-trt 12.08 --seed 876364 "$@"
frame "$OUT/ponytail_0010001.exr" --style ponytail --strands 31518 --hair-seed 567713 --opacity 0.318 --thickness-scale 0.3029 --size 256x256 --cam-distance 2.948 --cam-yaw 259.75 --cam-pitch -3.56 --light-yaw 340.30 --light-pitch 62.11 --light-distance 2.61 --alpha-r -5.30 --alpha-trt 7.96 --seed 9653 "$@"
frame "$OUT/coily_0010002.exr" --style coily --strands 25670 --hair-seed 797912 --opacity 0.774 --thickness-scale 26.0137 --size 256x256 --cam-distance 3.986 --cam-yaw 189.95 --cam-pitch 23.19 --light-yaw 338.10 --light-pitch 34.23 --light-distance 3.71 --alpha-r -5.24 --alpha-trt 7.86 --seed 481930 "$@"
frame "$OUT/straight_0010003.exr" --style straight --strands 12345 --hair-seed 745739 --opacity 0.927 --thickness-scale 20.4014 --size 256x256 --cam-distance 4.712 --cam-yaw 36.00 --cam-pitch 16.47 --light-yaw 260.51 --light-pitch 13.71 --light-distance 5.10 --alpha-r -5.32 --alpha-trt 7.98 --seed 525127 "$@"
frame "$OUT/coily_0010004.exr" --style coily --strands 15819 --hair-seed 503555 --opacity 0.897 --thickness-scale 19.8377 --size 256x256 --cam-distance 2.002 --cam-yaw 102.30 --cam-pitch 33.67 --light-yaw 179.77 --light-pitch 65.27 --light-distance 3.88 --alpha-r -6.28 --alpha-trt 9.42 --seed 254532 "$@"
frame "$OUT/coily_0010005.exr" --style coily --strands 12283 --hair-seed 546244 --opacity 0.845 --thickness-scale 0.6655 --size 256x256 --cam-distance 3.331 --cam-yaw 253.09 --cam-pitch 18.72 --light-yaw 134.89 --light-pitch 25.12 --light-distance 4.28 --alpha-r -8.03 --alpha-trt 12.05 --seed 880754 "$@"
frame "$OUT/coily_0010006.exr" --style coily --strands 29097 --hair-seed 12900 --opacity 0.459 --thickness-scale 2.6047 --size 256x256 --cam-distance 2.442 --cam-yaw 305.39 --cam-pitch 15.74 --light-yaw 208.14 --light-pitch 41.77 --light-distance 3.09 --alpha-r -9.00 --alpha-trt 13.50 --seed 807953 "$@"
frame "$OUT/ponytail_0010007.exr" --style ponytail --strands 7501 --hair-seed 821723 --opacity 0.304 --thickness-scale 3.1964 --size 256x256 --cam-distance 4.824 --cam-yaw 208.01 --cam-pitch 7.96 --light-yaw 96.94 --light-pitch 33.84 --light-distance 5.85 --alpha-r -5.90 --alpha-trt 8.85 --seed 898577 "$@"
frame "$OUT/ponytail_0010008.exr" --style ponytail --strands 35783 --hair-seed 508481 --opacity 0.653 --thickness-scale 3.2695 --size 256x256 --cam-distance 3.377 --cam-yaw 153.39 --cam-pitch -12.19 --light-yaw 313.20 --light-pitch 35.60 --light-distance 3.20 --alpha-r -8.22 --alpha-trt 12.32 --seed 852861 "$@"
frame "$OUT/curly_0010009.exr" --style curly --strands 4017 --hair-seed 96052 --opacity 0.427 --thickness-scale 3.6086 --size 256x256 --cam-distance 4.210 --cam-yaw 119.21 --cam-pitch 14.99 --light-yaw 289.65 --light-pitch 40.83 --light-distance 4.43 --alpha-r -7.24 --alpha-trt 10.87 --seed 837224 "$@"
frame "$OUT/curly_0010010.exr" --style curly --strands 4367 --hair-seed 193578 --opacity 0.858 --thickness-scale 23.1346 --size 256x256 --cam-distance 1.561 --cam-yaw 312.51 --cam-pitch 7.65 --light-yaw 271.49 --light-pitch 12.50 --light-distance 3.44 --alpha-r -8.55 --alpha-trt 12.82 --seed 361154 "$@"
frame "$OUT/wavy_0010011.exr" --style wavy --strands 6163 --hair-seed 405335 --opacity 0.317 --thickness-scale 3.4032 --size 256x256 --cam-distance 1.922 --cam-yaw 98.25 --cam-pitch 20.58 --light-yaw 163.69 --light-pitch 15.76 --light-distance 4.16 --alpha-r -7.90 --alpha-trt 11.84 --seed 360021 "$@"
frame "$OUT/wavy_0010012.exr" --style wavy --strands 8053 --hair-seed 37043 --opacity 0.578 --thickness-scale 0.9639 --size 256x256 --cam-distance 4.002 --cam-yaw 351.63 --cam-pitch 33.28 --light-yaw 155.40 --light-pitch 68.04 --light-distance 3.29 --alpha-r -5.20 --alpha-trt 7.80 --seed 753754 "$@"
frame "$OUT/coily_0010013.exr" --style coily --strands 26961 --hair-seed 414081 --opacity 0.754 --thickness-scale 6.8151 --size 256x256 --cam-distance 3.315 --cam-yaw 79.42 --cam-pitch 33.78 --light-yaw 287.21 --light-pitch 31.33 --light-distance 3.28 --alpha-r -7.12 --alpha-trt 10.68 --seed 707687 "$@"
frame "$OUT/curly_0010014.exr" --style curly --strands 23882 --hair-seed 312350 --opacity 0.942 --thickness-scale 2.1366 --size 256x256 --cam-distance 4.029 --cam-yaw 45.25 --cam-pitch -4.39 --light-yaw 17.08 --light-pitch -4.34 --light-distance 2.77 --alpha-r -9.21 --alpha-trt 13.81 --seed 779975 "$@"
frame "$OUT/ponytail_0010015.exr" --style ponytail --strands 7922 --hair-seed 817908 --opacity 0.907 --thickness-scale 0.3119 --size 256x256 --cam-distance 4.551 --cam-yaw 13.65 --cam-pitch 25.97 --light-yaw 346.39 --light-pitch 35.62 --light-distance 3.10 --alpha-r -6.89 --alpha-trt 10.33 --seed 738222 "$@"
frame "$OUT/straight_0010016.exr" --style straight --strands 11132 --hair-seed 524079 --opacity 0.507 --thickness-scale 1.4825 --size 256x256 --cam-distance 2.061 --cam-yaw 242.70 --cam-pitch 6.65 --light-yaw 69.88 --light-pitch -1.65 --light-distance 4.83 --alpha-r -8.37 --alpha-trt 12.56 --seed 18036 "$@"
frame "$OUT/coily_0010017.exr" --style coily --strands 45726 --hair-seed 878394 --opacity 0.772 --thickness-scale 0.3261 --size 256x256 --cam-distance 2.043 --cam-yaw 117.99 --cam-pitch 34.35 --light-yaw 281.77 --light-pitch 17.13 --light-distance 3.25 --alpha-r -5.34 --alpha-trt 8.01 --seed 397656 "$@"
