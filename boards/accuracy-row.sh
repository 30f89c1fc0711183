# Sourced by measure.sh and measure-targets.sh: the accuracy that ships, as a row of their table.
#   accuracy_row TARGET UART   a QEMU run's UART bytes fed to the base station, against the f32 map of the points
#                              the firmware took (host-sim/examples/firmware_accuracy.rs); TARGET is thumbv7em,
#                              thumbv6m or riscv32imac
# A host build: run from the workspace with the host's target dir and without the firmware's RUSTFLAGS (which
# would rebuild host-sim with other flags).
accuracy_row() {
  (cd "$(dirname "${BASH_SOURCE[0]}")/.." &&
    env -u CARGO_TARGET_DIR -u RUSTFLAGS cargo run --release --quiet -p host-sim --example firmware_accuracy -- \
      --row "$1" "$2")
}
