#!/usr/bin/env bash
# Installs everything hairfilter needs to build, test, render and train on
# Debian 12. Idempotent; run as root (or with sudo).
set -euo pipefail

packages=(
  build-essential cmake pkg-config git
  libcjson-dev libopenexr-dev libpng-dev libuv1-dev libcmocka-dev
  libdnnl-dev libosmesa6-dev
  python3 python3-numpy python3-torch libopenblas0-openmp python3-openimageio
  libegl-dev libassimp-dev
)

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
