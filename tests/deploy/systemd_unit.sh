#!/usr/bin/env bash
# deploy/systemd/hairfilterd.service passes `systemd-analyze verify` (with
# ExecStart pointed at the binary just built) and its exposure level by
# `systemd-analyze security` is below 3 (--threshold counts tenths).
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
echo "1 passed, 0 failed"
