//! What the tests need on the machine beyond Rust itself, checked, and installed when missing:
//!
//! | need | for | installed with |
//! |---|---|---|
//! | the firmware targets | the QEMU firmware tests build each board's firmware | `rustup target add` |
//! | `qemu-system-arm`, `qemu-system-riscv32` | they run it | `apt-get install qemu-system-arm qemu-system-misc` |
//! | Python's numpy, mcap, mcap-protobuf-support | independent readers of what `host-sim` writes | `pip` (a venv where the system Python refuses) |
//! | the npm client `@foxglove/ws-protocol` | the live view's independent client | `npm ci` (nodejs and npm from apt if missing) |
//!
//! Each check prints one line; anything that cannot be installed here stops the run with one line saying
//! what to do. `LATENTBKI_NO_QEMU=1` skips the targets and QEMU (the firmware tests then show as ignored).
//!
//! QEMU on this machine kind: the image ships `qemu-utils` from bookworm-backports (10.x), which breaks
//! bookworm's `qemu-system-common` (7.2), so a plain `apt-get install qemu-system-arm` fails there; the
//! fallback installs the `qemu-utils` of the same version as the `qemu-system-common` apt would install
//! (`--allow-downgrades`).

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// The targets the QEMU boards (and the real board) build for.
pub const FIRMWARE_TARGETS: [&str; 3] = [
    "thumbv7em-none-eabihf",
    "thumbv6m-none-eabi",
    "riscv32imac-unknown-none-elf",
];

/// The QEMU binaries the boards run under, and the Debian package of each.
const QEMU: [(&str, &str); 2] = [
    ("qemu-system-arm", "qemu-system-arm"),
    ("qemu-system-riscv32", "qemu-system-misc"),
];

/// The Python modules the tests import, and the PyPI packages that provide them (pinned as the readers the
/// tests were written against).
const PY_IMPORT: &str = "import numpy, mcap, mcap_protobuf";
const PY_PACKAGES: [&str; 3] = ["numpy", "mcap==1.6.0", "mcap-protobuf-support==0.6.0"];

/// The environment variable that opts out of the QEMU firmware tests.
pub const NO_QEMU: &str = "LATENTBKI_NO_QEMU";

/// The one line that opts out, for error messages.
const OPT_OUT: &str =
    "or set LATENTBKI_NO_QEMU=1 to skip the QEMU firmware tests (they show as ignored)";

/// What the test run needs in its environment after the setup (a venv's `bin` first on `PATH`).
#[derive(Default)]
pub struct Env {
    path_first: Option<PathBuf>,
}

impl Env {
    pub fn apply(&self, cmd: &mut Command) {
        if let Some(dir) = &self.path_first {
            let path = std::env::var_os("PATH").unwrap_or_default();
            let joined = std::env::join_paths(
                std::iter::once(dir.clone()).chain(std::env::split_paths(&path)),
            )
            .expect("a venv path without ':'");
            cmd.env("PATH", joined);
        }
    }
}

/// The workspace's root directory (xtask's parent).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("xtask lives in the workspace")
        .to_path_buf()
}

/// Whether the firmware tests are opted out (`LATENTBKI_NO_QEMU` set, not empty, not `0`).
pub fn no_qemu() -> bool {
    std::env::var(NO_QEMU).is_ok_and(|v| !v.is_empty() && v != "0")
}

/// Check and install everything; the first thing that cannot be had ends it with one line.
pub fn run() -> Result<Env, String> {
    let mut apt = Apt::default();
    if no_qemu() {
        println!(
            "setup: {NO_QEMU} is set: no firmware targets or QEMU needed; the QEMU firmware tests show as ignored"
        );
    } else {
        targets()?;
        qemu(&mut apt)?;
    }
    let env = python(&mut apt)?;
    node(&mut apt)?;
    Ok(env)
}

fn targets() -> Result<(), String> {
    let missing = missing_targets()?;
    if missing.is_empty() {
        println!(
            "setup: firmware targets ok ({})",
            FIRMWARE_TARGETS.join(", ")
        );
        return Ok(());
    }
    if which("rustup").is_none() {
        return Err(format!(
            "the Rust targets {} are missing and rustup is not on PATH: add them to your toolchain, {OPT_OUT}",
            missing.join(" ")
        ));
    }
    println!("setup: adding the Rust targets {}", missing.join(" "));
    // rustup adds them to the toolchain this task runs on (`cargo xtask` sets RUSTUP_TOOLCHAIN).
    let status = Command::new("rustup")
        .args(["target", "add"])
        .args(&missing)
        .status()
        .map_err(|e| format!("cannot run rustup: {e}"))?;
    let still = missing_targets()?;
    if !status.success() || !still.is_empty() {
        return Err(format!(
            "`rustup target add {}` failed ({status}): add the targets by hand, {OPT_OUT}",
            missing.join(" ")
        ));
    }
    println!("setup: firmware targets added");
    Ok(())
}

