#!/usr/bin/env bash
# deploy/systemd/hairfilterd.service passes `systemd-analyze verify` (with
# ExecStart pointed at the binary just built) and its exposure level by
# `systemd-analyze security` is below 3 (--threshold counts tenths); it
# does not restart the daemon on the status of a bad option.
# usage: systemd_unit.sh UNIT HAIRFILTERD
set -euo pipefail
unit=$1 daemon=$2
command -v systemd-analyze >/dev/null || { echo "SKIP: no systemd-analyze"; exit 77; }
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
sed "s|/usr/local/bin/hairfilterd|$daemon|" "$unit" > "$tmp/hairfilterd.service"
grep -q '^Type=notify$' "$tmp/hairfilterd.service"
systemd-analyze verify "$tmp/hairfilterd.service"
systemd-analyze security --offline=yes --threshold=29 "$tmp/hairfilterd.service" | tail -1
# The check can fail: a unit without the hardening scores far above 3.
grep -v -E '^(Protect|Private|Restrict|SystemCall|Capability|Ambient|Device|NoNewPriv|Lock|Remove|Keyring|UMask)' \
  "$tmp/hairfilterd.service" > "$tmp/bare.service"
if systemd-analyze security --offline=yes --threshold=29 "$tmp/bare.service" >/dev/null 2>&1; then
  echo "FAIL: an unhardened unit passed the threshold"; exit 1
fi
# Bad options and config lines exit with 2 (docs/SERVER.md, "Options"):
# the unit must not restart on that status, which no restart can fix.
printf 'queue = 5\n' > "$tmp/bad.conf"
set +e
"$daemon" --config "$tmp/bad.conf" --listen "unix:$tmp/s.sock" --weights-dir "$tmp" >/dev/null 2>&1
status=$?
set -e
[ "$status" -eq 2 ] || { echo "FAIL: a bad config line gave status $status, not 2"; exit 1; }
grep -q "^RestartPreventExitStatus=.*\b$status\b" "$tmp/hairfilterd.service" ||
  { echo "FAIL: the unit restarts on status $status (a bad option), which no restart fixes"; exit 1; }
echo "1 passed, 0 failed"
