#!/usr/bin/env bash
# Firmware measurements of the targets without an FPU, each on its QEMU board, the same self-test program as
# the an386 (boards/selftest-firmware):
#   thumbv6m      (Cortex-M0/M0+ instruction set)  boards/qemu-mps2-an385  (QEMU's Cortex-M3 runs v6-M code)
#   riscv32imac                                    boards/qemu-riscv32-virt
# boards/measure.sh calls this for each of its modes, after the an386's part:
#   --size          build; fails if a target's build exceeds its flash budget (boards/flash-limit.sh): the
#                   boards' build 96 KiB, the minimal build (`--no-default-features`) 64 KiB (a limit, not a
#                   golden file: the an386's golden size catches drift)
#   --panic-never   the link-time no-panic proof: the `panic-never` build links, runs, and streams the same
#                   UART bytes as the target's reporting build
#   --table         rows of measure.sh's table: flash, whole-run stack, instructions/point at f = 3 on the
#                   depth frame (per feature type) and, with int8 features, on the 8×8 ToF and the scanning
#                   LiDAR; the accuracy of the firmware's stream at the base station
#   --MODE TARGET   only that target (thumbv6m or riscv32imac)
#   --profile       after --table: each target's hot spots in one scenario's counted regions (PROFILE_SCENARIO,
#                   default depth_f3_i8), from a second run with the plugin's per-PC profile (measure.sh's
#                   PROFILE=1 calls it)
set -euo pipefail
BOARDS=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$BOARDS/.." && pwd)
# As measure.sh: fixed source paths (a path dependency's panic locations embed them).
export RUSTFLAGS="--remap-path-prefix=$ROOT=/latentbki"
HOST=$(rustc -vV | sed -n 's/^host: //p')
LLVM_BIN="$(rustc --print sysroot)/lib/rustlib/$HOST/bin"
[ -x "$LLVM_BIN/llvm-size" ] || rustup component add llvm-tools
# shellcheck source=flash-limit.sh
. "$BOARDS/flash-limit.sh"
# shellcheck source=accuracy-row.sh
. "$BOARDS/accuracy-row.sh"
# board directory, target triple, name in the table
TARGETS=("qemu-mps2-an385 thumbv6m-none-eabi thumbv6m"
         "qemu-riscv32-virt riscv32imac-unknown-none-elf riscv32imac")

elf() { echo "$BOARDS/$1/target/$2/release/latentbki-$1"; }

build() {
  (cd "$BOARDS/$1" && CARGO_TARGET_DIR="$PWD/target" cargo build --release --quiet)
}

# flash = what the image stores (code, read-only data, unwind tables, .data's initial values);
# ram = the statics (.data, .bss, .uninit).
size_line() {
  "$LLVM_BIN/llvm-size" -A -d "$1" | awk '
    $1 ~ /^\.(vector_table|text|init\.rust|rodata|eh_frame|data)$/ { flash += $2 }
    $1 ~ /^\.(data|bss|uninit)$/ { ram += $2 }
    END { printf "flash=%d ram=%d\n", flash, ram }'
}

# Both budgets of one target: its full build and its minimal build (each named on its own line).
check_size() {
  local dir=$1 triple=$2 name=$3 min_elf over=0
  build "$dir" || { echo "$name ($dir): build failed" >&2; return 1; }
  check_flash_limit "$name full build ($dir)" "$(elf "$dir" "$triple")" "$FLASH_LIMIT_FULL" || over=1
  min_elf=$(cd "$BOARDS/$dir" && build_minimal) || { echo "$name ($dir): minimal build failed" >&2; return 1; }
  flash_bytes "$min_elf" > "$BOARDS/$dir/target/flash-minimal.txt"
  check_flash_limit "$name minimal build ($dir --no-default-features)" "$min_elf" "$FLASH_LIMIT_MINIMAL" || over=1
  return "$over"
}

