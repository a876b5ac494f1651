#!/usr/bin/env bash
# Every test: builds (installing dependencies if needed) and runs CTest.
# Tests that read ../shared/data fail when CI is set and the data is missing.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
ctest --test-dir build --output-on-failure --timeout 1200 "$@"
