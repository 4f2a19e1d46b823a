//! Link arguments and the memory map, only for the boards (target_os = "none").
//! Host builds (tests, hal-sim) link normally.

use std::{env, fs, path::PathBuf};

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-env-changed=MODBUS_MAX_CONNECTIONS");
    if env::var("CARGO_CFG_TARGET_OS").as_deref() != Ok("none") {
        return;
    }
    let manifest = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").unwrap_or_default());
    // One memory map per board, in its board folder. The workspace root's
    // memory.x (found first: the linker runs there) includes board-memory.x,
    // which is the selected board's map, copied here. flip-link follows the
    // same INCLUDE, so it sees the same RAM region as the linker.
    let memory = if env::var_os("CARGO_FEATURE_NUCLEO_F429ZI").is_some() {
        manifest.join("src/board/nucleo_f429zi/memory.x")
    } else if env::var_os("CARGO_FEATURE_MPS2_AN386").is_some() {
        manifest.join("src/board/mps2_an386/memory.x")
    } else {
        return; // `cargo check --lib` for the target: nothing to link.
    };
    println!("cargo:rerun-if-changed={}", memory.display());
    let out = PathBuf::from(env::var_os("OUT_DIR").unwrap_or_default());
    println!("cargo:rerun-if-changed={}", manifest.join("../memory.x").display());
    if let Err(e) = fs::copy(&memory, out.join("board-memory.x")) {
        println!("cargo:warning=cannot copy {}: {e}", memory.display());
    }
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
}
