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
  chromium
)

SUDO=""
if [ "$(id -u)" != "0" ]; then SUDO="sudo"; fi
if [ "${SKIP_APT:-0}" != "1" ]; then
  missing=()
  for p in "${PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if [ ${#missing[@]} -gt 0 ]; then
    echo "setup: installing ${#missing[@]} Debian packages: ${missing[*]}"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  else
    echo "setup: all ${#PACKAGES[@]} Debian packages present"
  fi
fi

# The viewer's three.js, from npm at the version package-lock.json pins
# (built into the library; without it `visloc view` says how to get it).
VIEWER=src/visloc/viewer
json_field() {  # FILE KEY... → the value, or nothing
  command -v python3 >/dev/null 2>&1 || return 0
  python3 - "$@" <<'PY'
import json, sys
try:
    value = json.load(open(sys.argv[1]))
    for key in sys.argv[2:]:
        value = value[key]
    print(value)
except Exception:
    pass
PY
}
want=$(json_field "$VIEWER/package-lock.json" packages node_modules/three version)
have=$(json_field "$VIEWER/node_modules/three/package.json" version)
if ! command -v npm >/dev/null 2>&1 && [ "${SKIP_APT:-0}" != "1" ] && [ "$want" != "$have" ]; then
  echo "setup: installing Debian's npm for the viewer's three.js"
  $SUDO apt-get update -qq || true
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends npm >/dev/null ||
    echo "setup: WARNING: could not install npm" >&2
fi
if [ -n "$want" ] && [ "$want" = "$have" ]; then
  echo "setup: three.js $have present for the viewer"
elif command -v npm >/dev/null 2>&1; then
  echo "setup: npm ci in $VIEWER (three.js $want)"
  npm ci --prefix "$VIEWER" --no-audit --no-fund --loglevel=error || echo "setup: WARNING: npm ci failed; visloc view will be unavailable" >&2
else
  echo "setup: WARNING: npm is missing (Debian package npm); visloc view will be unavailable" >&2
fi

JOBS="${JOBS:-$(nproc)}"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release ${CMAKE_ARGS:-}
cmake --build build -j "$JOBS"
echo "setup: built build/src/visloc/cli/visloc"
