#!/usr/bin/env bash
# Cargo runner for QEMU mps2-an386: run-qemu.sh <elf> [extra qemu args...]
# Exit code = the firmware's semihosting exit code (124 = timeout). Semihosting stdout goes to stdout.
# Env:
#   QEMU_TIMEOUT     seconds before giving up (default 300)
#   QEMU_SERIAL      file receiving the raw UART0 bytes (default: <elf>.uart.bin)
#   QEMU_PLUGIN      path to the insncount plugin (.so); its log goes to QEMU_PLUGIN_LOG (default <elf>.insn.log)
#   QEMU_PLUGIN_ARGS extra plugin arguments, comma separated (regions=on, profile=on)
set -u
elf="$1"; shift
command -v qemu-system-arm >/dev/null || { echo "run-qemu.sh: qemu-system-arm not found (apt-get install qemu-system-arm)" >&2; exit 127; }
serial="${QEMU_SERIAL:-$elf.uart.bin}"
args=(-M mps2-an386 -cpu cortex-m4 -display none -monitor none
      -semihosting-config enable=on,target=native
      -serial "file:$serial" -kernel "$elf")
if [ -n "${QEMU_PLUGIN:-}" ]; then
  plugin="$QEMU_PLUGIN"
  [ -n "${QEMU_PLUGIN_ARGS:-}" ] && plugin="$plugin,${QEMU_PLUGIN_ARGS}"
  args+=(-icount shift=0 -plugin "$plugin" -d plugin -D "${QEMU_PLUGIN_LOG:-$elf.insn.log}")
fi
# </dev/null: QEMU must not own the terminal or read stdin.
timeout --foreground -k 5 "${QEMU_TIMEOUT:-300}" qemu-system-arm "${args[@]}" "$@" </dev/null
