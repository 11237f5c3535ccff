//! Puts this board's `memory.x` (Pico: BOOT2 + the first MiB of flash for the
//! program, 256 KiB RAM) on the link search path and links with cortex-m-rt's
//! `link.x`.

use std::{env, fs, path::PathBuf};

fn main() {
    let manifest =
        PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"));
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    let memory = manifest.join("memory.x");
    if let Err(e) = fs::copy(&memory, out.join("memory.x")) {
        panic!("cannot copy {}: {e}", memory.display());
    }
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory.display());
    println!("cargo:rerun-if-changed=build.rs");
    // --nmagic: no page alignment of the sections (flash starts right after BOOT2).
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
}
