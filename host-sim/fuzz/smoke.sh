#!/usr/bin/env bash
# Every fuzz target for a short run from the committed seed corpus (seeds/<target>/, written by
# `cargo run --release -p host-sim --example fuzz_seeds`); fails on a crash, leak or timeout, and the
# crashing input is left in host-sim/fuzz/artifacts/<target>/. CI's `fuzz` job runs it with 15 s per target.
# Needs a nightly toolchain and cargo-fuzz; installs both if missing.
# Usage: bash host-sim/fuzz/smoke.sh [seconds per target, default 5]
set -euo pipefail
cd "$(dirname "$0")/../.."
SECONDS_PER_TARGET="${1:-5}"
rustup toolchain list | grep -q '^nightly' || rustup toolchain install nightly --profile minimal
if ! command -v cargo-fuzz >/dev/null 2>&1; then
  cargo install cargo-fuzz --locked
fi
# Every [[bin]] of the fuzz crate.
targets=$(sed -n 's/^name = "\(.*\)"/\1/p' host-sim/fuzz/Cargo.toml | grep -v '^latentbki-fuzz$')
# Build once, then run: the time limit is spent fuzzing, not compiling.
cargo +nightly fuzz build --fuzz-dir host-sim/fuzz
for target in $targets; do
  seeds="host-sim/fuzz/seeds/$target"
  [ -d "$seeds" ] || { echo "no seed corpus $seeds for fuzz target $target" >&2; exit 1; }
  # New inputs go to a scratch corpus (first directory); the committed seeds are only read.
  scratch=$(mktemp -d)
  echo "--- fuzz $target (${SECONDS_PER_TARGET} s, $(ls "$seeds" | wc -l) seeds)"
  log="$scratch.log"
  if ! cargo +nightly fuzz run --fuzz-dir host-sim/fuzz "$target" "$scratch" "$seeds" -- \
    -max_total_time="$SECONDS_PER_TARGET" -max_len=8192 -rss_limit_mb=2048 -print_final_stats=1 >"$log" 2>&1; then
    tail -n 60 "$log"
    echo "fuzz target $target failed; the input is in host-sim/fuzz/artifacts/$target/" >&2
    exit 1
  fi
  grep -E '^(#[0-9]+ +DONE|stat::number_of_executed_units|stat::peak_rss_mb)' "$log" || true
  rm -rf "$scratch" "$log"
done