panic_never() {
  local dir=$1 triple=$2 name=$3 out pn_elf
  build "$dir"
  out="$BOARDS/$dir/target/measure"
  mkdir -p "$out"
  # Its own target dir, as on the an386: built into the reporting build's, cargo would uplift it over that ELF.
  pn_elf=$(cd "$BOARDS/$dir" && CARGO_TARGET_DIR="$PWD/target/panic-never" \
    cargo build --release --quiet --features panic-never --message-format=json-render-diagnostics |
    python3 -c 'import json,sys; print([m["executable"] for m in map(json.loads, sys.stdin) if m.get("executable")][-1])') || {
    echo "$name: panic-never build does not link: a panic is reachable (python3 boards/panic-sites.py lists where)" >&2
    return 1; }
  QEMU_SERIAL="$out/uart-panic-never.bin" "$BOARDS/$dir/run-qemu.sh" "$pn_elf" >/dev/null || {
    echo "$name: panic-never firmware failed: exit code $?" >&2; return 1; }
  # Its own reporting run: the an386 cools int8 sums in f32 and these targets in fixed point
  # (latentbki::quant::Cooling), so their streams differ from the an386's.
  # (The stream the QEMU firmware test kept after checking it against the host twin, `<elf>.twin.uart`,
  # when it is newer than the ELF: as measure.sh --panic-never.)
  local reference="$out/uart-reporting.bin" rep_elf
  rep_elf=$(elf "$dir" "$triple")
  if [ "$rep_elf.twin.uart" -nt "$rep_elf" ]; then
    reference="$rep_elf.twin.uart"
  else
    QEMU_SERIAL="$reference" "$BOARDS/$dir/run-qemu.sh" "$rep_elf" > "$out/reporting.stdout" || {
      echo "$name: firmware failed: exit code $?" >&2; return 1; }
    grep -qx done "$out/reporting.stdout" || {
      echo "$name: the reporting build printed no \`done\` line" >&2; return 1; }
  fi
  cmp "$out/uart-panic-never.bin" "$reference" || {
    echo "$name: the panic-never build streams different bytes from the reporting build ($reference)" >&2; return 1; }
  echo "panic-never ok ($name, $dir): links, runs, streams the same $(wc -c < "$out/uart-panic-never.bin") bytes"
}

# Run under the instruction-counting plugin; leaves stdout.txt, insn.log and firmware.size in target/measure.
run_counted() {
  local dir=$1 triple=$2 out
  build "$dir"
  out="$BOARDS/$dir/target/measure"
  mkdir -p "$out"
  size_line "$(elf "$dir" "$triple")" > "$out/firmware.size"
  OUT="$out/insncount.so" "$BOARDS/qemu-mps2-an386/plugin/build.sh"
  # Soft float under the counting plugin is slow: more than run-qemu.sh's default 300 s on a loaded machine.
  QEMU_TIMEOUT="${QEMU_TIMEOUT:-1200}" \
  QEMU_PLUGIN="$out/insncount.so" QEMU_PLUGIN_LOG="$out/insn.log" \
    QEMU_SERIAL="$out/uart.bin" "$BOARDS/$dir/run-qemu.sh" "$(elf "$dir" "$triple")" > "$out/stdout.txt" || {
    echo "$dir firmware failed: exit code $? (101 panic, 102 fault, 124 timeout)" >&2; return 1; }
  grep -q '^done$' "$out/stdout.txt" || { echo "$dir firmware did not finish" >&2; return 1; }
}

# The table rows of one target (after run_counted).
rows() {
  local dir=$1 name=$3 out="$BOARDS/$1/target/measure"
  python3 - "$out" "$name" <<'PY'
import re, sys
out, name = sys.argv[1], sys.argv[2]
kv = lambda line: dict(re.findall(r'(\w+)=(\w+)', line))
size = kv(open(f"{out}/firmware.size").read())
lines = open(f"{out}/stdout.txt").read().splitlines()
marks = [l for l in open(f"{out}/insn.log") if l.startswith("mark ")]
frames = [l for l in lines if l.startswith("frame ")]
assert len(frames) == len(marks), f"{len(frames)} frame lines, {len(marks)} plugin marks"
scen = {int(kv(l)["s"]): kv(l) for l in lines if l.startswith("scenario ")}
stack = [kv(l) for l in lines if l.startswith("stack ")]
mem = kv(next(l for l in lines if l.startswith("memory ")))
KB = lambda b: f"{int(b) / 1024:.1f} KiB"
print(f"| flash (text + rodata + data), {name}, the boards' build | {KB(size['flash'])} ({size['flash']} B) | ≤ 96 KiB |")
minimal = int(open(f"{out}/../flash-minimal.txt").read())
print(f"| flash, {name}, minimal build (`latentbki` `default-features = false`) | {KB(minimal)} ({minimal} B) | ≤ 64 KiB |")
whole = max([int(s['setup_high_water']) for s in stack] + [int(s['loop_high_water']) for s in stack]
            + [int(mem['tail_stack_high_water'])])
print(f"| stack, whole run (set-up included), {name} | {whole} B | ≤ 8 KB |")
runs = {}
for f, m in zip(frames, marks):
    d = kv(f)
    runs.setdefault(int(d["s"]), []).append((int(d["points"]), int(m.split()[2])))
# At f = 3, by the scenario's name (latentbki-selftest's SELF_TEST): the depth frames per feature type, and the
# sparse sensor patterns with int8 features (the integer path these targets run; their f32 rows are soft float).
NAMED = re.compile(r'name=(\w+)')
ROWS = {
    "depth_f3": ("f32 features", "depth frames", "none (soft float: the i8 path is for this target)"),
    "depth_f3_i8": ("i8 features", "depth frames", "≤ 2,000"),
    "tof_f3_i8": ("i8 features, ToF 8×8", "8×8 zones", "≤ 3,000"),
    "lidar_f3_i8": ("i8 features, scanning LiDAR", "revolutions of 360 beams, room and corridor", "≤ 3,000"),
}
names = {int(kv(l)["s"]): NAMED.search(l).group(1) for l in lines if l.startswith("scenario ")}
for s, fr in sorted(runs.items(), key=lambda r: list(ROWS).index(names[r[0]]) if names[r[0]] in ROWS else 99):
    if names[s] not in ROWS:
        continue
    what, unit, goal = ROWS[names[s]]
    per = sorted(i / p for p, i in fr if p > 0)
    mean = sum(i for _, i in fr) / sum(p for p, _ in fr)
    print(f"| instructions/point, f = 3, {name}, {what} ({len(fr)} {unit}, {sum(p for p, _ in fr):,} points, "
          f"scenario {s}) | {mean:.0f} mean, median {per[len(per) // 2]:.0f}, {per[0]:.0f}–{per[-1]:.0f} per frame | {goal} |")
PY
  accuracy_row "$name" "$out/uart.bin"
}

