#!/usr/bin/env bash
# The main job on the built-in default scene: build its tile set, then print and
# verify the summary. Usage: scripts/demo.sh [OUT_DIR]   (default: out/)
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-out}"
scripts/setup.sh
echo
echo "== building the default scene's tile set into $out/scene"
build/bin/surfcast-build --default-scene -o "$out/scene"
echo
echo "== verifying it"
build/bin/surfcast-build --info "$out/scene"
