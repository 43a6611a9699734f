#!/usr/bin/env bash
# Installs everything hairfilter needs to build, test, render and train on
# Debian 12 (dpkg-dev and file: cpack -G DEB). Idempotent; run as root
# (or with sudo).
set -euo pipefail

packages=(
  build-essential cmake pkg-config git dpkg-dev file
  libcjson-dev libopenexr-dev libpng-dev zlib1g-dev libuv1-dev libcmocka-dev
  libmicrohttpd-dev libsystemd-dev libinih-dev
  # TLS listeners and tls: URLs (OpenSSL); the openssl command makes
  # certificates (docs/SERVER.md, "TLS").
  libssl-dev openssl
  libdnnl-dev libosmesa6-dev
  python3 python3-numpy python3-torch libopenblas0-openmp python3-openimageio
  libegl-dev libassimp-dev
  # hairfilterd's operator tests: promtool (the prometheus package, 19 MB)
  # and the Python client's parser read /metrics; npm installs the pinned
  # Kubernetes schema validator (deploy/kubernetes/validate).
  prometheus python3-prometheus-client
  # deploy.shipped_configs reads the Kubernetes ConfigMap's config file.
  python3-yaml
  # the fuzz targets (clang, libFuzzer) and hairfilter load's plot.
  clang libclang-rt-14-dev gnuplot-nox
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

# The prometheus package is installed for promtool; its server is not
# wanted on a development machine (where systemd runs it).
if printf '%s\n' "${missing[@]}" | grep -qx prometheus && [ -d /run/systemd/system ]; then
  ${SUDO:-} systemctl disable --now prometheus >/dev/null 2>&1 || true
fi

# The Kubernetes manifests' validator, at the versions package-lock.json pins.
here=$(cd "$(dirname "$0")/../.." && pwd)
if [ ! -d "$here/deploy/kubernetes/validate/node_modules/kubernetes-models" ]; then
  if ! command -v npm >/dev/null; then
    SUDO=""
    [ "$(id -u)" -eq 0 ] || SUDO="sudo"
    $SUDO apt-get install -y -qq --no-install-recommends nodejs npm
  fi
  npm ci --prefix "$here/deploy/kubernetes/validate" --no-audit --no-fund --loglevel=error
fi
