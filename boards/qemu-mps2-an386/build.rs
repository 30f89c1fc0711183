//! Puts the top-level `memory.x` where cortex-m-rt's `link.x` finds it and adds the linker scripts.
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));
    // One memory layout for the project: the top-level memory.x (Cortex-M4F, 192 KiB RAM).
    fs::copy("../../memory.x", out.join("memory.x")).expect("copy ../../memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    // Here rather than in .cargo rustflags, so a RUSTFLAGS variable cannot drop them.
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    // The stack grows down towards the statics and an overflow would corrupt them silently: demand room.
    // 16 KiB; 8 KiB in the measurement build of an explorer-sized view (`--features explorer-view`, not
    // shipped), whose 6,912 B of hits leave ≈ 10 KiB: `boards/measure.sh --explorer-view` fails when its
    // stack high-water mark is over 8 KiB.
    let kib = if env::var_os("CARGO_FEATURE_EXPLORER_VIEW").is_some() {
        8
    } else {
        16
    };
    fs::write(
        out.join("stack_guard.x"),
        format!("ASSERT(ORIGIN(RAM) + LENGTH(RAM) - __euninit >= {kib}K, \"less than {kib} KiB of RAM left for the stack\");\n"),
    )
    .expect("write stack_guard.x");
    println!("cargo:rustc-link-arg-bins=-Tstack_guard.x");
    if env::var_os("CARGO_FEATURE_DEFMT").is_some() {
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
    println!("cargo:rerun-if-changed=../../memory.x");
    println!("cargo:rerun-if-changed=build.rs");
}
