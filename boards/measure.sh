#!/usr/bin/env bash
# Firmware measurements on QEMU mps2-an386 (Cortex-M4F), reproducible (and, through measure-targets.sh, the
# same for thumbv6m on mps2-an385 and riscv32imac on riscv32 virt; rows appended to the table):
#   flash and RAM   llvm-size of the firmware ELF (the boards' build: their default feature `full`, every
#                   `latentbki` feature the demo's robot uses), compared with the golden file
#                   boards/qemu-mps2-an386/expected/firmware.size (BLESS=1 rewrites it); --size and --table
#                   fail when that build's flash exceeds 96 KiB or the minimal build's (`--no-default-features`,
#                   `latentbki` with `default-features = false`) 64 KiB, on each target (boards/flash-limit.sh;
#                   FLASH_LIMIT_FULL / FLASH_LIMIT_MINIMAL=bytes override them, e.g. to see the failure:
#                   FLASH_LIMIT_MINIMAL=60000 boards/measure.sh --size)
#   stack           high-water marks printed by the firmware (cortex-m-rt paint-stack)
#   instructions    exact executed instructions per input point, per sensor pattern (depth frames, 8×8 ToF, 2D
#                   LiDAR) and feature type (f32, int8), f = 1 and f = 3 (latentbki-selftest SELF_TEST): the
#                   insncount QEMU plugin (built here with cc) counts between the markers around the map's work
# Usage: boards/measure.sh            everything, prints a Markdown table
#        boards/measure.sh --size     only build, compare the size and check the flash limit of every
#                                     measured build: this one and its minimal build, the forgetting build,
#                                     thumbv6m, riscv32imac and the NUCLEO board (each full and minimal) (CI)
#        boards/measure.sh --panic-never   the link-time proof that no panic is reachable (CI): builds with
#                                     `--features panic-never`, runs it and checks its UART bytes equal the
#                                     reporting build's
#        boards/measure.sh --forgetting   the cost of forgetting and of scoring a candidate view (issue 21):
#                                     the rows of a build with `--features forgetting` against this one's,
#                                     its flash and stack high-water mark; fails when either is over its
#                                     limit (96 KiB as the full build's, 8 KiB; STACK_LIMIT=bytes overrides
#                                     the stack's)
#        boards/measure.sh --explorer-view   what scoring one candidate view the size of `host-sim explore`'s
#                                     costs (issue 21): a measurement build (not shipped, flash not
#                                     limited) with the explorer's 24 × 18 rays cast from each frame's pose;
#                                     the view's instructions and the per-point cost of the int8 and f32
#                                     rows with one such view per frame; fails over 8 KiB of stack
#        PROFILE=1 boards/measure.sh  also the per-function profile of the marked regions (hot spots; with
#                                     --forgetting, the forgetting build's: frames and views together)
set -euo pipefail
cd "$(dirname "$0")/qemu-mps2-an386"
export CARGO_TARGET_DIR="$PWD/target"
# Panic locations embed source paths, and `latentbki` is a path dependency: without a fixed prefix the
# golden size would depend on where the repository is checked out.
ROOT=$(cd ../.. && pwd)
export RUSTFLAGS="--remap-path-prefix=$ROOT=/latentbki"
HOST=$(rustc -vV | sed -n 's/^host: //p')
LLVM_BIN="$(rustc --print sysroot)/lib/rustlib/$HOST/bin"
[ -x "$LLVM_BIN/llvm-size" ] || rustup component add llvm-tools
# shellcheck source=flash-limit.sh
. ../flash-limit.sh
# shellcheck source=accuracy-row.sh
. ../accuracy-row.sh
ELF="$CARGO_TARGET_DIR/thumbv7em-none-eabihf/release/latentbki-qemu-mps2-an386"
OUT="$CARGO_TARGET_DIR/measure"
mkdir -p "$OUT"

cargo build --release --quiet

