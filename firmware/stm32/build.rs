//! Puts the memory map on the linker search path, where cortex-m-rt's `link.x` includes it: the
//! workspace's `memory.x` (STM32F411CE) for the board, `qemu-memory.x` (QEMU's netduinoplus2, an
//! STM32F405) for the `qemu` build. embassy-stm32's `memory-x` feature stays off: one map, ours.

use std::path::PathBuf;
use std::{env, fs};

fn main() {
    let manifest_dir = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR"));
    let memory_x = if env::var_os("CARGO_FEATURE_QEMU").is_some() {
        manifest_dir.join("qemu-memory.x")
    } else {
        manifest_dir.join("../../memory.x")
    };
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));

    fs::copy(&memory_x, out.join("memory.x"))
        .unwrap_or_else(|e| panic!("copying {} into OUT_DIR: {e}", memory_x.display()));

    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory_x.display());
    println!("cargo:rerun-if-changed=qemu-memory.x");
    println!("cargo:rerun-if-changed=build.rs");
}