profile() {
  local dir=$1 triple=$2 name=$3 out="$BOARDS/$1/target/measure" scenario=${PROFILE_SCENARIO:-depth_f3_i8} marks
  # The report markers of the scenario's frames (one per frame line, in order) in the last --table run.
  marks=$(python3 - "$out/stdout.txt" "$scenario" <<'PY'
import re, sys
lines = open(sys.argv[1]).read().splitlines()
s = next(m.group(1) for l in lines for m in [re.match(rf"scenario s=(\d+) name={sys.argv[2]} ", l)] if m)
idx = [i for i, l in enumerate(l for l in lines if l.startswith("frame ")) if f" s={s} " in l]
print(f"{idx[0]}-{idx[-1] + 1}")
PY
) || { echo "$name: no scenario $scenario in the last run (run --table first)" >&2; return 1; }
  QEMU_TIMEOUT="${QEMU_TIMEOUT:-3600}" QEMU_PLUGIN="$out/insncount.so" QEMU_PLUGIN_ARGS="profile=on,profile_marks=$marks" \
    QEMU_PLUGIN_LOG="$out/insn-profile.log" QEMU_SERIAL="$out/uart-profile.bin" \
    "$BOARDS/$dir/run-qemu.sh" "$(elf "$dir" "$triple")" > /dev/null || {
    echo "$dir firmware failed under the profiler: exit code $?" >&2; return 1; }
  echo
  echo "$name, scenario $scenario (report marks $marks):"
  "$LLVM_BIN/llvm-objdump" -d --no-show-raw-insn "$(elf "$dir" "$triple")" > "$out/firmware.dis"
  python3 "$BOARDS/profile.py" "$out/firmware.dis" "$out/insn-profile.log"
}

mode=${1:---table}
only=${2:-}   # optional: one target by its name (thumbv6m, riscv32imac)
over=0        # --size, --table: targets over the flash limit (each named on its own line; all are checked)
for t in "${TARGETS[@]}"; do
  read -r dir triple name <<< "$t"
  [ -z "$only" ] || [ "$only" = "$name" ] || continue
  case $mode in
    --size) check_size "$dir" "$triple" "$name" || over=$((over + 1)) ;;
    --panic-never) panic_never "$dir" "$triple" "$name" ;;
    --table)
      run_counted "$dir" "$triple"
      # Both budgets checked (the minimal build's flash is a row of the table); the table is printed
      # first, an image over its limit then fails the run.
      check_size "$dir" "$triple" "$name" >/dev/null || over=$((over + 1))
      rows "$dir" "$triple" "$name" ;;
    --profile) profile "$dir" "$triple" "$name" ;;
    *) echo "usage: $0 --size | --panic-never | --table | --profile" >&2; exit 2 ;;
  esac
done
[ "$over" -eq 0 ] || exit 1
