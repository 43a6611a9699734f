#!/bin/sh
# A --ready-file on a full file system: hairfilterd stops at start (exit 1)
# before any model is built, and says the file system is full and what to
# do; the socket it would have served on is not left behind. It used to
# build every model, log "serving", then stop with "No space left on
# device" alone, since an empty file needs no room and only the write
# after the models met the full disk.
#
# The full file system is a 4 KiB tmpfs, filled, in a mount namespace of
# this test's own (unshare; as root, or through a user namespace), so
# nothing outside the test sees it. Skips (77) where neither works.
#
# usage: ready_file_full.sh HAIRFILTERD WEIGHTS.safetensors
set -u
hfd=$1 weights=$2

if [ "${HF_READY_FULL_INNER:-}" != 1 ]; then
  for how in "-m" "-r -m"; do
    # shellcheck disable=SC2086
    if unshare $how true 2>/dev/null; then
      HF_READY_FULL_INNER=1 exec unshare $how "$0" "$@"
    fi
  done
  echo "SKIP: no mount namespace (unshare -m or -r -m) here"
  exit 77
fi

w=$(mktemp -d /tmp/hf-ready-full.XXXXXX) || exit 1
trap 'umount "$w/full" 2>/dev/null; rm -rf "$w"' EXIT
mkdir "$w/full"
if ! mount -t tmpfs -o size=4k tmpfs "$w/full" 2>/dev/null; then
  echo "SKIP: cannot mount a tmpfs in this namespace"
  exit 77
fi
dd if=/dev/zero of="$w/full/fill" bs=1024 count=64 2>/dev/null
# The fill stops where the tmpfs is full: no byte more can be written.
if (printf x > "$w/full/probe") 2>/dev/null && [ -s "$w/full/probe" ]; then
  echo "SKIP: the tmpfs did not fill"
  exit 77
fi
rm -f "$w/full/probe"

fail=0
timeout -k 5 60 "$hfd" --config none --listen "unix:$w/d.sock" --backend cpu-ref \
  --weights "$weights" --ready-file "$w/full/ready" > "$w/log" 2>&1
rc=$?
cat "$w/log"
if [ "$rc" -ne 1 ]; then
  echo "FAIL: exit status $rc, not 1"
  fail=1
fi
if ! grep -q "error: --ready-file $w/full/ready: .*No space left on device; the file system it is on is full.*free space there, or give a path on another file system" "$w/log"; then
  echo "FAIL: no error saying the file system is full and what to do"
  fail=1
fi
if grep -q "variant \|serving:" "$w/log"; then
  echo "FAIL: models were built (or serving said) before the full file system stopped the start"
  fail=1
fi
if [ -e "$w/d.sock" ] || ls "$w/full" | grep -q "ready"; then
  echo "FAIL: a socket or ready file was left behind"
  fail=1
fi
[ "$fail" -eq 0 ] && echo "PASS"
exit "$fail"
