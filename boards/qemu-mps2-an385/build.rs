//! Puts this board's `memory.x` where cortex-m-rt's `link.x` finds it and adds the linker scripts.
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));
    fs::copy("memory.x", out.join("memory.x")).expect("copy memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    // Here rather than in .cargo rustflags, so a RUSTFLAGS variable cannot drop them.
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    // The stack grows down towards the statics and an overflow would corrupt them silently: demand room.
    fs::write(
        out.join("stack_guard.x"),
        "ASSERT(ORIGIN(RAM) + LENGTH(RAM) - __euninit >= 16K, \"less than 16 KiB of RAM left for the stack\");\n",
    )
    .expect("write stack_guard.x");
    println!("cargo:rustc-link-arg-bins=-Tstack_guard.x");
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=build.rs");
}
