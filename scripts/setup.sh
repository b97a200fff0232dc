#!/usr/bin/env bash
# Installs every Debian package visloc needs (idempotent; run as root or with
# sudo available) and builds it in Release into build/.
#   scripts/setup.sh            install + configure + build
#   SKIP_APT=1 scripts/setup.sh build only
set -euo pipefail
cd "$(dirname "$0")/.."

PACKAGES=(
  build-essential cmake ninja-build pkg-config git
  libeigen3-dev libopencv-dev
  libopenblas-dev libfaiss-dev
  colmap
  libgeographiclib-dev libexiv2-dev libsqlite3-dev sqlite3
  libcli11-dev nlohmann-json3-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  slurm-wlm munge
  pybind11-dev python3-dev python3-numpy python3-pytest
)

if [ "${SKIP_APT:-0}" != "1" ]; then
  missing=()
  for p in "${PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if [ ${#missing[@]} -gt 0 ]; then
    echo "setup: installing ${#missing[@]} Debian packages: ${missing[*]}"
    SUDO=""
    if [ "$(id -u)" != "0" ]; then SUDO="sudo"; fi
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  else
    echo "setup: all ${#PACKAGES[@]} Debian packages present"
  fi
fi

JOBS="${JOBS:-$(nproc)}"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release ${CMAKE_ARGS:-}
cmake --build build -j "$JOBS"
echo "setup: built build/src/visloc/cli/visloc"