/// The firmware targets whose standard library is not in the toolchain's sysroot.
fn missing_targets() -> Result<Vec<&'static str>, String> {
    let out = Command::new("rustc")
        .args(["--print", "sysroot"])
        .output()
        .map_err(|e| format!("cannot run rustc: {e}"))?;
    let sysroot = PathBuf::from(String::from_utf8_lossy(&out.stdout).trim());
    Ok(FIRMWARE_TARGETS
        .into_iter()
        .filter(|t| !sysroot.join("lib/rustlib").join(t).join("lib").is_dir())
        .collect())
}

/// How a QEMU binary answers `--version`.
enum Probe {
    Runs(String),
    Missing,
    Broken(PathBuf, String),
}

fn probe(bin: &str) -> Probe {
    let Some(path) = which(bin) else {
        return Probe::Missing;
    };
    match Command::new(&path)
        .arg("--version")
        .stdin(Stdio::null())
        .output()
    {
        Ok(o) if o.status.success() => Probe::Runs(
            String::from_utf8_lossy(&o.stdout)
                .lines()
                .next()
                .unwrap_or("")
                .to_string(),
        ),
        Ok(o) => Probe::Broken(path, format!("`{bin} --version` exited with {}", o.status)),
        Err(e) => Probe::Broken(path, e.to_string()),
    }
}

fn qemu(apt: &mut Apt) -> Result<(), String> {
    // A QEMU that is there but does not run (another one first on PATH, a broken install) is not
    // replaced behind the user's back.
    for (bin, _) in QEMU {
        if let Probe::Broken(path, why) = probe(bin) {
            return Err(format!(
                "{} does not run ({why}): put a working {bin} first on PATH, {OPT_OUT}",
                path.display()
            ));
        }
    }
    let missing: Vec<&str> = QEMU
        .iter()
        .filter(|(bin, _)| matches!(probe(bin), Probe::Missing))
        .map(|&(_, package)| package)
        .collect();
    if !missing.is_empty() {
        let line = "apt-get install qemu-system-arm qemu-system-misc";
        apt.usable().map_err(|why| {
            format!(
                "QEMU ({}) is not installed and {why}: install it (Debian/Ubuntu, as root: {line}), {OPT_OUT}",
                missing.join(", ")
            )
        })?;
        println!("setup: installing QEMU ({})", missing.join(" "));
        if apt.install(&missing, &[]).is_err() {
            // This machine kind's backports qemu-utils breaks bookworm's qemu-system-common: install the
            // qemu-utils that goes with the qemu-system-common apt picks.
            let Some(version) = apt.candidate("qemu-system-common") else {
                return Err(format!("`{line}` failed (see above): {OPT_OUT}"));
            };
            let utils = format!("qemu-utils={version}");
            println!("setup: retrying with {utils} (--allow-downgrades): the installed qemu-utils conflicts");
            let mut packages = missing.clone();
            packages.push(&utils);
            apt.install(&packages, &["--allow-downgrades"]).map_err(|_| {
                format!(
                    "`{line}` failed, also with {utils} --allow-downgrades (see above): install QEMU by hand, {OPT_OUT}"
                )
            })?;
        }
    }
    let mut versions = Vec::new();
    for (bin, _) in QEMU {
        match probe(bin) {
            Probe::Runs(v) => versions.push(format!("{bin}: {v}")),
            Probe::Missing => {
                return Err(format!(
                    "{bin} is still not on PATH after installing QEMU (apt puts it in /usr/bin): put it on PATH, \
                     {OPT_OUT}"
                ))
            }
            Probe::Broken(path, why) => {
                return Err(format!(
                    "{} does not run ({why}): {OPT_OUT}",
                    path.display()
                ))
            }
        }
    }
    println!("setup: QEMU ok ({})", versions.join("; "));
    Ok(())
}

