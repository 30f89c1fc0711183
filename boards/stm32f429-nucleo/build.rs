//! Puts this board's `memory.x` where cortex-m-rt's `link.x` finds it, and the VL53L5CX firmware blob
//! (ST's, not redistributable: `VL53L5CX_FW=path/to/blob.bin cargo build --release`) where `main.rs`
//! includes it — an empty file without one.
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));
    fs::copy("memory.x", out.join("memory.x")).expect("copy memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=build.rs");
    let blob = out.join("vl53l5cx_fw.bin");
    match env::var_os("VL53L5CX_FW") {
        Some(path) => {
            fs::copy(&path, &blob).expect("copy the VL53L5CX firmware blob named by VL53L5CX_FW");
            println!("cargo:rerun-if-changed={}", PathBuf::from(path).display());
        }
        None => fs::write(&blob, []).expect("write an empty VL53L5CX blob"),
    }
    println!("cargo:rerun-if-env-changed=VL53L5CX_FW");
}
