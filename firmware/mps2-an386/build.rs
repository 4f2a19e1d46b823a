//! Puts the mps2-an386's memory map in the link search path as
//! `board-memory.x`, which the workspace's `memory.x` includes: `memory.x`
//! beside this file (QEMU boots the image directly), or with the `update`
//! feature `memory-update.x` (the image runs from the ACTIVE partition
//! under the bootloader). The linker scripts are named in `.cargo/config.toml`.

fn main() {
    let map = if std::env::var_os("CARGO_FEATURE_UPDATE").is_some() { "memory-update.x" } else { "memory.x" };
    let out = std::env::var("OUT_DIR").unwrap_or_default();
    if let Err(e) = std::fs::copy(map, format!("{out}/board-memory.x")) {
        println!("cargo:warning=cannot copy {map}: {e}");
    }
    println!("cargo:rerun-if-changed=memory.x\ncargo:rerun-if-changed=memory-update.x\ncargo:rustc-link-search={out}");
}
