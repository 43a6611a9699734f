#!/bin/bash
# tools/gpu-run/tree_size.sh counts what the device tool carries (tracked
# files, untracked ones git does not ignore, the carried paths; not the
# ignored ones, not a tracked file deleted since) and refuses a total over
# LIMIT_MB, saying so.
#
#   tests/gpu/tree_size.sh REPO_ROOT
set -u
ROOT=${1:?usage: tree_size.sh REPO_ROOT}
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
fail() {
  echo "FAIL: $*"
  exit 1
}
cd "$T" || exit 1
git init -q . && git config user.email t@t && git config user.name t
head -c 3145728 /dev/zero > tracked.bin
head -c 1000 /dev/zero > gone.bin
echo "/ignored/" > .gitignore
git add tracked.bin gone.bin .gitignore && git commit -qm init
rm gone.bin
head -c 1048576 /dev/zero > untracked.bin
mkdir ignored carry
head -c 5242880 /dev/zero > ignored/big.bin
head -c 2097152 /dev/zero > ignored/carried.bin
want_tree=$((3145728 + 1048576 + $(stat -c %s .gitignore)))
out=$("$ROOT/tools/gpu-run/tree_size.sh" ignored/carried.bin) || fail "refused under the limit: $out"
[ "$out" = "tree $want_tree carried 2097152 total $((want_tree + 2097152)) limit 67108864" ] ||
  fail "counted '$out', want tree $want_tree carried 2097152"
err=$(LIMIT_MB=5 "$ROOT/tools/gpu-run/tree_size.sh" ignored/carried.bin 2>&1 >/dev/null) &&
  fail "6 MiB passed a 5 MiB limit"
case $err in
  *"over the device tool's 5 MiB"*) ;;
  *) fail "the refusal does not say why: $err" ;;
esac
echo "PASS: tree_size.sh counts the carried tree and refuses one over the limit"
