//! Sets two `cfg`s the core's code paths are chosen by, from the target (stable Rust has no `cfg` for them):
//! - `latentbki_dsp` on targets whose every core has the Armv7E-M DSP instructions (Cortex-M4, M7:
//!   `thumbv7em-*`), where the int8 code sums use them (`src/obs/dsp.rs`). Arm target features are
//!   unstable, and `thumbv8m.main` is left out: its DSP extension is optional.
//! - `latentbki_soft_float` on targets without a hardware FPU in their ABI (`*-eabi` Arm targets such as
//!   thumbv6m and thumbv7m, riscv32 without the F extension), where f32 arithmetic is library calls: the
//!   core keeps one compact path there and links no code meant for an FPU (`quant::HAS_FPU`).
fn main() {
    println!("cargo::rustc-check-cfg=cfg(latentbki_dsp)");
    println!("cargo::rustc-check-cfg=cfg(latentbki_soft_float)");
    println!("cargo::rerun-if-changed=build.rs");
    let target = std::env::var("TARGET").unwrap_or_default();
    if target.starts_with("thumbv7em-") {
        println!("cargo::rustc-cfg=latentbki_dsp");
    }
    let cfg = |name: &str| std::env::var(format!("CARGO_CFG_{name}")).unwrap_or_default();
    let has_f = cfg("TARGET_FEATURE").split(',').any(|f| f == "f");
    if cfg("TARGET_ABI") == "eabi" || (cfg("TARGET_ARCH") == "riscv32" && !has_f) {
        println!("cargo::rustc-cfg=latentbki_soft_float");
    }
}
