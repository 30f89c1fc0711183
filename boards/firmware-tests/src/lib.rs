//! The QEMU boards of `boards/` as the host sees them: where each lives, what it builds for, what runs it,
//! and whether this machine can do both — for `tests/firmware_qemu.rs`, which runs each board's firmware
//! under QEMU against its host twin.
//!
//! A machine without QEMU or the boards' Rust targets makes those tests *fail* with the one line that fixes
//! it ([`Board::ready`]): a firmware test that passes without running the firmware cannot fail, so it must
//! not pass. `cargo xtask setup` installs both (`cargo xtask test`, the README's test command, runs it
//! first); `LATENTBKI_NO_QEMU=1` opts out, and the build script turns it into `cfg(latentbki_no_qemu)`,
//! under which the tests are ignored.

use latentbki::quant::Cooling;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// The one line that fixes a machine that cannot run the firmware tests.
pub const FIX: &str = "run `cargo xtask setup` (installs QEMU and the firmware targets; `cargo xtask test` runs \
                       it first), or set LATENTBKI_NO_QEMU=1 to skip the QEMU firmware tests (they show as ignored)";

/// A QEMU board of `boards/`: where it is, what it builds for, what runs it.
pub struct Board {
    /// Directory under `boards/` (the binary is `latentbki-<dir>`).
    pub dir: &'static str,
    /// Its Rust target.
    pub target: &'static str,
    /// The QEMU binary its `run-qemu.sh` starts.
    pub qemu: &'static str,
    /// Environment variable naming a prebuilt ELF (then nothing is built).
    pub elf_var: &'static str,
    /// How its firmware cools int8 sums (its target's [`Cooling::NATIVE`]): the twin cools the same way.
    pub cooling: Cooling,
}

/// Cortex-M4F (thumbv7em) on QEMU's mps2-an386.
pub const AN386: Board = Board {
    dir: "qemu-mps2-an386",
    target: "thumbv7em-none-eabihf",
    qemu: "qemu-system-arm",
    elf_var: "LATENTBKI_FIRMWARE_ELF",
    cooling: Cooling::Float,
};
/// The Cortex-M0 instruction set (thumbv6m: soft float) on QEMU's mps2-an385.
pub const AN385: Board = Board {
    dir: "qemu-mps2-an385",
    target: "thumbv6m-none-eabi",
    qemu: "qemu-system-arm",
    elf_var: "LATENTBKI_FIRMWARE_ELF_AN385",
    cooling: Cooling::Fixed,
};
/// RISC-V without an FPU (riscv32imac) on QEMU's virt machine.
pub const RISCV32_VIRT: Board = Board {
    dir: "qemu-riscv32-virt",
    target: "riscv32imac-unknown-none-elf",
    qemu: "qemu-system-riscv32",
    elf_var: "LATENTBKI_FIRMWARE_ELF_RISCV32",
    cooling: Cooling::Fixed,
};

/// The embassy board: the self-test over `embedded-io-async` on an embassy executor, Cortex-M4F on QEMU's
/// mps2-an386 (`boards/embassy-mps2-an386`; `tests/embassy_qemu.rs`).
pub const EMBASSY_AN386: Board = Board {
    dir: "embassy-mps2-an386",
    target: "thumbv7em-none-eabihf",
    qemu: "qemu-system-arm",
    elf_var: "LATENTBKI_EMBASSY_ELF",
    cooling: Cooling::Float,
};

/// The repository's root.
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()
        .expect("the repository root")
}

impl Board {
    /// The board's directory.
    pub fn path(&self) -> PathBuf {
        repo_root().join("boards").join(self.dir)
    }

    /// Whether this machine can build and run the board's firmware; if not, the one line that says why
    /// and how to fix it.
    pub fn ready(&self) -> Result<(), String> {
        match Command::new(self.qemu)
            .arg("--version")
            .stdin(Stdio::null())
            .output()
        {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(format!("{} not found on PATH: {FIX}", self.qemu))
            }
            Err(e) => return Err(format!("{} does not start ({e}): {FIX}", self.qemu)),
            Ok(o) if !o.status.success() => {
                return Err(format!(
                    "{} on PATH does not run (`{} --version` exited with {}): {FIX}",
                    self.qemu, self.qemu, o.status
                ))
            }
            Ok(_) => {}
        }
        if std::env::var_os(self.elf_var).is_none() && !target_installed(self.target) {
            return Err(format!(
                "the Rust target {} is not installed: {FIX}",
                self.target
            ));
        }
        Ok(())
    }

    /// The firmware's ELF: `elf_var`'s if set, else built (`cargo build --release` in the board's
    /// directory, with `boards/measure.sh`'s flags, so that either reuses the other's build).
    pub fn firmware_elf(&self) -> PathBuf {
        if let Some(p) = std::env::var_os(self.elf_var) {
            return PathBuf::from(p);
        }
        let dir = self.path();
        // measure.sh's RUSTFLAGS (fixed source paths): the same build, whichever of the two runs first.
        let status = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
            .args(["build", "--release", "--quiet"])
            .current_dir(&dir)
            .env("CARGO_TARGET_DIR", dir.join("target"))
            .env(
                "RUSTFLAGS",
                format!("--remap-path-prefix={}=/latentbki", repo_root().display()),
            )
            .status()
            .expect("run cargo build for the firmware");
        assert!(status.success(), "{} firmware build failed", self.dir);
        dir.join(format!(
            "target/{}/release/latentbki-{}",
            self.target, self.dir
        ))
    }

    /// Run the firmware in QEMU: (UART bytes, semihosting stdout). Panics unless it exits 0 after its
    /// `done` line.
    pub fn run_firmware(&self, elf: &Path) -> (Vec<u8>, String) {
        let dir = tempfile::tempdir().unwrap();
        let uart = dir.path().join("uart.bin");
        let out = Command::new(self.path().join("run-qemu.sh"))
            .arg(elf)
            .env("QEMU_SERIAL", &uart)
            // qemu-run.sh's 300 s is tight for the thumbv6m run (soft float) on a loaded 2-core machine.
            .env(
                "QEMU_TIMEOUT",
                std::env::var("QEMU_TIMEOUT").unwrap_or_else(|_| "1200".into()),
            )
            .env_remove("QEMU_PLUGIN")
            .output()
            .expect("run qemu");
        let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
        assert!(
            out.status.success(),
            "firmware exited with {:?}\nstdout:\n{stdout}\nstderr:\n{}",
            out.status.code(),
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(
            stdout.lines().any(|l| l == "done"),
            "no `done` line:\n{stdout}"
        );
        (std::fs::read(&uart).unwrap(), stdout)
    }
}

/// Whether the toolchain that runs these tests has `target`'s core library.
fn target_installed(target: &str) -> bool {
    let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
    Command::new(rustc)
        .args(["--print", "sysroot"])
        .output()
        .ok()
        .map(|o| PathBuf::from(String::from_utf8_lossy(&o.stdout).trim()))
        .is_some_and(|sysroot| {
            sysroot
                .join("lib/rustlib")
                .join(target)
                .join("lib")
                .is_dir()
        })
}
