#!/usr/bin/env bash
# Runs a QEMU board's firmware: qemu-run.sh "<qemu-system-X> <machine args>" <elf> [extra qemu args...]
# (each board's run-qemu.sh, its cargo runner, calls this with its machine).
# Exit code = the firmware's semihosting exit code (124 = timeout). Semihosting stdout goes to stdout.
# Env:
#   QEMU_TIMEOUT     seconds before giving up (default 900: the thumbv6m self-test runs minutes of soft float on
#                    a loaded machine)
#   QEMU_SERIAL      file receiving the raw UART bytes (default: <elf>.uart.bin)
#   QEMU_PLUGIN      path to the insncount plugin (.so); its log goes to QEMU_PLUGIN_LOG (default <elf>.insn.log)
#   QEMU_PLUGIN_ARGS extra plugin arguments, comma separated (regions=on, profile=on)
set -u
read -r -a machine <<< "$1"; shift
elf="$1"; shift
command -v "${machine[0]}" >/dev/null || {
  echo "run-qemu.sh: ${machine[0]} not found (apt-get install qemu-system-arm qemu-system-misc)" >&2; exit 127; }
serial="${QEMU_SERIAL:-$elf.uart.bin}"
args=("${machine[@]:1}" -display none -monitor none
      -semihosting-config enable=on,target=native
      -serial "file:$serial" -kernel "$elf")
if [ -n "${QEMU_PLUGIN:-}" ]; then
  plugin="$QEMU_PLUGIN"
  [ -n "${QEMU_PLUGIN_ARGS:-}" ] && plugin="$plugin,${QEMU_PLUGIN_ARGS}"
  args+=(-icount shift=0 -plugin "$plugin" -d plugin -D "${QEMU_PLUGIN_LOG:-$elf.insn.log}")
fi
# </dev/null: QEMU must not own the terminal or read stdin.
timeout --foreground -k 5 "${QEMU_TIMEOUT:-900}" "${machine[0]}" "${args[@]}" "$@" </dev/null
