# Sourced by measure.sh and measure-targets.sh: the flash limit every measured firmware build must fit.
#   flash_bytes ELF            what the image stores: code, read-only data, unwind tables, .data's initial values
#   check_flash_limit WHAT ELF prints one line; returns 1 when the flash exceeds the limit
# FLASH_LIMIT (bytes, default 65,536 = 64 KiB, the budget of issue 12) overrides the limit, e.g.
# `FLASH_LIMIT=60000 bash boards/measure.sh --size` to see the failure path.
FLASH_LIMIT=${FLASH_LIMIT:-65536}

flash_bytes() {
  "$LLVM_BIN/llvm-size" -A -d "$1" |
    awk '$1 ~ /^\.(vector_table|text|init\.rust|rodata|eh_frame|data)$/ { f += $2 } END { print f + 0 }'
}

check_flash_limit() {
  local what=$1 flash
  flash=$(flash_bytes "$2")
  if [ "$flash" -gt "$FLASH_LIMIT" ]; then
    echo "flash over the limit: $what: $flash B > $FLASH_LIMIT B (by $((flash - FLASH_LIMIT)) B)" >&2
    return 1
  fi
  echo "flash within the limit: $what: $flash B ≤ $FLASH_LIMIT B ($((FLASH_LIMIT - flash)) B spare)"
}
