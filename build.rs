//! Sets `latentbki_dsp` on targets whose every core has the Armv7E-M DSP instructions (Cortex-M4, M7:
//! `thumbv7em-*`), where the int8 code sums use them (`src/obs/dsp.rs`). A build script because stable Rust
//! does not set `cfg(target_feature = "dsp")` (Arm target features are unstable), and `thumbv8m.main` is
//! left out: its DSP extension is optional.
fn main() {
    println!("cargo::rustc-check-cfg=cfg(latentbki_dsp)");
    println!("cargo::rerun-if-changed=build.rs");
    let target = std::env::var("TARGET").unwrap_or_default();
    if target.starts_with("thumbv7em-") {
        println!("cargo::rustc-cfg=latentbki_dsp");
    }
}
