//! The NUCLEO-F429ZI's bootloader (docs/update.md): embassy-boot-stm32 over
//! the chip's flash with the partitions of `memory.x`, so an armed update
//! is swapped into ACTIVE (or one that did not confirm itself rolled back),
//! page by page and power-fail safe; then the image in ACTIVE starts.
//!
//! Built in CI, not yet flashed: the image linked at ACTIVE (a `memory.x`
//! for the `update` feature of nucleo-f429zi) and the IWDG during a swap
//! (about 1-2 s per 128 KiB sector erase, several per swap) are still to
//! come.
#![no_std]
#![no_main]

use core::cell::RefCell;

use cortex_m_rt::entry;
use embassy_boot_stm32::{BootLoader, BootLoaderConfig};
use embassy_stm32::flash::{FLASH_BASE, Flash};
use embassy_sync::blocking_mutex::Mutex;

/// The swap's copy buffer: a divisor of the 128 KiB page, a multiple of
/// the 4-byte flash word.
const COPY_LEN: usize = 2048;

#[entry]
fn main() -> ! {
    let p = embassy_stm32::init(Default::default());
    let flash = Mutex::new(RefCell::new(Flash::new_blocking(p.FLASH)));
    let config = BootLoaderConfig::from_linkerfile_blocking(&flash, &flash, &flash);
    let active = config.active.offset();
    let Ok(bootloader) = BootLoader::try_prepare::<_, _, _, COPY_LEN>(config) else {
        // The flash failed under a swap: stop here rather than start a
        // half-copied image (a reset tries again; the swap resumes).
        halt()
    };
    // SAFETY: ACTIVE holds the image's vector table at its start (memory.x);
    // `load` sets VTOR to it and jumps to its reset handler.
    unsafe { bootloader.load(FLASH_BASE as u32 + active) }
}

fn halt() -> ! {
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    halt()
}
