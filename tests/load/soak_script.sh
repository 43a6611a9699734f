#!/bin/bash
# bench/load_soak.sh end to end, briefly: its verdict line counts the
# point's requests (not the warm-up's, which have a line of their own) and
# says that all of them were answered.
#
#   soak_script.sh SOURCE_DIR BUILD_DIR
set -euo pipefail
src=$1 build=$2
out=$(mktemp)
trap 'rm -f "$out"' EXIT
if ! "$src/bench/load_soak.sh" "$build" 1 10 "$src/weights/small.safetensors" Small 16x16 \
     > "$out" 2>&1; then
  cat "$out"
  echo "FAIL: load_soak.sh exited non-zero"
  exit 1
fi
cat "$out"
point=$(grep -v 'warm-up:' "$out" | sed -n 's/^ *requests sent \([0-9]*\)  answered \([0-9]*\) .*/\1 \2/p' | tail -1)
verdict=$(sed -n 's/^load exit status 0; requests sent \([0-9]*\), answered \([0-9]*\), unanswered 0, errors 0; warm-up: requests sent \([0-9]*\), errors 0$/\1 \2 \3/p' "$out")
warm=$(sed -n 's/.*warm-up: requests sent \([0-9]*\) .*/\1/p' "$out" | tail -1)
read -r psent panswered <<< "$point"
read -r vsent vanswered vwarm <<< "${verdict:-x x x}"
if [ "$vsent" != "$psent" ] || [ "$vanswered" != "$panswered" ] || [ "$vsent" != "$vanswered" ] ||
   [ "$vwarm" != "$warm" ]; then
  echo "FAIL: the verdict line does not give the point's requests ($psent sent, $panswered answered) and the warm-up's ($warm)"
  exit 1
fi
grep -q '^soak passed' "$out" || { echo "FAIL: no 'soak passed' line"; exit 1; }
echo "PASS"
