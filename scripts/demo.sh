#!/usr/bin/env bash
# The main job on the built-in default scene: build its tile set, verify it,
# render it with object-space EWA splatting (Vulkan; lavapipe without a GPU) to
# out/scene.png, serve it over HTTP on loopback, fetch tileset.json and a block
# through the server as a check, and stream it from the server with level of
# detail to out/streamed.png. With a display (and SURFCAST_DEMO_WINDOW=1) it
# also opens the viewer window.
# Usage: scripts/demo.sh [OUT_DIR]   (default: out/)
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-out}"
scripts/setup.sh --demo
echo
echo "== building the default scene's tile set into $out/sets/scene"
build/bin/surfcast-build --default-scene -o "$out/sets/scene"
echo
echo "== verifying it"
build/bin/surfcast-build --info "$out/sets/scene"
echo
echo "== rendering it (ewa-pixel, 1280x720) to $out/scene.png"
build/bin/surfcast-view --headless "$out/sets/scene" --out "$out/scene.png"
if [ -n "${DISPLAY:-}${WAYLAND_DISPLAY:-}" ] && [ "${SURFCAST_DEMO_WINDOW:-0}" = 1 ]; then
  echo "== opening the viewer (Esc closes it)"
  build/bin/surfcast-view "$out/sets/scene"
fi
echo
echo "== serving $out/sets on loopback"
log="$out/serve.log"
build/bin/surfcast-serve "$out/sets" --bind 127.0.0.1:0 2> "$log" &
server=$!
trap 'kill $server 2>/dev/null || true' EXIT
for _ in $(seq 50); do grep -q "http://" "$log" && break; sleep 0.1; done
url=$(grep -o "http://[0-9.:]*" "$log" | head -n 1)
[ -n "$url" ] || { cat "$log"; exit 1; }
echo "server: $url"
echo "browser viewer: $url/?set=/sets/scene (while the demo runs; afterwards: build/bin/surfcast-serve $out/sets)"
curl -fsS -o "$out/sets.json" "$url/sets"
echo "GET /sets: $(grep -c '"name"' "$out/sets.json") tile set(s)"
curl -fsS -o "$out/tileset.json" "$url/sets/scene/tileset.json"
echo "fetched tileset.json: $(wc -c < "$out/tileset.json") bytes"
curl -fsS -o "$out/root.block" "$url/sets/scene/nodes/0-0-0-0"
# A draco-columns block (docs/FORMAT.md, "blocks.bin"): a u32 length, then the positions' Draco cloud.
echo "fetched the root block (node 0-0-0-0): $(wc -c < "$out/root.block") bytes, its positions a Draco cloud of" \
     "$(od -An -tu4 -N4 "$out/root.block" | tr -d ' ') bytes starting $(tail -c +5 "$out/root.block" | head -c 5)"
echo
echo "== streaming it from the server (level of detail 1 px) to $out/streamed.png"
build/bin/surfcast-view --headless "$url/sets/scene" --lod 1 --out "$out/streamed.png" > "$out/streamed.jsonl"
python3 - "$out/streamed.jsonl" <<'PY'
import json, sys
lines = [json.loads(l) for l in open(sys.argv[1]) if l.startswith("{")]
first = next((l for l in lines if l["splats"] > 0), lines[-1])
last = lines[-1]
print(f"first image after {first['time_s']:.2f} s ({first['splats']} splats); converged={last['converged']} after "
      f"{last['time_s']:.2f} s: {last['nodes']} nodes, {last['splats']} splats, "
      f"{last['bytes_downloaded'] / 1e6:.1f} MB in {last['requests']} requests, {last['failures']} failures")
PY
kill -TERM $server
wait $server
trap - EXIT
echo "== server log"
cat "$log"
