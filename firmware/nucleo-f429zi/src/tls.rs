//! TLS on the NUCLEO (feature `tls`, docs/tls.md): its arena, most of it
//! in the STM32F429's 64 KiB CCM data RAM at `0x1000_0000` (RM0090 2.3.1),
//! which only the CPU reaches (no DMA: the Ethernet MAC's buffers stay in
//! SRAM) and which nothing else uses, and the rest in SRAM: two regions of
//! one arena. Its clock, RCC_AHB1ENR.CCMDATARAMEN, is on from reset
//! (RM0090 6.3.10: reset value 0x0010_0000). The entropy is the hardware
//! RNG's (`http::entropy`).

use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, Ordering};

use adapter::program::TLS_ARENA_LEN;

/// The CCM RAM's size: the arena's first region fills it.
const CCM_LEN: usize = 64 * 1024;
/// The arena's second region, in SRAM: the rest of [`TLS_ARENA_LEN`], and 4
/// KiB more, since a block (a session's 16 KiB record buffer) never spans
/// two regions.
const SRAM_PART_LEN: usize = TLS_ARENA_LEN.saturating_sub(CCM_LEN) + 4 * 1024;

/// The arena's first region, in `.ccmram` (memory.x: NOLOAD, so not zeroed
/// at start: `tls::init` takes its bytes as free memory and `calloc` zeroes
/// what it hands out).
#[unsafe(link_section = ".ccmram")]
static mut CCM_PART: MaybeUninit<[u8; CCM_LEN]> = MaybeUninit::uninit();
/// The second, in SRAM (.bss).
static mut SRAM_PART: MaybeUninit<[u8; SRAM_PART_LEN]> = MaybeUninit::uninit();
/// Whether [`arena`] gave it out (in SRAM: zeroed at start).
static TAKEN: AtomicBool = AtomicBool::new(false);

/// The arena's two regions, once (`None` after).
pub fn arena() -> Option<[&'static mut [u8]; 2]> {
    if TAKEN.swap(true, Ordering::AcqRel) {
        return None;
    }
    // SAFETY: handed out once (TAKEN); the bytes are then the arena's
    // alone, and a `u8` array has no invalid values.
    unsafe {
        Some([
            core::slice::from_raw_parts_mut((&raw mut CCM_PART).cast::<u8>(), CCM_LEN),
            core::slice::from_raw_parts_mut((&raw mut SRAM_PART).cast::<u8>(), SRAM_PART_LEN),
        ])
    }
}
