//! Puts the bootloader's memory map (`memory.x` beside this file) in the
//! link search path as `board-memory.x`, which the workspace's `memory.x`
//! includes. The linker scripts are named in `.cargo/config.toml`.

fn main() {
    let out = std::env::var("OUT_DIR").unwrap_or_default();
    if let Err(e) = std::fs::copy("memory.x", format!("{out}/board-memory.x")) {
        println!("cargo:warning=cannot copy memory.x: {e}");
    }
    println!("cargo:rerun-if-changed=memory.x\ncargo:rustc-link-search={out}");
}
