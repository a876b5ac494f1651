#!/usr/bin/env bash
# Installs what Surfcast needs from Debian's packages (idempotent; run as root on
# a fresh Debian 12, or with sudo available), then configures and builds.
# Usage: scripts/setup.sh [--no-build] [--clang] [--demo]
#   --no-build  install only
#   --clang     also clang, its sanitizer runtimes and LLVM's OpenMP runtime
#               (the asan and tsan presets)
#   --demo      only what the programs and scripts/demo.sh need: no test
#               packages (Chromium, nginx, Xvfb, GoogleTest, cpp-httplib, the
#               Python venv, SeaweedFS), no test or benchmark programs, and the browser
#               viewer's build tools without the tests' (npm --omit=dev)
set -euo pipefail
cd "$(dirname "$0")/.."

packages=(
  build-essential cmake ninja-build pkg-config git zlib1g-dev
  libcli11-dev libdraco-dev libopenmesh-dev libflann-dev liblz4-dev libeigen3-dev libmeshoptimizer-dev
  libglfw3-dev libvulkan-dev mesa-vulkan-drivers vulkan-validationlayers glslang-tools
  libmicrohttpd-dev libcurl4-openssl-dev nlohmann-json3-dev libstb-dev curl python3
)
# What the tests and benchmarks add.
test_packages=(libcpp-httplib-dev libgtest-dev python3-venv xvfb xdotool nginx-light chromium)
# Node.js and npm build the browser viewer (web/): any node on PATH (the
# machines here have 20 from a configured source), else Debian's (18).
command -v node >/dev/null 2>&1 || packages+=(nodejs)
command -v npm >/dev/null 2>&1 || packages+=(npm)
# A Rust toolchain for the LAZ and E57 readers (preprocess/readers/laz_ffi): any
# cargo on PATH of Rust 1.73 or newer, else Debian's rustc-web (1.85 or newer;
# Debian 12's plain rustc is 1.63, older than the e57 crate needs).
rust_minor=$(cargo --version 2>/dev/null | sed -n 's/^cargo 1\.\([0-9]*\).*/\1/p')
[ "${rust_minor:-0}" -ge 73 ] || packages+=(cargo-web rustc-web)
build=1 demo=0
for arg in "$@"; do
  case "$arg" in
    --no-build) build=0 ;;
    --clang) packages+=(clang libclang-rt-14-dev libomp-14-dev) ;;
    --demo) demo=1 ;;
    *) echo "usage: scripts/setup.sh [--no-build] [--clang] [--demo]" >&2; exit 2 ;;
  esac
done
((demo)) || packages+=("${test_packages[@]}")
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "setup: installing ${missing[*]}"
  sudo_cmd=()
  [ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
  export DEBIAN_FRONTEND=noninteractive
  "${sudo_cmd[@]}" apt-get update -q
  "${sudo_cmd[@]}" apt-get install -y -q --no-install-recommends "${missing[@]}"
fi

((build)) || exit 0
# Both ways are said outright: the one build folder serves both.
with_tests=$( ((demo)) && echo OFF || echo ON )
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE="${BUILD_TYPE:-Release}" -DSURFCAST_TESTS="$with_tests" \
  -DSURFCAST_BENCH="$with_tests" ${CMAKE_ARGS:-}
cmake --build build --parallel
# The object-store tests' real S3 server (a Go build: minutes on a fresh machine).
((demo)) || scripts/install-seaweedfs.sh
