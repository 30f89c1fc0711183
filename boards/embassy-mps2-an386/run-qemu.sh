#!/usr/bin/env bash
# Cargo runner for QEMU mps2-an386 (Cortex-M4F): run-qemu.sh <elf> [extra qemu args...] (see ../qemu-run.sh).
exec "$(dirname "$0")/../qemu-run.sh" "qemu-system-arm -M mps2-an386 -cpu cortex-m4" "$@"
