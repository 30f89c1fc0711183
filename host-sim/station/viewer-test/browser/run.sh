#!/usr/bin/env bash
# The map in a real viewer: Lichtblick's web build (the open-source Foxglove Studio) in headless Chromium, on
# the live view of `host-sim demo --view` and on its `--record` recording, with checks on the 3D panels'
# pixels and the app's alerts; writes docs/viewer/live.png, recording-open.png, -middle.png, -end.png
# (browser.js says what it checks). Not in CI: the Lichtblick build comes from no registry CI reaches;
# LICHTBLICK_TGZ names it (default: the copy this workplace keeps in /work/shared/viewer).
# Installs Debian's chromium and the pinned npm packages if missing; takes ≈ 4 minutes (the demo runs once).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
repo="$(cd "$here/../../../.." && pwd)"
tgz="${LICHTBLICK_TGZ:-/work/shared/viewer/lichtblick-web-v1.22.0.tar.gz}"
[ -f "$tgz" ] || { echo "no Lichtblick web build at $tgz: set LICHTBLICK_TGZ" >&2; exit 1; }
command -v chromium >/dev/null || { apt-get update && apt-get install -y chromium; }
(cd "$here" && npm ci --no-audit --no-fund)
(cd "$repo" && cargo build --release -p host-sim)
exec node "$here/browser.js" --host-sim "$repo/target/release/host-sim" --lichtblick "$tgz" \
  --shots "$repo/docs/viewer" "$@"
