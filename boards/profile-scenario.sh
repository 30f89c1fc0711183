#!/usr/bin/env bash
# The per-function profile of one self-test scenario on the Cortex-M4F (QEMU mps2-an386): which functions
# execute the instructions of that sensor pattern alone (boards/measure.sh's PROFILE=1 sums every scenario).
# Usage: boards/profile-scenario.sh N     (N = the scenario's number, as in measure.sh's `scenario N` rows)
# Builds the boards' firmware with ONLY_SCENARIO=N into its own target dir (never the golden firmware).
set -euo pipefail
[ $# -eq 1 ] || { echo "usage: $0 SCENARIO" >&2; exit 2; }
cd "$(dirname "$0")/qemu-mps2-an386"
ROOT=$(cd ../.. && pwd)
export RUSTFLAGS="--remap-path-prefix=$ROOT=/latentbki"
export CARGO_TARGET_DIR="$PWD/target/only-scenario"
HOST=$(rustc -vV | sed -n 's/^host: //p')
LLVM_BIN="$(rustc --print sysroot)/lib/rustlib/$HOST/bin"
OUT="$CARGO_TARGET_DIR/profile-$1"
mkdir -p "$OUT"
ONLY_SCENARIO=$1 cargo build --release --quiet
ELF="$CARGO_TARGET_DIR/thumbv7em-none-eabihf/release/latentbki-qemu-mps2-an386"
OUT="$OUT/insncount.so" plugin/build.sh
QEMU_PLUGIN="$OUT/insncount.so" QEMU_PLUGIN_ARGS="profile=on" QEMU_PLUGIN_LOG="$OUT/insn.log" \
  QEMU_SERIAL="$OUT/uart.bin" ./run-qemu.sh "$ELF" > "$OUT/stdout.txt"
grep '^scenario s=' "$OUT/stdout.txt" | cut -c1-200
"$LLVM_BIN/llvm-objdump" -d --no-show-raw-insn "$ELF" > "$OUT/firmware.dis"
python3 ../profile.py "$OUT/firmware.dis" "$OUT/insn.log"
