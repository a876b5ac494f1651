#!/usr/bin/env bash
# The main job on the built-in default scene: build its tile set, verify it,
# serve it over HTTP on loopback and fetch tileset.json and a block through the
# server as a check. (Rendering through HTTP comes with the streaming client.)
# Usage: scripts/demo.sh [OUT_DIR]   (default: out/)
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-out}"
scripts/setup.sh
echo
echo "== building the default scene's tile set into $out/sets/scene"
build/bin/surfcast-build --default-scene -o "$out/sets/scene"
echo
echo "== verifying it"
build/bin/surfcast-build --info "$out/sets/scene"
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
curl -fsS -o "$out/sets.json" "$url/sets"
echo "GET /sets: $(grep -c '"name"' "$out/sets.json") tile set(s)"
curl -fsS -o "$out/tileset.json" "$url/sets/scene/tileset.json"
echo "fetched tileset.json: $(wc -c < "$out/tileset.json") bytes"
curl -fsS -o "$out/root.drc" "$url/sets/scene/nodes/0-0-0-0"
echo "fetched the root block (node 0-0-0-0): $(wc -c < "$out/root.drc") bytes, starts with $(head -c 5 "$out/root.drc")"
kill -TERM $server
wait $server
trap - EXIT
echo "== server log"
cat "$log"
