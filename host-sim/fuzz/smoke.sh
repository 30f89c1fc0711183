#!/usr/bin/env bash
# A few seconds of each fuzz target (CI smoke). Needs a nightly toolchain; installs cargo-fuzz if missing.
# Usage: bash host-sim/fuzz/smoke.sh [seconds per target, default 5]
set -euo pipefail
cd "$(dirname "$0")/../.."
SECONDS_PER_TARGET="${1:-5}"
if ! command -v cargo-fuzz >/dev/null 2>&1; then
  cargo install cargo-fuzz --locked
fi
rustup toolchain list | grep -q '^nightly' || rustup toolchain install nightly --profile minimal
for target in frame_decoder roundtrip map_integrate base_station_db ack_reader; do
  echo "--- fuzz $target (${SECONDS_PER_TARGET} s)"
  cargo +nightly fuzz run --fuzz-dir host-sim/fuzz "$target" -- \
    -max_total_time="$SECONDS_PER_TARGET" -rss_limit_mb=2048
done
