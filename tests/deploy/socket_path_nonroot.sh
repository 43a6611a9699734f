#!/usr/bin/env bash
# What is already at the socket path, or a directory the daemon cannot
# search, meets a daemon that is not root (nobody, through setpriv):
#
# 1. a directory it cannot search (root's, mode 0700): status 1 with the
#    directory, its owner and the fix; it stopped with no word at all;
# 2. a live root daemon's socket (mode 0755, so nobody may not connect) in
#    a directory anyone may write: status 1, saying it cannot tell whether
#    a server listens there; the root daemon keeps its socket. It took the
#    socket as stale, removed it and served there, cutting the live
#    daemon off from every new client;
# 3. a stale socket of root's in a sticky directory (as in /tmp), which
#    only its owner may remove: status 1 naming the owner and `rm PATH`;
#    it said "cannot remove stale socket PATH: Operation not permitted";
# 4. a stale socket it may remove: removed, and the daemon serves, then
#    stops on SIGTERM with status 0 (what it was doing is shown if not).
# usage: socket_path_nonroot.sh HAIRFILTERD WEIGHTS_FILE
set -uo pipefail
daemon=$1 weights=$2
[ "$(id -u)" -eq 0 ] || { echo "SKIP: needs root to run the daemon as another user"; exit 77; }
command -v setpriv >/dev/null || { echo "SKIP: no setpriv (util-linux)"; exit 77; }
uid=$(id -u nobody) gid=$(id -g nobody)
tmp=$(mktemp -d)
root_pid=
cleanup() { [ -n "$root_pid" ] && kill "$root_pid" 2>/dev/null; rm -rf "$tmp"; }
trap cleanup EXIT
chmod 0755 "$tmp"
install -m 0644 "$weights" "$tmp/small.safetensors"
fail=0
bad() { echo "FAIL: $*"; fail=1; }

# Runs the daemon as nobody on unix:$1 for at most 20 s; its status in
# $status, its log in $tmp/log.
as_nobody() {
  timeout -k 5 20 setpriv --reuid="$uid" --regid="$gid" --clear-groups -- "$daemon" --config none \
    --listen "unix:$1" --weights "$tmp/small.safetensors" --backend cpu-ref \
    > "$tmp/log" 2>&1
  status=$?
  cat "$tmp/log"
}
# A socket file with no server behind it.
stale_socket() {
  /usr/bin/python3 -c 'import socket, sys; socket.socket(socket.AF_UNIX).bind(sys.argv[1])' "$1"
}

# 1.
install -d -o root -g root -m 0700 "$tmp/priv"
as_nobody "$tmp/priv/hf.sock"
[ "$status" -eq 1 ] || bad "1: status $status, want 1"
grep -q "error: --listen unix:$tmp/priv/hf.sock: .*cannot create a socket in $tmp/priv (owner uid 0 gid 0, mode 0700).*install -d -o $uid -g $gid -m 0750 $tmp/priv" "$tmp/log" ||
  bad "1: no error naming the directory and the fix"

# 2.
install -d -o root -g root -m 0777 "$tmp/shared"
"$daemon" --config none --listen "unix:$tmp/shared/hf.sock" --weights "$tmp/small.safetensors" \
  --backend cpu-ref --ready-file "$tmp/root-ready" > "$tmp/root.log" 2>&1 &
root_pid=$!
for _ in $(seq 1 300); do [ -s "$tmp/root-ready" ] && break; sleep 0.1; done
[ -s "$tmp/root-ready" ] || { cat "$tmp/root.log"; bad "2: the root daemon did not start"; }
chmod 0755 "$tmp/shared/hf.sock"
ino=$(stat -c %i "$tmp/shared/hf.sock")
as_nobody "$tmp/shared/hf.sock"
[ "$status" -eq 1 ] || bad "2: status $status, want 1"
grep -q "cannot tell whether a server listens on it: connect: Permission denied (owner uid 0 gid 0, mode 0755); if no server uses it, remove it (rm $tmp/shared/hf.sock)" "$tmp/log" ||
  bad "2: no error saying it cannot tell"
[ "$(stat -c %i "$tmp/shared/hf.sock" 2>/dev/null)" = "$ino" ] ||
  bad "2: the live daemon's socket was removed or replaced"
kill "$root_pid"; wait "$root_pid"; root_pid=

# 3.
install -d -o root -g root -m 1777 "$tmp/sticky"
stale_socket "$tmp/sticky/hf.sock"
chmod 0777 "$tmp/sticky/hf.sock"
as_nobody "$tmp/sticky/hf.sock"
[ "$status" -eq 1 ] || bad "3: status $status, want 1"
grep -q "cannot remove the socket file left there by a server that is gone: Operation not permitted; hairfilterd runs as uid $uid and the file's owner is uid 0 .*rm $tmp/sticky/hf.sock" "$tmp/log" ||
  bad "3: no error naming the owner and rm"

# 4.
install -d -o "$uid" -g "$gid" -m 0750 "$tmp/own"
stale_socket "$tmp/own/hf.sock"
chown "$uid:$gid" "$tmp/own/hf.sock"
setpriv --reuid="$uid" --regid="$gid" --clear-groups -- "$daemon" --config none \
  --listen "unix:$tmp/own/hf.sock" --weights "$tmp/small.safetensors" --backend cpu-ref \
  > "$tmp/log" 2>&1 &
pid=$!
for _ in $(seq 1 200); do
  grep -q "listening on unix:$tmp/own/hf.sock" "$tmp/log" && break
  kill -0 "$pid" 2>/dev/null || break
  sleep 0.1
done
grep -q "listening on unix:$tmp/own/hf.sock" "$tmp/log" || bad "4: a stale socket it may remove stopped the start"
kill -TERM "$pid" 2>/dev/null
stopped=
for _ in $(seq 1 100); do kill -0 "$pid" 2>/dev/null || { stopped=1; break; }; sleep 0.1; done
if [ -z "$stopped" ]; then
  # What the daemon is doing, for a stop that does not come: each
  # thread's state and wait channel, and the process's signal masks.
  bad "4: the daemon did not stop within 10 s of SIGTERM"
  grep -E '^(State|Sig|ShdPnd)' "/proc/$pid/status"
  for task in /proc/"$pid"/task/*; do
    echo "thread ${task##*/} $(cat "$task/comm") $(cut -d' ' -f3 "$task/stat") $(cat "$task/wchan")"
    grep -E '^(SigPnd|SigBlk)' "$task/status"
  done
  kill -KILL "$pid"
fi
wait "$pid"
status=$?
[ -n "$stopped" ] && [ "$status" -ne 0 ] && bad "4: status $status after SIGTERM, want 0"
cat "$tmp/log"

[ "$fail" -eq 0 ] && echo PASS
exit "$fail"
