"""What boards/measure.sh reads back from a QEMU run of the self-test firmware, in one place.

The firmware prints integer key=value lines (`scenario`, `frame`, `view`, `stack`, `memory`); the TCG plugin
writes one `mark` line per counted region, in the same order as the `frame` and `view` lines. Each of
measure.sh's tables pairs them the same way, so the pairing and the stack high-water mark live here.
"""
import re


def kv(line):
    """The integer fields of a report line."""
    return dict(re.findall(r'(\w+)=(\d+)', line))


def runs(out, which):
    """Frames and views of run `which` (stdout-<which>.txt, insn-<which>.log in `out`), by scenario name:
    frames as (points, instructions), views as (their line's fields, instructions); and the stdout lines."""
    text = open(f"{out}/stdout-{which}.txt").read().splitlines()
    lines = [l for l in text if l.startswith(("frame ", "view "))]
    marks = [int(l.split()[2]) for l in open(f"{out}/insn-{which}.log") if l.startswith("mark ")]
    assert len(lines) == len(marks), (which, len(lines), len(marks))
    names = {int(kv(l)["s"]): re.search(r'name=(\w+)', l).group(1) for l in text if l.startswith("scenario ")}
    frames, views = {}, {}
    for l, m in zip(lines, marks):
        d = kv(l)
        if l.startswith("frame "):
            frames.setdefault(names[int(d["s"])], []).append((int(d["points"]), m))
        else:
            views.setdefault(names[int(d["s"])], []).append((d, m))
    return frames, views, text


def whole_stack(text):
    """The deepest of all the run's stack windows: each set-up, each loop, and the tail after the last."""
    stack = [kv(l) for l in text if l.startswith("stack ")]
    tail = int(kv(next(l for l in text if l.startswith("memory ")))["tail_stack_high_water"])
    return max([int(s["setup_high_water"]) for s in stack] + [int(s["loop_high_water"]) for s in stack] + [tail])
