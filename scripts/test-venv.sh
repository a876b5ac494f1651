#!/usr/bin/env bash
# The Python packages tests and fuzz seeds use to make inputs
# (tests/requirements.txt, from PyPI) in BUILD_DIR/test-venv.
# Usage: scripts/test-venv.sh BUILD_DIR
set -euo pipefail
cd "$(dirname "$0")/.."
venv="${1:?usage: scripts/test-venv.sh BUILD_DIR}/test-venv"
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/pip" install -q -r tests/requirements.txt
