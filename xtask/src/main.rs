//! `cargo xtask`: the project's own tasks, written so that a fresh machine needs nothing installed by hand.
//!
//! - `cargo xtask test [ARGS…]` — the README's test command: [`setup`] (what the tests need), then
//!   `cargo test --release --no-fail-fast [ARGS…]` over the whole workspace, the firmware run under QEMU
//!   included, and a closing summary that names the QEMU firmware tests and how each ended.
//! - `cargo xtask setup` — only the installs (CI's `setup` job calls it too).
//!
//! Why a task and not tests that install what they miss: installing system packages needs root, takes a
//! minute and changes the machine, which a test must not do behind its runner's back. So a plain
//! `cargo test --release` on a machine without QEMU or the firmware targets *fails*, with the one line that
//! fixes it (`cargo xtask setup`), and `cargo xtask test` runs that line first. Opting out of the firmware
//! tests is explicit: `LATENTBKI_NO_QEMU=1` (they then show as ignored, never as passed).

mod setup;
mod summary;

use std::io::{BufRead, BufReader, Write};
use std::process::{Command, ExitCode, Stdio};

const USAGE: &str = "usage: cargo xtask test [CARGO TEST ARGS…]   setup, then every test (cargo test --release)
       cargo xtask setup                        install what the tests need (Rust targets, QEMU, Python and npm packages)
env:   LATENTBKI_NO_QEMU=1                      opt out of the QEMU firmware tests (they show as ignored)";

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.first().map(String::as_str) {
        Some("setup") if args.len() == 1 => setup::run().map(|_| ExitCode::SUCCESS),
        Some("test") => setup::run().and_then(|env| test(&args[1..], &env)),
        Some("help" | "-h" | "--help") => {
            println!("{USAGE}");
            Ok(ExitCode::SUCCESS)
        }
        _ => Err(format!("unknown task\n{USAGE}")),
    };
    result.unwrap_or_else(|line| {
        eprintln!("error: {line}");
        ExitCode::FAILURE
    })
}

/// `cargo test --release --no-fail-fast ARGS` with the setup's environment; its output is passed through
/// line by line and summarised at the end. Exits as cargo does.
fn test(args: &[String], env: &setup::Env) -> Result<ExitCode, String> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut cmd = Command::new(&cargo);
    cmd.args(["test", "--release", "--no-fail-fast"])
        .args(args)
        .current_dir(setup::workspace_root())
        .stdout(Stdio::piped());
    env.apply(&mut cmd);
    let shown = format!("cargo test --release --no-fail-fast {}", args.join(" "));
    println!("xtask: {}", shown.trim_end());
    let mut child = cmd
        .spawn()
        .map_err(|e| format!("cannot run {cargo}: {e}"))?;
    let mut summary = summary::Summary::default();
    let stdout = child.stdout.take().expect("piped");
    let mut out = std::io::stdout().lock();
    for line in BufReader::new(stdout).lines() {
        let line = line.map_err(|e| format!("reading cargo test's output: {e}"))?;
        summary.read(&line);
        // A closed stdout (`| head`) must not stop the tests: keep reading.
        let _ = writeln!(out, "{line}");
        let _ = out.flush();
    }
    let status = child
        .wait()
        .map_err(|e| format!("waiting for cargo test: {e}"))?;
    let _ = write!(out, "{}", summary.report());
    Ok(if status.success() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(u8::try_from(status.code().unwrap_or(1)).unwrap_or(1))
    })
}
