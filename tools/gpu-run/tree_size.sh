#!/bin/bash
# What the device tool carries from this checkout, against its limit: the
# tracked files and the untracked ones git does not ignore (links as
# links), plus each carried path named, in bytes. Prints
#   tree BYTES carried BYTES total BYTES limit BYTES
# and exits 1, saying so, when the total is over LIMIT_MB (default 64):
# the device tool then refuses the call.
#
#   tools/gpu-run/tree_size.sh [CARRIED_PATH...]      # from the checkout
set -euo pipefail
limit=$(( ${LIMIT_MB:-64} * 1024 * 1024 ))
# A tracked file deleted in the working tree does not travel: stat skips
# it (its complaint discarded), the others are counted.
tree=$(git ls-files -z --cached --others --exclude-standard |
  { xargs -0 -r stat -c %s -- 2>/dev/null || true; } | awk '{ s += $1 } END { printf "%d", s }')
carried=0
for p in "$@"; do
  [ -e "$p" ] || continue
  carried=$((carried + $(du -sb -- "$p" | cut -f1)))
done
total=$((tree + carried))
echo "tree $tree carried $carried total $total limit $limit"
if [ "$total" -gt "$limit" ]; then
  echo "tree_size.sh: the working tree and the carried paths come to $((total >> 20)) MiB," \
       "over the device tool's ${LIMIT_MB:-64} MiB: the call would be refused; carry less or" \
       "make the tree smaller" >&2
  exit 1
fi
