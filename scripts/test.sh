#!/usr/bin/env bash
# Every test: builds (installing dependencies if needed) and runs CTest.
# Tests that read ../shared/data fail when CI is set and the data is missing.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
# The Python packages tests use to make inputs (tests/requirements.txt), from PyPI.
if [ ! -x build/test-venv/bin/python ]; then
  python3 -m venv build/test-venv
fi
build/test-venv/bin/pip install -q -r tests/requirements.txt
ctest --test-dir build --output-on-failure --timeout 1200 "$@"
