#!/usr/bin/env bash
# Installs what rolamos needs on Debian 12 (when missing) and builds it in Release into build/.
# Safe to run again: apt-get and the build are skipped when already done.
set -euo pipefail
cd "$(dirname "$0")/.."

PACKAGES=(
  build-essential cmake ninja-build pkg-config clang-14 libclang-rt-14-dev
  libopencv-dev libeigen3-dev libceres-dev libtiff-dev libtiff-tools libgdal-dev gdal-bin python3-gdal
  libopenimageio-dev openimageio-tools libvips-tools
  libgtest-dev libgmock-dev libbenchmark-dev libcli11-dev nlohmann-json3-dev libcpp-httplib-dev
  libzstd-dev libwebp-dev libjpeg-dev time wrk curl
  slurm-wlm munge python3-numpy
  chromium
  gstreamer1.0-tools gstreamer1.0-plugins-base gstreamer1.0-plugins-good
  pybind11-dev python3-dev python3-pytest python3-rasterio python3-matplotlib python3-pil
)

# QGIS's Python bindings for the QGIS client test, on request (a large install): ROLAMOS_WITH_QGIS=1.
[ "${ROLAMOS_WITH_QGIS:-0}" = 1 ] && PACKAGES+=(python3-qgis)

missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
# Node.js and npm from Debian unless some other install already provides them.
command -v npm >/dev/null 2>&1 || missing+=(nodejs npm)
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing ${missing[*]}" >&2
  SUDO=""
  [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# The viewer's front-end packages, pinned by viewer/package-lock.json (OpenSeadragon is built into
# the binary; playwright-core drives Debian's Chromium in the browser tests).
if [ ! -d viewer/node_modules/openseadragon ] || [ ! -d viewer/node_modules/leaflet ] || [ ! -d viewer/node_modules/playwright-core ] ||
   [ viewer/package-lock.json -nt viewer/node_modules/.package-lock.json ]; then
  (cd viewer && npm ci --no-audit --no-fund --loglevel=error >/dev/null)
fi

# clang builds everything so that the libFuzzer targets can be part of the test suite.
if [ ! -f build/build.ninja ]; then
  cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release \
        -DCMAKE_C_COMPILER=clang-14 -DCMAKE_CXX_COMPILER=clang++-14 >/dev/null
fi
cmake --build build -j "$(nproc)"
