//! TLS on the NUCLEO (feature `tls`, docs/tls.md): its arena in the
//! STM32F429's 64 KiB CCM data RAM at `0x1000_0000` (RM0090 2.3.1), which
//! only the CPU reaches (no DMA: the Ethernet MAC's buffers stay in SRAM)
//! and which nothing else uses, so the arena costs none of the 192 KiB of
//! SRAM the static RAM budget counts. Its clock, RCC_AHB1ENR.CCMDATARAMEN,
//! is on from reset (RM0090 6.3.10: reset value 0x0010_0000). The entropy
//! is the hardware RNG's (`http::entropy`).

use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, Ordering};

use adapter::server::secure::ARENA_LEN;

/// The CCM RAM's size; the arena must fit it (checked at build time).
const CCM_LEN: usize = 64 * 1024;
const _: () = assert!(ARENA_LEN <= CCM_LEN, "the TLS arena must fit the 64 KiB CCM RAM");

/// The arena, in `.ccmram` (memory.x: NOLOAD, so not zeroed at start:
/// `tls::init` takes its bytes as free memory and `calloc` zeroes what it
/// hands out).
#[unsafe(link_section = ".ccmram")]
static mut ARENA: MaybeUninit<[u8; ARENA_LEN]> = MaybeUninit::uninit();
/// Whether [`arena`] gave it out (in SRAM: zeroed at start).
static TAKEN: AtomicBool = AtomicBool::new(false);

/// The arena, once (`None` after).
pub fn arena() -> Option<&'static mut [u8]> {
    if TAKEN.swap(true, Ordering::AcqRel) {
        return None;
    }
    // SAFETY: handed out once (TAKEN); the bytes are then the arena's
    // alone, and a `u8` array has no invalid values.
    Some(unsafe { core::slice::from_raw_parts_mut((&raw mut ARENA).cast::<u8>(), ARENA_LEN) })
}