# The forgetting build (issue 21's cost rows): its own target dir, never the golden firmware. Prints its ELF.
build_forgetting() {
  CARGO_TARGET_DIR="$CARGO_TARGET_DIR/forgetting" \
    cargo build --release --quiet --features forgetting --message-format=json-render-diagnostics |
    python3 -c 'import json,sys; print([m["executable"] for m in map(json.loads, sys.stdin) if m.get("executable")][-1])'
}
FORGETTING_NAME="thumbv7em forgetting build (qemu-mps2-an386 --features forgetting)"
# The stack budget (8 KiB; STACK_LIMIT=bytes overrides it, e.g. to see the failure: STACK_LIMIT=4096
# boards/measure.sh --forgetting): --forgetting fails when that build's high-water mark exceeds it.
STACK_LIMIT=${STACK_LIMIT:-8192}

# ---- panic-never: the panic handler calls an undefined symbol, so this build links only if no panic is
# reachable from the firmware's entry. Same program otherwise: its UART stream must equal the normal build's.
if [ "${1:-}" = --panic-never ]; then
  # Its own target dir: built into the same one, cargo would uplift it over $ELF (and a later plain
  # `cargo build` of the fresh reporting build does not copy it back), so every later run would use it.
  PN_ELF=$(CARGO_TARGET_DIR="$CARGO_TARGET_DIR/panic-never" \
    cargo build --release --quiet --features panic-never --message-format=json-render-diagnostics |
    python3 -c 'import json,sys; print([m["executable"] for m in map(json.loads, sys.stdin) if m.get("executable")][-1])') || {
    echo "panic-never build does not link: a panic is reachable (python3 boards/panic-sites.py lists where)" >&2; exit 1; }
  QEMU_SERIAL="$OUT/uart-panic-never.bin" ./run-qemu.sh "$PN_ELF" >/dev/null || {
    echo "panic-never firmware failed: exit code $?" >&2; exit 1; }
  # The reporting build's stream: the one the QEMU firmware test kept after checking it equals the host
  # twin's (boards/firmware-tests, `<elf>.twin.uart`, newer than the ELF), else a run of it here.
  if [ "$ELF.twin.uart" -nt "$ELF" ]; then
    reference="$ELF.twin.uart"
  else
    reference="$OUT/uart-reporting.bin"
    QEMU_SERIAL="$reference" ./run-qemu.sh "$ELF" > "$OUT/reporting.stdout" || {
      echo "firmware failed: exit code $?" >&2; exit 1; }
    # The reporting build prints its report (the panic-never build compiles it out): proves $ELF is not
    # the panic-never build, so the comparison below is between two different programs.
    grep -qx done "$OUT/reporting.stdout" || {
      echo "the reporting build printed no \`done\` line: is $ELF the panic-never build?" >&2; exit 1; }
  fi
  cmp "$OUT/uart-panic-never.bin" "$reference" || {
    echo "the panic-never build streams different bytes from the reporting build" >&2; exit 1; }
  echo "panic-never ok: links, runs, streams the same $(wc -c < "$OUT/uart-panic-never.bin") bytes as $reference"
  bash ../measure-targets.sh --panic-never   # thumbv6m and riscv32imac
  exit 0
fi

# ---- forgetting (issue 21): the same scenarios on a mapper that forgets (half-life 4 frames, one tick per
# frame), plus one candidate view scored after each frame, built apart (`--features forgetting`, its own
# target dir: never the golden firmware), against this build's rows. Prints its rows of the table.
# Runs this build ("off") and the build $1 ("on") under the instruction counter: $OUT/stdout-{off,on}.txt and
# $OUT/insn-{off,on}.log.
run_off_on() {
  OUT="$OUT/insncount.so" plugin/build.sh
  for run in off on; do
    elf=$ELF; [ $run = on ] && elf=$1
    # PROFILE=1: the forgetting build's run also logs per-PC counts (its hot spots, printed after the rows).
    args=""; [ $run = on ] && [ "${PROFILE:-0}" = 1 ] && args="profile=on"
    QEMU_PLUGIN="$OUT/insncount.so" QEMU_PLUGIN_ARGS="$args" QEMU_PLUGIN_LOG="$OUT/insn-$run.log" \
      QEMU_SERIAL="$OUT/uart-$run.bin" ./run-qemu.sh "$elf" > "$OUT/stdout-$run.txt" || { echo "firmware ($run) failed: exit code $?" >&2; exit 1; }
    grep -q '^done$' "$OUT/stdout-$run.txt" || { echo "firmware ($run) did not finish" >&2; exit 1; }
    # A start marker seen twice without its stop means regions went uncounted (seen once, with a build
    # whose stops the plugin never saw): refuse to print such counts.
    if grep -q 'inside a region' "$OUT/insn-$run.log"; then
      echo "the instruction counter saw unbalanced markers ($run build): its counts are not the map's work" >&2
      exit 1
    fi
  done
}

