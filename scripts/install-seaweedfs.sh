#!/usr/bin/env bash
# Builds SeaweedFS's `weed` (Apache-2.0), the real S3 server the object-store
# tests start, from its Go module into build/seaweedfs/weed (once: an existing
# binary of this version is kept). `go install` refuses the module (its
# go.mod has replace directives), so it is downloaded and built in place.
# Needs Go 1.26 or newer on PATH, or Debian's golang-go where that is new enough.
set -euo pipefail
cd "$(dirname "$0")/.."
version=v0.0.0-20261109003541-7506e5f91cd6
out=build/seaweedfs
if [ -x "$out/weed" ] && [ "$(cat "$out/version" 2>/dev/null)" = "$version" ]; then exit 0; fi
command -v go >/dev/null 2>&1 || PATH="$PATH:/usr/local/go/bin"
if ! command -v go >/dev/null 2>&1; then
  echo "install-seaweedfs: no Go toolchain on PATH (SeaweedFS needs Go 1.26 or newer)" >&2
  exit 1
fi
mkdir -p "$out"
start=$SECONDS
dir=$(go mod download -json "github.com/seaweedfs/seaweedfs@$version" | python3 -c 'import json,sys; print(json.load(sys.stdin)["Dir"])')
(cd "$dir" && GOFLAGS=-mod=mod go build -o "$OLDPWD/$out/weed.partial" ./weed)
mv "$out/weed.partial" "$out/weed"
echo "$version" > "$out/version"
echo "install-seaweedfs: built $out/weed in $((SECONDS - start)) s"
