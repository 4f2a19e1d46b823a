//! Links the nucleo-f429zi image: its memory map (`memory.x` beside this file,
//! which the workspace's `memory.x` includes as `board-memory.x`), then
//! cortex-m-rt's and defmt's linker scripts.

fn main() {
    let out = std::env::var("OUT_DIR").unwrap_or_default();
    if let Err(e) = std::fs::copy("memory.x", format!("{out}/board-memory.x")) {
        println!("cargo:warning=cannot copy memory.x: {e}");
    }
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rustc-link-search={out}");
    for arg in ["--nmagic", "-Tlink.x", "-Tdefmt.x"] {
        println!("cargo:rustc-link-arg-bins={arg}");
    }
}
