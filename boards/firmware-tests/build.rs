//! `LATENTBKI_NO_QEMU=1` opts out of the QEMU firmware tests (host-sim/tests/firmware_qemu.rs): it sets
//! `cfg(latentbki_no_qemu)`, under which they are `#[ignore]`d, so an opted-out run shows them as ignored
//! rather than passing them. (libtest has no run-time ignore; a build script is how an environment variable
//! becomes a cfg, and cargo rebuilds when it changes.)
fn main() {
    println!("cargo::rustc-check-cfg=cfg(latentbki_no_qemu)");
    println!("cargo::rerun-if-changed=build.rs");
    println!("cargo::rerun-if-env-changed=LATENTBKI_NO_QEMU");
    if std::env::var("LATENTBKI_NO_QEMU").is_ok_and(|v| !v.is_empty() && v != "0") {
        println!("cargo::rustc-cfg=latentbki_no_qemu");
    }
}
