#!/bin/sh
# weights/experiments/error_by_highlight.py on a small rendered frame with
# the 16-sample baseline: a table of six groups, the three highlight groups
# and the three texture groups each covering every hair pixel and all of
# the variant's error, an MSE column for ST 16 and none for ST 64 (the
# frame has none); a frame without ground truth and weights that do not
# exist are refused, named.
#
#   error_by_highlight.sh SOURCE_DIR HAIRFILTER WORK_DIR
src=$1 hf=$2 work=$3
py=/usr/bin/python3
[ -x "$py" ] && "$py" -c 'import torch' 2>/dev/null || { echo "SKIP: no $py with torch"; exit 77; }
rm -rf "$work" && mkdir -p "$work" || exit 1
"$hf" render frame --style braided --strands 3000 --size 40x40 --spp 4 --gt-ss 2 --st 16 --quiet \
    --out "$work/f.exr" || { echo "FAIL: render"; exit 1; }
s="$src/weights/experiments/error_by_highlight.py"
out=$("$py" "$s" "$work/f.exr" 2>&1)
rc=$?
echo "$out"
fail=0
if [ "$rc" -ne 0 ] || ! printf '%s\n' "$out" | grep -q "| MSE KernelMix | MSE ST 16 |$" ||
   printf '%s\n' "$out" | grep -q "ST 64"; then
  echo "FAIL: status $rc, or the columns are not KernelMix and ST 16"; fail=1
fi
printf '%s\n' "$out" | "$py" -c '
import sys
rows = [l.split("|")[1:-1] for l in sys.stdin if l.startswith("| highlight") or l.startswith("| texture")]
if len(rows) != 6:
    sys.exit(f"FAIL: {len(rows)} group rows, not 6")
pct = lambda v: 0.0 if v.strip() == "-" else float(v.strip().rstrip("%"))
for name, part in (("highlight", rows[:3]), ("texture", rows[3:])):
    px, err = sum(pct(r[1]) for r in part), sum(pct(r[2]) for r in part)
    if abs(px - 100) > 0.5 or abs(err - 100) > 0.5:
        sys.exit(f"FAIL: the {name} groups hold {px}% of the hair pixels and {err}% of the error")
' || fail=1
out=$("$py" "$s" "$src/tests/data/field/frame-64x64.exr" 2>&1)
rc=$?
if [ "$rc" -eq 0 ] || ! printf '%s\n' "$out" | grep -q "frame-64x64.exr: no ground truth"; then
  echo "FAIL: a frame without ground truth: status $rc, said: $out"; fail=1
fi
out=$("$py" "$s" --weights "$work/none.safetensors" "$work/f.exr" 2>&1)
rc=$?
if [ "$rc" -eq 0 ] || ! printf '%s\n' "$out" | grep -q "^error_by_highlight.py: --weights .*none.safetensors: No such file"; then
  echo "FAIL: --weights that do not exist: status $rc, said: $out"; fail=1
fi
[ "$fail" -eq 0 ] && echo PASS
exit "$fail"
