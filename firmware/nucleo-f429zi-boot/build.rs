//! Puts the bootloader's memory map (`memory.x` beside this file) in the
//! link search path as `board-memory.x`, which the workspace's `memory.x`
//! includes (the linker scripts are named in `.cargo/config.toml`), and
//! checks that its partitions are the image's (`memory-update.x` of
//! firmware/nucleo-f429zi, which the image is linked with): a bootloader
//! that swaps other ranges than the image writes would brick the board.

/// The image's map, and the regions both must agree on.
const IMAGE_MAP: &str = "../nucleo-f429zi/memory-update.x";
const PARTITIONS: &[&str] = &["BOOTLOADER", "ACTIVE", "SETTINGS", "BOOTLOADER_STATE", "DFU"];

fn main() -> Result<(), String> {
    let out = std::env::var("OUT_DIR").map_err(|e| format!("OUT_DIR: {e}"))?;
    println!("cargo:rerun-if-changed=memory.x\ncargo:rerun-if-changed={IMAGE_MAP}\ncargo:rustc-link-search={out}");
    let own = std::fs::read_to_string("memory.x").map_err(|e| format!("memory.x: {e}"))?;
    let image = std::fs::read_to_string(IMAGE_MAP).map_err(|e| format!("{IMAGE_MAP}: {e}"))?;
    for name in PARTITIONS {
        let (mine, theirs) = (region(&own, name), region(&image, name));
        if mine.is_none() || mine != theirs {
            return Err(format!("memory.x's {name} is {mine:x?}, {IMAGE_MAP}'s is {theirs:x?}: they must be the same"));
        }
    }
    std::fs::write(format!("{out}/board-memory.x"), own).map_err(|e| format!("board-memory.x: {e}"))
}

// region() and number(): reading a MEMORY region's line.
include!("../memory_x.rs");
