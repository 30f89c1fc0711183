#!/usr/bin/env bash
# Cargo runner for QEMU riscv32 virt (one hart; `-bios none`: the reset ROM jumps straight to the ELF at
# 0x8000_0000): run-qemu.sh <elf> [qemu args...]. Everything else (exit code, stdout, QEMU_SERIAL,
# QEMU_PLUGIN…) as in ../qemu-run.sh. UART = the NS16550A at 0x1000_0000.
exec "$(dirname "$0")/../qemu-run.sh" "qemu-system-riscv32 -M virt -smp 1 -bios none" "$@"
