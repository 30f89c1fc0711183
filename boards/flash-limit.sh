# Sourced by measure.sh and measure-targets.sh: the flash budgets of issue 32, one per build.
#   full build     the boards' build (their default feature `full`: every `latentbki` feature the demo's
#                  robot uses, latentbki_selftest::BOARD_FEATURES): ≤ 96 KiB, FLASH_LIMIT_FULL
#   minimal build  the same board with `--no-default-features`: what a firmware author gets with
#                  `latentbki`'s `default-features = false`: ≤ 64 KiB, FLASH_LIMIT_MINIMAL
#   flash_bytes ELF                 what the image stores: code, read-only data, unwind tables, .data's
#                                   initial values
#   check_flash_limit WHAT ELF LIMIT  prints one line; returns 1 when the flash exceeds LIMIT (bytes)
#   build_minimal                   from a board's directory: builds its minimal build in its own target
#                                   dir (target/minimal: never the shipped ELF) and prints the ELF's path
# The limits (bytes) can be overridden to see the failure path, e.g.
# `FLASH_LIMIT_MINIMAL=60000 bash boards/measure.sh --size`.
FLASH_LIMIT_FULL=${FLASH_LIMIT_FULL:-98304}
FLASH_LIMIT_MINIMAL=${FLASH_LIMIT_MINIMAL:-65536}

flash_bytes() {
  "$LLVM_BIN/llvm-size" -A -d "$1" |
    awk '$1 ~ /^\.(vector_table|text|init\.rust|rodata|eh_frame|data)$/ { f += $2 } END { print f + 0 }'
}

check_flash_limit() {
  local what=$1 flash limit=$3
  flash=$(flash_bytes "$2")
  if [ "$flash" -gt "$limit" ]; then
    echo "flash over the limit: $what: $flash B > $limit B (by $((flash - limit)) B)" >&2
    return 1
  fi
  echo "flash within the limit: $what: $flash B ≤ $limit B ($((limit - flash)) B spare)"
}

build_minimal() {
  CARGO_TARGET_DIR="$PWD/target/minimal" \
    cargo build --release --quiet --no-default-features --message-format=json-render-diagnostics |
    python3 -c 'import json,sys; print([m["executable"] for m in map(json.loads, sys.stdin) if m.get("executable")][-1])'
}
