#!/usr/bin/env python3
"""Per-function profile of the instruction counter's marked regions (boards/measure.sh with PROFILE=1).

Usage: profile.py <disassembly> <insn.log>
  disassembly  `llvm-objdump -d --no-show-raw-insn` of the firmware ELF (function starts)
  insn.log     the insncount plugin's log with profile=on (`pc 0x<addr> <instructions>` lines)
Prints the 12 functions that executed the most instructions inside the regions.
"""
import bisect, collections, re, sys

dis, log = sys.argv[1], sys.argv[2]
# Mapping symbols (`$t`, `$d`, `$x`…: where Thumb code or data starts) are not functions; a system
# llvm-objdump prints them as labels of their own, which would take the instructions after them.
funcs = sorted((int(m.group(1), 16), m.group(2)) for m in
               (re.match(r'^([0-9a-f]+) <(.*)>:', l) for l in open(dis))
               if m and not m.group(2).startswith('$'))
starts = [a for a, _ in funcs]
agg = collections.Counter()
for l in open(log):
    if l.startswith("pc "):
        _, pc, n = l.split()
        name = funcs[bisect.bisect_right(starts, int(pc, 16)) - 1][1]
        agg[re.sub(r'17h[0-9a-f]{16}E$', '', name)] += int(n)
tot = sum(agg.values())
print(f"profile of the marked regions ({tot} instructions):")
for name, n in agg.most_common(12):
    print(f"{n:>12} {100 * n / tot:5.1f}%  {name[:100]}")