# ---- explorer-view (issue 21): what one candidate view the size of `host-sim explore`'s costs, counted. A
# measurement build, not shipped (`--features explorer-view`, its own target dir): the forgetting build with
# the 64-voxel view replaced by the explorer's 24 × 18 rays (its camera's field of view) cast from each
# frame's pose against the self-test room (boards/selftest-firmware/src/explorer_view.rs), the hits in a
# static. Its flash is over 64 KiB (the casting and the report's extra fields; printed, not limited) and its
# statics leave ≈ 10 KiB of stack instead of 16: it fails when its stack high-water mark exceeds 8 KiB.
if [ "${1:-}" = --explorer-view ]; then
  EV_ELF=$(CARGO_TARGET_DIR="$CARGO_TARGET_DIR/explorer-view" \
    cargo build --release --quiet --features explorer-view --message-format=json-render-diagnostics |
    python3 -c 'import json,sys; print([m["executable"] for m in map(json.loads, sys.stdin) if m.get("executable")][-1])')
  run_off_on "$EV_ELF"
  flash_bytes "$EV_ELF" > "$OUT/flash-explorer-view.txt"
  PYTHONPATH=.. python3 - "$OUT" "$STACK_LIMIT" <<'PY'
import sys
from marked_runs import kv, runs, whole_stack
out, limit = sys.argv[1], int(sys.argv[2])
off, _, _ = runs(out, "off")
on, views, text = runs(out, "on")
med = lambda xs: sorted(xs)[len(xs) // 2]
v = [(int(d["voxels"]), int(d["reached"]), m) for d, m in views["depth_f3"]]
assert all(int(kv(l)["score_bits"]) != 0 for l in text if l.startswith("view ")), "a view was refused"
print(f"view score, 24 × 18 rays (432 rays; median {med([h for h, _, _ in v])} hits, {med([r for _, r, _ in v])} "
      f"reached, 0.1 m voxels): median {med([i for _, _, i in v])} instructions, "
      f"{min(i for _, _, i in v)}–{max(i for _, _, i in v)} ({len(v)} views, depth_f3)")
for name, label in [("depth_f3_i8", "int8"), ("depth_f3", "f32")]:
    p = sum(n for n, _ in on[name])
    a = sum(i for _, i in off[name]) / sum(n for n, _ in off[name])
    c = (sum(i for _, i in on[name]) + sum(i for _, i in views[name])) / p
    print(f"per point, f = 3, {label}, forgetting on and one 24 × 18-ray view scored per frame: {c:.0f} mean, "
          f"{100 * (c / a - 1):+.1f} % vs {a:.0f} without ({len(on[name])} depth frames, {p:,} points)")
whole = whole_stack(text)
flash = int(open(f"{out}/flash-explorer-view.txt").read())
print(f"explorer-view build (measurement only): stack, whole run {whole} B (≤ {limit}); flash {flash} B (not limited)")
sys.exit(1 if whole > limit else 0)
PY
  exit $?
fi

if [ "${1:-}" = --forgetting ]; then
  FG_ELF=$(build_forgetting)
  run_off_on "$FG_ELF"
  flash_bytes "$FG_ELF" > "$OUT/flash-forgetting.txt"
  PYTHONPATH=.. python3 - "$OUT" <<'PY'
import sys
from marked_runs import runs, whole_stack
out = sys.argv[1]
off, _, _ = runs(out, "off")
on, views, text = runs(out, "on")
flash = int(open(f"{out}/flash-forgetting.txt").read())
print("| measure | value | goal |")
print("|---|---|---|")
for name, label in [("depth_f3", "f32 features"), ("depth_f3_i8", "i8 features")]:
    p = sum(n for n, _ in on[name])
    a = sum(i for _, i in off[name]) / sum(n for n, _ in off[name])
    b = sum(i for _, i in on[name]) / p
    v = sum(m for _, m in views[name])
    c = (sum(i for _, i in on[name]) + v) / p
    print(f"| instructions/point, f = 3, thumbv7em, {label}, forgetting on (half-life 4 frames; {len(on[name])} depth "
          f"frames, {p:,} points) | {b:.0f} mean, {100 * (b / a - 1):+.1f} % vs {a:.0f} without; with one candidate view "
          f"scored per frame {c:.0f}, {100 * (c / a - 1):+.1f} % | ≤ +15 % |")
v = sorted(m for _, m in views["depth_f3"])
print(f"| instructions to score one candidate view of 64 voxels (`Mapper::view_score`), f = 3, after each depth frame "
      f"| median {v[len(v) // 2]}, {v[0]}–{v[-1]} ({len(v)} views) | |")
print(f"| flash, the forgetting build (the boards' build with forgetting and view scoring linked) | {flash / 1024:.1f} KiB ({flash} B) | ≤ 96 KiB |")
# The deepest of all the run's windows, as in the reporting build's table (view scoring included).
whole = whole_stack(text)
print(f"| stack, whole run (set-up and view scoring included), the forgetting build | {whole} B | ≤ 8 KB |")
open(f"{out}/stack-forgetting.txt", "w").write(f"{whole}\n")
PY
  if [ "${PROFILE:-0}" = 1 ]; then
    # Every marked region of the forgetting build: the frames' work and the views scored after them.
    "$LLVM_BIN/llvm-objdump" -d --no-show-raw-insn "$FG_ELF" > "$OUT/firmware-forgetting.dis"
    echo
    python3 ../profile.py "$OUT/firmware-forgetting.dis" "$OUT/insn-on.log"
  fi
  # The rows are printed first; an image over a limit then fails the run (every limit checked, one line each).
  failed=0
  check_flash_limit "$FORGETTING_NAME" "$FG_ELF" "$FLASH_LIMIT_FULL" >/dev/null || failed=1
  stack=$(cat "$OUT/stack-forgetting.txt")
  if [ "$stack" -gt "$STACK_LIMIT" ]; then
    echo "stack over the limit: $FORGETTING_NAME: $stack B > $STACK_LIMIT B (by $((stack - STACK_LIMIT)) B)" >&2
    failed=1
  fi
  exit "$failed"
fi

# ---- size: the flash limit, then the golden file (allocated sections only: debug sections and paths never
# enter it)
# Every build is checked before the run fails (`failed`), so one run names each build over the limit.
failed=0
check_flash_limit "thumbv7em full build (qemu-mps2-an386)" "$ELF" "$FLASH_LIMIT_FULL" || failed=1
MIN_ELF=$(build_minimal)
check_flash_limit "thumbv7em minimal build (qemu-mps2-an386 --no-default-features)" "$MIN_ELF" \
  "$FLASH_LIMIT_MINIMAL" || failed=1
flash_bytes "$MIN_ELF" > "$OUT/flash-minimal.txt"
"$LLVM_BIN/llvm-size" -A -d "$ELF" | awk '
  $1==".vector_table"{vt=$2} $1==".text"{t=$2} $1==".rodata"{ro=$2}
  $1==".data"{d=$2} $1==".bss"{b=$2} $1==".uninit"{u=$2}
  END{printf "vector_table=%d text=%d rodata=%d data=%d bss=%d uninit=%d flash=%d ram=%d\n",
      vt,t,ro,d,b,u,vt+t+ro+d,d+b+u}' > "$OUT/firmware.size"
if [ "${BLESS:-0}" = 1 ]; then
  cp "$OUT/firmware.size" expected/firmware.size
  echo "blessed expected/firmware.size: $(cat expected/firmware.size)"
elif ! diff -u expected/firmware.size "$OUT/firmware.size"; then
  # Cargo hashes a path dependency's absolute path into its symbol names, so another checkout directory
  # reorders functions and moves alignment padding by a few bytes (measured: 4 B of .text between
  # /work/main and /check/work/main). A change within 64 B of flash with the same RAM is that, not code.
  read -r want_flash want_ram < <(sed 's/.*flash=\([0-9]*\) ram=\([0-9]*\)/\1 \2/' expected/firmware.size)
  read -r now_flash now_ram < <(sed 's/.*flash=\([0-9]*\) ram=\([0-9]*\)/\1 \2/' "$OUT/firmware.size")
  delta=$((now_flash - want_flash))
  if [ "$now_ram" != "$want_ram" ] || [ "${delta#-}" -gt 64 ]; then
    echo "firmware size changed (above: - expected, + now). If intended: BLESS=1 boards/measure.sh --size" >&2
    failed=1
  else
    echo "flash differs from the golden file by $delta B (within the 64 B a checkout path moves; RAM equal)"
  fi
fi
[ "$failed" = 1 ] || echo "size ok: $(cat "$OUT/firmware.size")"
if [ "${1:-}" = --size ]; then
  FG_ELF=$(build_forgetting)
  check_flash_limit "$FORGETTING_NAME" "$FG_ELF" "$FLASH_LIMIT_FULL" || failed=1
  bash ../measure-targets.sh --size || failed=1   # thumbv6m and riscv32imac
  # The real board (NUCLEO-F429ZI): its minimal build, then its build (the boards' features and codec), in
  # its own target dir (the minimal first: the last build is the one left at the board's ELF path).
  (
    cd ../stm32f429-nucleo
    export CARGO_TARGET_DIR="$PWD/target"
    nucleo_elf() {
      cargo build --release --quiet "$@" --message-format=json-render-diagnostics |
        python3 -c 'import json,sys; print([m["executable"] for m in map(json.loads, sys.stdin) if m.get("executable")][-1])'
    }
    check_flash_limit "thumbv7em real board, minimal build (stm32f429-nucleo --no-default-features)" \
      "$(nucleo_elf --no-default-features)" "$FLASH_LIMIT_MINIMAL"
    check_flash_limit "thumbv7em real board (stm32f429-nucleo)" "$(nucleo_elf)" "$FLASH_LIMIT_FULL"
  ) || failed=1
  exit "$failed"
fi

# ---- run under the instruction-counting plugin
OUT="$OUT/insncount.so" plugin/build.sh
args=""
[ "${PROFILE:-0}" = 1 ] && args="profile=on"
QEMU_PLUGIN="$OUT/insncount.so" QEMU_PLUGIN_ARGS="$args" QEMU_PLUGIN_LOG="$OUT/insn.log" \
  QEMU_SERIAL="$OUT/uart.bin" ./run-qemu.sh "$ELF" > "$OUT/stdout.txt" || {
  echo "firmware failed: exit code $? (101 panic, 102 HardFault, 124 timeout)" >&2; exit 1; }
grep -q '^done$' "$OUT/stdout.txt" || { echo "firmware did not finish" >&2; cat "$OUT/stdout.txt" >&2; exit 1; }

# Pair each frame line with its plugin mark (one per frame, in order).
paste -d' ' <(grep '^frame ' "$OUT/stdout.txt") <(grep '^mark ' "$OUT/insn.log") > "$OUT/frames.txt"
PYTHONPATH=.. python3 - "$OUT" <<'PY'
import re, sys
from marked_runs import kv, whole_stack
out = sys.argv[1]
size = kv(open(f"{out}/firmware.size").read())
runs = {}
for line in open(f"{out}/frames.txt"):
    d = kv(line)
    insns = int(line.split()[-2])
    runs.setdefault(int(d["s"]), []).append((int(d["f"]), int(d["points"]), insns))
stdout = open(f"{out}/stdout.txt").read()
scen = {int(kv(l)["s"]): kv(l) for l in stdout.splitlines() if l.startswith("scenario ")}
stack = [kv(l) for l in stdout.splitlines() if l.startswith("stack ")]
mem = kv(next(l for l in stdout.splitlines() if l.startswith("memory ")))
KB = lambda b: f"{int(b) / 1024:.1f} KiB"
print("| measure | value | goal |")
print("|---|---|---|")
print(f"| flash (text + rodata + data), thumbv7em, the boards' build (every feature the demo's robot uses) | {KB(size['flash'])} ({size['flash']} B; of which .data {KB(size['data'])}) | ≤ 96 KiB |")
minimal = int(open(f"{out}/flash-minimal.txt").read())
print(f"| flash, thumbv7em, minimal build (`latentbki` `default-features = false`) | {KB(minimal)} ({minimal} B) | ≤ 64 KiB |")
print(f"| RAM (data + bss) | {KB(size['ram'])} ({size['ram']} B) | map + stack ≤ 192 KB |")
print(f"| map | {KB(mem['map_bytes'])}, {scen[0]['capacity']} voxels, {mem['bytes_per_voxel']} B/voxel | |")
print(f"| stack, integrate-and-stream loop | {max(int(s['loop_high_water']) for s in stack)} B | ≤ 8 KB |")
# Whole run: the deepest of all windows (each set-up mark covers the previous loop's reports and this set-up,
# each loop mark its loop, the tail mark the last loop and the final reports).
whole = whole_stack(stdout.splitlines())
print(f"| stack, whole run (set-up included) | {whole} B | ≤ 8 KB |")
# One row per sensor pattern and feature type (the scenarios' names are in latentbki-selftest's SELF_TEST).
names = {s: re.search(r'name=(\w+)', l).group(1) for l in stdout.splitlines() if l.startswith("scenario ")
         for s in [int(kv(l)["s"])]}
rows = {
    "depth_f1": ("instructions/point, f = 1", "depth frames", "≤ 900"),
    "depth_f3": ("instructions/point, f = 3, thumbv7em, f32 features", "depth frames", "≤ 1,200"),
    "depth_f3_i8": ("instructions/point, f = 3, thumbv7em, i8 features", "depth frames", "≤ 600"),
    "full_map": ("instructions/point, f = 3, full map", "depth frames, the window holds the room", ""),
    "tof_f3": ("instructions/point, f = 3, ToF 8×8", "8×8 zones", "≤ 1,500"),
    "lidar_f3": ("instructions/point, f = 3, scanning LiDAR", "revolutions of 360 beams, room and corridor", "≤ 1,500"),
    "tof_f3_i8": ("instructions/point, f = 3, thumbv7em, i8 features, ToF 8×8", "8×8 zones", ""),
    "lidar_f3_i8": ("instructions/point, f = 3, thumbv7em, i8 features, scanning LiDAR",
                    "revolutions of 360 beams, room and corridor", ""),
}
for s, frames in sorted(runs.items(), key=lambda r: list(rows).index(names[r[0]]) if names[r[0]] in rows else 99):
    if names[s] not in rows:
        continue
    label, unit, goal = rows[names[s]]
    total_i = sum(i for _, _, i in frames); total_p = sum(p for _, p, _ in frames)
    per = sorted(i / p for _, p, i in frames if p > 0)
    med = per[len(per) // 2]
    print(f"| {label} ({len(frames)} {unit}, {total_p:,} points, scenario {s}) | {total_i / total_p:.0f} mean, "
          f"median {med:.0f}, {per[0]:.0f}–{per[-1]:.0f} per frame | {goal} |")
answer = {int(kv(l)["s"]): kv(l) for l in stdout.splitlines() if l.startswith("answerable ")}
best = answer[next(s for s, n in names.items() if n == "full_map")]
full = int(best["held"]) == int(scen[0]["capacity"])
print(f"| answerable voxels (held + within the kernel's reach of one), full map, f = {best['f']} | "
      f"{best['answerable']} ({best['held']} held{'' if full else ', map not full'}) | ≥ 5,000 |")
print(f"| answerable voxels per KiB of map RAM | {int(best['answerable']) / (int(mem['map_bytes']) / 1024):.1f} "
      f"({best['answerable']} in {KB(mem['map_bytes'])}{'' if full else ', map not full'}) | ≥ 35 |")
for s in sorted(scen):
    d = scen[s]
    print(f"| scenario {s} (f = {d['f']}) | {d['points']} points, {d['integrated']} integrated, peak {d['peak_voxels']} voxels held, "
          f"{d['evicted']} evicted, {d['frames_sent']} frames / {d['bytes_sent']} B sent | |")
PY
# The accuracy that ships: this run's UART bytes through the base station, against the f32 map of the points
# the firmware took (host-sim's firmware_accuracy; a host build, without the firmware's flags).
accuracy_row thumbv7em "$OUT/uart.bin"
# The same table, continued: the targets without an FPU (thumbv6m, riscv32imac) on their QEMU boards.
bash ../measure-targets.sh --table

if [ "${PROFILE:-0}" = 1 ]; then
  "$LLVM_BIN/llvm-objdump" -d --no-show-raw-insn "$ELF" > "$OUT/firmware.dis"
  echo
  python3 ../profile.py "$OUT/firmware.dis" "$OUT/insn.log"
  bash ../measure-targets.sh --profile
fi
exit "$failed"
