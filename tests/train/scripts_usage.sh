#!/bin/sh
# weights/data/*.sh called without their arguments: status 2 and a usage
# line (not the shell's "1: hairfilter binary"); models_written_apart.py
# --help: its usage, status 0; models_written_apart_2.py: --help, its usage
# with status 0, a model it does not make, status 2 naming the ones it does.
#
#   scripts_usage.sh SOURCE_DIR
cd "$1" || exit 1
fail=0
for s in weights/data/kernel_ac_sets.sh weights/data/kernel_mix_sets.sh weights/data/kernel_mix_eval_sets.sh \
    weights/data/train256.sh; do
  out=$(sh "$s" 2>&1)
  rc=$?
  if [ "$rc" -ne 2 ] || ! printf '%s\n' "$out" | grep -q "^usage: $s BUILD/hairfilter OUT_DIR"; then
    echo "FAIL: $s without arguments: status $rc, said: $out"
    fail=1
  fi
done
if [ -x /usr/bin/python3 ]; then
  out=$(/usr/bin/python3 weights/experiments/models_written_apart.py --help 2>&1)
  rc=$?
  if [ "$rc" -ne 0 ] || ! printf '%s\n' "$out" | grep -q '^Usage: models_written_apart.py \[--seed N\]'; then
    echo "FAIL: models_written_apart.py --help: status $rc, said: $out"
    fail=1
  fi
fi
if [ -x /usr/bin/python3 ] && /usr/bin/python3 -c "import numpy" 2>/dev/null; then
  s=weights/experiments/models_written_apart_2.py
  out=$(/usr/bin/python3 "$s" --help 2>&1)
  rc=$?
  if [ "$rc" -ne 0 ] || ! printf '%s\n' "$out" | grep -q '^usage: models_written_apart_2.py \[bob|braids|buzzbeard|wavy|braids-<variant> \.\.\.\]'; then
    echo "FAIL: $s --help: status $rc, said: $out"
    fail=1
  fi
  out=$(/usr/bin/python3 "$s" plaits 2>&1)
  rc=$?
  if [ "$rc" -ne 2 ] || ! printf '%s\n' "$out" | grep -q "no model 'plaits'; the models: bob braids buzzbeard wavy; the braids' variants: braids-flat braids-unplaited braids-untwisted braids-thick-bundles"; then
    echo "FAIL: $s plaits: status $rc, said: $out"
    fail=1
  fi
fi
[ "$fail" -eq 0 ] && echo PASS
exit "$fail"
