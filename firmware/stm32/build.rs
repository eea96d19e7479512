//! Puts the workspace's `memory.x` (the STM32F411CE memory map) on the linker search path, where
//! cortex-m-rt's `link.x` includes it. embassy-stm32's `memory-x` feature stays off: one map, ours.

use std::path::PathBuf;
use std::{env, fs};

fn main() {
    let manifest_dir = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR"));
    let memory_x = manifest_dir.join("../../memory.x");
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));

    fs::copy(&memory_x, out.join("memory.x"))
        .unwrap_or_else(|e| panic!("copying {} into OUT_DIR: {e}", memory_x.display()));

    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory_x.display());
    println!("cargo:rerun-if-changed=build.rs");
}
