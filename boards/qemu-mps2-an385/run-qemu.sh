#!/usr/bin/env bash
# Cargo runner for QEMU mps2-an385 (a Cortex-M3 running the thumbv6m build): run-qemu.sh <elf> [qemu args...]
# Everything else (exit code, stdout, QEMU_SERIAL, QEMU_PLUGIN…) as in ../qemu-run.sh.
exec "$(dirname "$0")/../qemu-run.sh" "qemu-system-arm -M mps2-an385 -cpu cortex-m3" "$@"
