#!/usr/bin/env bash
# Creates bench/.venv with the measurement harness's PyPI packages (idempotent).
set -euo pipefail
cd "$(dirname "$0")"
if [ ! -x .venv/bin/python ]; then
  python3 -m venv .venv
fi
.venv/bin/pip install -q -r requirements.txt
