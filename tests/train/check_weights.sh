#!/bin/sh
# weights/check_weights.py, a researcher's check of an exported weights
# file against PyTorch: the bundled Small on a rendered frame and the
# bundled KernelMix (which reads the estimate) on an odd-sized frame pass
# on cpu and cpu-ref, and fail a tolerance below float32's rounding; a
# frame with fewer samples than the variant reads,
# and a backend it does not know, are refused with status 2, named.
#
#   check_weights.sh SOURCE_DIR HAIRFILTER
src=$1 hf=$2
py=/usr/bin/python3
[ -x "$py" ] && "$py" -c 'import torch' 2>/dev/null || { echo "SKIP: no $py with torch"; exit 77; }
fail=0
run() { out=$("$py" "$src/weights/check_weights.py" "$@" --hairfilter "$hf" 2>&1); rc=$?; }
run "$src/weights/small.safetensors" "$src/tests/data/field/frame-64x64.exr"
echo "$out"
if [ "$rc" -ne 0 ] || ! printf '%s\n' "$out" | grep -q "passed: every output within 0.0001" ||
   [ "$(printf '%s\n' "$out" | grep -c '^  cpu ')" -ne 3 ] ||
   [ "$(printf '%s\n' "$out" | grep -c '^  cpu-ref ')" -ne 3 ]; then
  echo "FAIL: Small on frame-64x64.exr: status $rc"; fail=1
fi
run "$src/weights/kernel_mix.safetensors" "$src/tests/data/golden/KernelMix_37x23.features.exr"
echo "$out"
if [ "$rc" -ne 0 ] || ! printf '%s\n' "$out" | grep -q "^KernelMix .* (37x23)"; then
  echo "FAIL: KernelMix on a 37x23 frame with the estimate: status $rc"; fail=1
fi
# Over a tolerance below float32's rounding: status 1, the outputs marked.
run "$src/weights/small.safetensors" "$src/tests/data/field/frame-64x64.exr" --backend cpu --tolerance 1e-12
if [ "$rc" -ne 1 ] || ! printf '%s\n' "$out" | grep -q "OVER 1e-12" ||
   ! printf '%s\n' "$out" | grep -q "check_weights.py: FAILED"; then
  echo "FAIL: --tolerance 1e-12: status $rc, said: $out"; fail=1
fi
run "$src/weights/small.safetensors" "$src/tests/data/golden/Base_1spp_19x41.features.exr"
if [ "$rc" -ne 2 ] || ! printf '%s\n' "$out" | grep -q "1 samples per pixel, the variant Small reads 4"; then
  echo "FAIL: a 1-spp frame for Small: status $rc, said: $out"; fail=1
fi
run "$src/weights/small.safetensors" "$src/tests/data/field/frame-64x64.exr" --backend gpu
if [ "$rc" -ne 2 ] || ! printf '%s\n' "$out" | grep -q "give cpu, cpu-ref or cudnn"; then
  echo "FAIL: --backend gpu: status $rc, said: $out"; fail=1
fi
[ "$fail" -eq 0 ] && echo PASS
exit "$fail"
