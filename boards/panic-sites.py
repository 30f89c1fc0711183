#!/usr/bin/env python3
"""Every call of a panic function in the firmware, with the inline chain that leads to it.

The `panic-never` build (boards/qemu-mps2-an386, `--features panic-never`) only says *that* a panic is
reachable; this says *where*: it disassembles the release ELF (the one `boards/measure.sh` builds), finds
every branch to `core::panicking::*`, `slice_index_fail`, `len_mismatch_fail`, … and asks the DWARF line
tables (the release profile keeps `debug = true`) for the inlined frames of each call site.

Usage: python3 boards/panic-sites.py [ELF]        (needs llvm-objdump from rustup's llvm-tools, and
                                                    llvm-addr2line on PATH: Debian's `llvm` package)

The `panic-never` build itself does not link while a panic remains; to list what remains in exactly that
build (its report lines are compiled out), link it with the symbol defined and pass its ELF:
  cd boards/qemu-mps2-an386 && RUSTFLAGS="-C link-arg=--defsym=__the_integrate_and_stream_path_can_panic=0" \
    CARGO_TARGET_DIR=target/panic-never cargo build --release --features panic-never
  python3 ../panic-sites.py target/panic-never/thumbv7em-none-eabihf/release/latentbki-qemu-mps2-an386
"""
import os
import re
import shutil
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ELF = os.path.join(HERE, "qemu-mps2-an386/target/thumbv7em-none-eabihf/release/latentbki-qemu-mps2-an386")
PANICKY = re.compile(r"core::panicking::|slice_index_fail|len_mismatch_fail|unwrap_failed|expect_failed"
                     r"|assert_failed|panic_const_|str_index_overflow_fail")


def tool(name):
    host = subprocess.check_output(["rustc", "-vV"], text=True).split("host: ")[1].split()[0]
    sysroot = subprocess.check_output(["rustc", "--print", "sysroot"], text=True).strip()
    path = os.path.join(sysroot, "lib/rustlib", host, "bin", name)
    return path if os.path.exists(path) else shutil.which(name)


def tidy(name):
    name = re.sub(r"::h[0-9a-f]{16}$", "", name)
    for a, b in (("$LT$", "<"), ("$GT$", ">"), ("$C$", ","), ("$u20$", " "), ("$RF$", "&"), ("$u7b$", "{"),
                 ("$u7d$", "}"), ("..", "::")):
        name = name.replace(a, b)
    return name


def main():
    elf = sys.argv[1] if len(sys.argv) > 1 else ELF
    objdump, nm, addr2line = tool("llvm-objdump"), tool("llvm-nm"), shutil.which("llvm-addr2line")
    if not (objdump and nm and addr2line):
        sys.exit("needs llvm-objdump and llvm-nm (rustup component add llvm-tools) and llvm-addr2line")
    targets = {}
    for line in subprocess.check_output([nm, "-C", elf], text=True).splitlines():
        parts = line.split(None, 2)
        if len(parts) == 3 and parts[1] in "tT" and PANICKY.search(parts[2]):
            targets[int(parts[0], 16) & ~1] = parts[2]
    sites, func = [], None
    for line in subprocess.check_output([objdump, "-d", "-C", "--no-show-raw-insn", elf], text=True).splitlines():
        m = re.match(r"^([0-9a-f]+) <(.*)>:", line)
        if m:
            func = m.group(2)
            continue
        m = re.match(r"^\s*([0-9a-f]+):\s+b[a-z.]*\s+0x([0-9a-f]+)", line)
        if m and int(m.group(2), 16) in targets and func and not PANICKY.search(func):
            sites.append((int(m.group(1), 16), func, targets[int(m.group(2), 16)]))
    print(f"{len(sites)} call sites of panic functions in {os.path.relpath(elf)}")
    for addr, func, target in sites:
        out = subprocess.run([addr2line, "-i", "-f", "-C", "-e", elf, hex(addr)],
                             capture_output=True, text=True).stdout.split("\n")
        frames = [(tidy(out[i]), out[i + 1]) for i in range(0, len(out) - 1, 2)]
        # The project's frames (innermost first); the standard library's only when nothing else is known.
        ours = [(f, loc) for f, loc in frames if "/rustc/" not in loc and "/library/" not in loc] or frames
        print(f"\n{addr:#x} in {tidy(func)[:80]} -> {tidy(target)}")
        for f, loc in ours:
            loc = re.sub(r"^.*?/(latentbki|boards|src|\.cargo/registry/src/[^/]+)/", r"\1/", loc)
            print(f"    {f[:90]}  @ {loc}")


if __name__ == "__main__":
    main()