fn python(apt: &mut Apt) -> Result<Env, String> {
    let imports = |python: &Path| {
        Command::new(python)
            .args(["-c", PY_IMPORT])
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    };
    let venv = workspace_root().join("target/xtask-venv");
    let venv_python = venv.join("bin/python3");
    let system = Path::new("python3");
    if which("python3").is_none() {
        apt.usable().map_err(|why| {
            format!("python3 is not installed and {why}: install Python 3 with pip and venv")
        })?;
        apt.install(&["python3", "python3-pip", "python3-venv"], &[])
            .map_err(|_| "installing python3 failed (see above)".to_string())?;
    }
    if imports(system) {
        println!("setup: Python packages ok ({})", PY_PACKAGES.join(" "));
        return Ok(Env::default());
    }
    let use_venv = || {
        println!(
            "setup: Python packages ok in {} (first on the tests' PATH)",
            venv.display()
        );
        Ok(Env {
            path_first: Some(venv.join("bin")),
        })
    };
    if imports(&venv_python) {
        return use_venv();
    }
    println!(
        "setup: installing Python packages ({})",
        PY_PACKAGES.join(" ")
    );
    let pip = |python: &Path| {
        Command::new(python)
            .args([
                "-m",
                "pip",
                "install",
                "--quiet",
                "--disable-pip-version-check",
            ])
            .args(PY_PACKAGES)
            .env("PIP_ROOT_USER_ACTION", "ignore")
            .status()
            .is_ok_and(|s| s.success())
    };
    if pip(system) && imports(system) {
        println!("setup: Python packages installed");
        return Ok(Env::default());
    }
    // A system Python may refuse pip installs (PEP 668): a venv of the project's own.
    println!(
        "setup: the system Python refused them: a venv in {}",
        venv.display()
    );
    let make_venv = || {
        Command::new("python3")
            .args(["-m", "venv"])
            .arg(&venv)
            .status()
            .is_ok_and(|s| s.success())
    };
    if !make_venv() {
        apt.usable()
            .and_then(|()| apt.install(&["python3-venv"], &[]).map_err(|_| "apt-get failed".into()))
            .map_err(|why| {
                format!("`python3 -m venv` failed and {why}: install python3-venv, or pip install {} yourself", PY_PACKAGES.join(" "))
            })?;
        if !make_venv() {
            return Err("`python3 -m venv` failed (see above)".into());
        }
    }
    if !(pip(&venv_python) && imports(&venv_python)) {
        return Err(format!(
            "pip could not install {} (see above)",
            PY_PACKAGES.join(" ")
        ));
    }
    use_venv()
}

fn node(apt: &mut Apt) -> Result<(), String> {
    let dir = workspace_root().join("host-sim/station/viewer-test");
    let ready =
        || which("node").is_some() && dir.join("node_modules/@foxglove/ws-protocol").is_dir();
    if ready() {
        println!("setup: npm packages ok (host-sim/station/viewer-test)");
        return Ok(());
    }
    if which("npm").is_none() || which("node").is_none() {
        apt.usable().map_err(|why| {
            format!("node/npm are not installed and {why}: install Node.js and npm")
        })?;
        println!("setup: installing nodejs npm");
        apt.install(&["nodejs", "npm"], &[])
            .map_err(|_| "apt-get install nodejs npm failed (see above)".to_string())?;
    }
    println!("setup: npm ci (host-sim/station/viewer-test)");
    let ok = Command::new("npm")
        .args(["ci", "--no-audit", "--no-fund", "--loglevel=error"])
        .current_dir(&dir)
        .status()
        .is_ok_and(|s| s.success());
    if !ok || !ready() {
        return Err(format!("`npm ci` in {} failed (see above)", dir.display()));
    }
    Ok(())
}

/// Debian's apt, as root; `apt-get update` once per run, before the first install.
#[derive(Default)]
struct Apt {
    updated: bool,
}

impl Apt {
    /// Why apt cannot be used here, if it cannot.
    fn usable(&self) -> Result<(), String> {
        if which("apt-get").is_none() {
            return Err("this machine has no apt-get".into());
        }
        let uid = Command::new("id").arg("-u").output().ok();
        let root = uid.is_some_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0");
        if !root {
            return Err("this task is not root (apt-get needs root)".into());
        }
        Ok(())
    }

    fn install(&mut self, packages: &[&str], flags: &[&str]) -> Result<(), ()> {
        if !self.updated {
            // A failed update leaves the old lists: the install may still work, so it is tried anyway.
            let _ = Command::new("apt-get").args(["update", "-qq"]).status();
            self.updated = true;
        }
        let ok = Command::new("apt-get")
            .args(["install", "-y", "-qq", "--no-install-recommends"])
            .args(flags)
            .args(packages)
            .env("DEBIAN_FRONTEND", "noninteractive")
            .status()
            .is_ok_and(|s| s.success());
        if ok {
            Ok(())
        } else {
            Err(())
        }
    }

    /// The version apt would install of `package`.
    fn candidate(&self, package: &str) -> Option<String> {
        let out = Command::new("apt-cache")
            .args(["policy", package])
            .output()
            .ok()?;
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .find_map(|l| l.trim().strip_prefix("Candidate: ").map(str::to_string))
            .filter(|v| v != "(none)")
    }
}

/// The first executable called `name` on PATH.
fn which(name: &str) -> Option<PathBuf> {
    use std::os::unix::fs::PermissionsExt;
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|dir| dir.join(name))
        .find(|p| {
            p.metadata()
                .is_ok_and(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
        })
}
