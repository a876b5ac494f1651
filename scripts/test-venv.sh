#!/usr/bin/env bash
# The Python packages tests and fuzz seeds use to make inputs
# (tests/requirements.txt, from PyPI) in build/test-venv: one for every build
# folder of the checkout (SURFCAST_TEST_VENV in tests/CMakeLists.txt), made
# once by whichever stage runs first.
# Usage: scripts/test-venv.sh
set -euo pipefail
cd "$(dirname "$0")/.."
venv=build/test-venv
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/pip" install -q -r tests/requirements.txt
