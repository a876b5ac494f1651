#!/usr/bin/env bash
# Every test: builds (installing dependencies if needed) and runs CTest, two
# tests at a time (tests/CMakeLists.txt says which run alone and why).
# Tests that read ../shared/data fail when CI is set and the data is missing.
# Further arguments go to ctest (e.g. -R stream_test).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
scripts/test-venv.sh
# Two tests share the two cores: an OpenMP thread with nothing to do sleeps
# rather than spinning on the other test's core (LLVM's runtime, the sanitizer
# builds', spins 200 ms by default, GCC's a shorter while:
# bench/RELIABILITY.md, "CI stages").
export OMP_WAIT_POLICY="${OMP_WAIT_POLICY:-passive}"
ctest --test-dir build --output-on-failure --timeout 1200 -j "${CTEST_PARALLEL_LEVEL:-2}" "$@"
