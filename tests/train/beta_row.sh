#!/bin/sh
# weights/experiments/kernel_mix_beta_row.py: trained on a small rendered
# frame, it changes the bundled KernelMix's mixing row (the head's last
# row) and nothing else, keeps the metadata, and what it writes computes in
# hairfilter what it computes in PyTorch (weights/check_weights.py); a
# frame without the estimate, a non-KernelMix file, weights that do not
# exist and an --out that cannot be written are refused, named.
#
#   beta_row.sh SOURCE_DIR HAIRFILTER WORK_DIR
src=$1 hf=$2 work=$3
py=/usr/bin/python3
[ -x "$py" ] && "$py" -c 'import torch' 2>/dev/null || { echo "SKIP: no $py with torch"; exit 77; }
rm -rf "$work" && mkdir -p "$work" || exit 1
fail=0
"$hf" render frame --style braided --strands 3000 --size 40x40 --spp 4 --gt-ss 2 --quiet \
    --out "$work/f.exr" || { echo "FAIL: render"; exit 1; }
"$hf" render frame --style wavy --strands 3000 --size 40x40 --spp 4 --gt-ss 2 \
    --no-alpha-corrected --quiet --out "$work/no_est.exr" || { echo "FAIL: render"; exit 1; }
s="$src/weights/experiments/kernel_mix_beta_row.py"
out=$("$py" "$s" --steps 5 --batch 2 --out "$work/row.safetensors" "$work/f.exr" 2>&1)
rc=$?
echo "$out"
if [ "$rc" -ne 0 ] || ! printf '%s\n' "$out" | grep -q "^step 5: loss"; then
  echo "FAIL: 5 steps on one frame: status $rc"; fail=1
fi
"$py" - "$src/weights" "$work/row.safetensors" <<'PY' || fail=1
import sys
sys.path.insert(0, sys.argv[1])
import hfnet
a_cfg, a = hfnet.load_safetensors(sys.argv[1] + "/kernel_mix.safetensors")
b_cfg, b = hfnet.load_safetensors(sys.argv[2])
row = hfnet.kernel_taps(a_cfg["kernel_radius"]) + 3
bad = [k for k in a if k not in ("head.weight", "head.bias") and not (a[k] == b[k]).all()]
keep_w = (a["head.weight"][:row] == b["head.weight"][:row]).all()
keep_b = (a["head.bias"][:row] == b["head.bias"][:row]).all()
moved = not (a["head.weight"][row] == b["head.weight"][row]).all()
meta_a = hfnet.load_metadata(sys.argv[1] + "/kernel_mix.safetensors")
meta_b = hfnet.load_metadata(sys.argv[2])
if bad or not keep_w or not keep_b or not moved or a_cfg != b_cfg or \
        meta_a.get("input_range") != meta_b.get("input_range"):
    sys.exit(f"FAIL: tensors changed {bad}, other head rows kept {bool(keep_w)} {bool(keep_b)}, "
             f"mixing row moved {moved}, config kept {a_cfg == b_cfg}, input range kept "
             f"{meta_a.get('input_range') == meta_b.get('input_range')}")
PY
out=$("$py" "$src/weights/check_weights.py" "$work/row.safetensors" "$work/f.exr" \
      --hairfilter "$hf" --backend cpu 2>&1)
rc=$?
if [ "$rc" -ne 0 ] || ! printf '%s\n' "$out" | grep -q "passed: every output within 0.0001"; then
  echo "FAIL: check_weights.py on the trained file: status $rc, said: $out"; fail=1
fi
# refused WHAT PATTERN ARGS...: the script run with ARGS fails, saying PATTERN.
refused() {
  what=$1 pattern=$2
  shift 2
  out=$("$py" "$s" "$@" 2>&1)
  rc=$?
  if [ "$rc" -eq 0 ] || ! printf '%s\n' "$out" | grep -q "$pattern"; then
    echo "FAIL: $what: status $rc, said: $out"; fail=1
  fi
}
refused "a frame without the estimate" "no acst4.\* channels" \
    --steps 5 --out "$work/x.safetensors" "$work/no_est.exr"
refused "Kernel's weights" "is not a KernelMix file" \
    --weights "$src/weights/kernel.safetensors" --steps 5 --out "$work/x.safetensors" "$work/f.exr"
refused "--out in a directory that does not exist" "cannot write into $work/none: create it first" \
    --steps 5 --out "$work/none/x.safetensors" "$work/f.exr"
refused "--weights that do not exist" "^kernel_mix_beta_row.py: --weights .*none.safetensors: No such file" \
    --weights "$work/none.safetensors" --steps 5 --out "$work/x.safetensors" "$work/f.exr"
[ -e "$work/x.safetensors" ] && { echo "FAIL: a refused run wrote a file"; fail=1; }
[ "$fail" -eq 0 ] && echo PASS
exit "$fail"
