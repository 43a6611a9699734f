#!/usr/bin/env bash
# The socket directory meets a daemon that is not root (docs/SERVER.md,
# "Socket directory"): run hairfilterd as an unprivileged user (nobody,
# through setpriv) with a Unix socket in a directory owned by root, as a
# kubelet-made hostPath or a hand-made /run/hairfilterd is, and a TCP
# listener. It must stop at once (status 1), before it is ready, with an
# error that names the directory, its owner and the fix; then, with the
# directory set up as documented (owned by the daemon's user), it must serve
# on both listeners; and a read-only directory is said to be one.
# usage: socket_dir_nonroot.sh HAIRFILTERD LOAD_CLIENT WEIGHTS_FILE
set -euo pipefail
daemon=$1 load=$2 weights=$3
[ "$(id -u)" -eq 0 ] || { echo "SKIP: needs root to run the daemon as another user"; exit 77; }
command -v setpriv >/dev/null || { echo "SKIP: no setpriv (util-linux)"; exit 77; }
uid=$(id -u nobody) gid=$(id -g nobody)
tmp=$(mktemp -d)
pid=
cleanup() { [ -n "$pid" ] && kill "$pid" 2>/dev/null; rm -rf "$tmp"; }
trap cleanup EXIT
chmod 0755 "$tmp"
install -m 0644 "$weights" "$tmp/small.safetensors"
install -d -o "$uid" -g "$gid" -m 0750 "$tmp/state"      # the daemon's ready file
run_as_nobody() {
  exec setpriv --reuid="$uid" --regid="$gid" --clear-groups -- "$daemon" --config none \
    --listen "unix:$tmp/run/hf.sock" --listen tcp:127.0.0.1:0 --no-auth \
    --weights "$tmp/small.safetensors" --backend cpu-ref --ready-file "$tmp/state/ready" "$@"
}

# 1. A root-owned directory: a clear error, status 1, never ready.
install -d -o root -g root -m 0755 "$tmp/run"
set +e
(run_as_nobody) > "$tmp/log1" 2>&1
status=$?
set -e
cat "$tmp/log1"
[ "$status" -eq 1 ] || { echo "FAIL: status $status, want 1"; exit 1; }
grep -q "cannot create a socket in $tmp/run (owner uid 0 gid 0, mode 0755)" "$tmp/log1"
grep -q "install -d -o $uid -g $gid -m 0750 $tmp/run" "$tmp/log1"
[ ! -e "$tmp/state/ready" ] || { echo "FAIL: a ready file was written"; exit 1; }

# 2. The documented setup: the directory belongs to the daemon's user.
rm -rf "$tmp/run"
install -d -o "$uid" -g "$gid" -m 0750 "$tmp/run"
run_as_nobody > "$tmp/log2" 2>&1 &
pid=$!
for _ in $(seq 1 300); do [ -s "$tmp/state/ready" ] && break; sleep 0.1; done
[ -s "$tmp/state/ready" ] || { cat "$tmp/log2"; echo "FAIL: not ready"; exit 1; }
unix=$(grep '^unix:' "$tmp/state/ready") tcp=$(grep '^tcp:' "$tmp/state/ready")
"$load" --server "$unix" --variant Small --spp 4 --size 16x16 --count 3 | tee "$tmp/u"
"$load" --server "$tcp" --variant Small --spp 4 --size 16x16 --count 3 | tee "$tmp/t"
grep -q '"OK": 3' "$tmp/u" && grep -q '"OK": 3' "$tmp/t"
kill -TERM "$pid"
status=0
wait "$pid" || status=$?
pid=
[ "$status" -eq 0 ] || { cat "$tmp/log2"; echo "FAIL: exit status $status after SIGTERM"; exit 1; }
# 3. A read-only directory (a container run with a read-only root file
# system, where /run/hairfilterd is the image's): status 1, the read-only
# file system named and a writable mount as the fix, not an owner or mode
# (install -d cannot help there). Needs a mount namespace to make one.
install -d -o "$uid" -g "$gid" -m 0750 "$tmp/ro"
if unshare -m true 2>/dev/null; then
  set +e
  unshare -m sh -c "mount --bind -o ro '$tmp/ro' '$tmp/ro' && \
    setpriv --reuid=$uid --regid=$gid --clear-groups -- '$daemon' --config none \
      --listen 'unix:$tmp/ro/hf.sock' --weights '$tmp/small.safetensors' --backend cpu-ref" \
    > "$tmp/log3" 2>&1
  status=$?
  set -e
  cat "$tmp/log3"
  [ "$status" -eq 1 ] || { echo "FAIL: read-only directory: status $status, want 1"; exit 1; }
  grep -q "$tmp/ro is on a read-only file system" "$tmp/log3"
  grep -q -- "--tmpfs $tmp/ro:uid=$uid,gid=$gid,mode=0750" "$tmp/log3"
  if grep -q "install -d" "$tmp/log3"; then
    echo "FAIL: read-only directory: the fix offered is an owner and mode"; exit 1
  fi
else
  echo "(the read-only directory is not checked: no mount namespace here)"
fi
echo "1 passed, 0 failed"
