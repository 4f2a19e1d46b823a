//! The NUCLEO-F429ZI's bootloader (docs/update.md): embassy-boot-stm32 over
//! the chip's flash with the partitions of `memory.x`, so an armed update
//! is swapped into ACTIVE (or one that did not confirm itself rolled back),
//! page by page and power-fail safe; then the image in ACTIVE starts (the
//! nucleo-f429zi image built with `update`, linked there by its
//! `memory-update.x`).
//!
//! The independent watchdog: once started it runs across every reset but a
//! power-on one, so the image's (2 s) may be running when the bootloader
//! starts. The bootloader sets it to [`WATCHDOG_TIMEOUT_US`] (starting it
//! when it is not running) and pets it before each erase and write of the
//! swap (a 128 KiB sector erase takes 1-2 s) and before it jumps: an image
//! that never gets as far as its own watchdog is reset then, and, on trial,
//! rolled back.
//!
//! It also serves the signature check to the image (`SERVICES`,
//! update_image::service). Built in CI; not yet run on a board.
//!
//! The chip's traps (docs/nucleo-f429zi.md, "Silicon"), as the image steps
//! around them, from the image's own `silicon.rs`: PA12 held low before
//! the first read of bank 2 (the boot state is there; on silicon before
//! revision 3 embassy-stm32 would panic, and this would never start the
//! image), the flash accelerator on, and every erase at x32 parallelism,
//! one sector at a time (the swap's 128 KiB pages: 1 s typical, 2 s at
//! most, where embassy's default x8 took 2 s typical, 4 s at most).
#![no_std]
#![no_main]

/// The image's, shared: what both programs do about the chip's traps.
#[path = "../../nucleo-f429zi/src/silicon.rs"]
mod silicon;

use core::cell::RefCell;

use cortex_m_rt::entry;
use embassy_boot_stm32::{BootLoader, BootLoaderConfig};
use embassy_stm32::flash::{Blocking, Error, FLASH_BASE, Flash, get_flash_regions};
use embassy_stm32::peripherals::IWDG;
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_sync::blocking_mutex::Mutex;
use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};

/// The swap's copy buffer: a divisor of the 128 KiB page, a multiple of
/// the 4-byte flash word.
const COPY_LEN: usize = 2048;

/// The signature check this bootloader serves to the image it starts
/// (update_image::service), where the image looks for it (memory.x).
#[used]
#[unsafe(link_section = ".boot_services")]
static SERVICES: update_image::service::Services = update_image::service::Services::new();

/// The watchdog's timeout while the bootloader runs and until the image
/// takes it over: longer than any one erase of the swap, and the image's
/// limit to get its own watchdog going. The LSI runs at 17-47 kHz, so it
/// is 20-56 s in fact (the IWDG's longest is 32.8 s at the nominal 32 kHz).
const WATCHDOG_TIMEOUT_US: u32 = 30_000_000;

#[entry]
fn main() -> ! {
    let p = embassy_stm32::init(Default::default());
    let mut watchdog = IndependentWatchdog::new(p.IWDG, WATCHDOG_TIMEOUT_US);
    watchdog.unleash();
    watchdog.pet();
    silicon::flash_accelerator_on();
    // Before BootLoaderConfig and try_prepare read the boot state (bank 2).
    silicon::hold_pa12_low(p.PA12);
    let flash = Mutex::new(RefCell::new(Petting { flash: Flash::new_blocking(p.FLASH), watchdog }));
    let config = BootLoaderConfig::from_linkerfile_blocking(&flash, &flash, &flash);
    let active = config.active.offset();
    let Ok(bootloader) = BootLoader::try_prepare::<_, _, _, COPY_LEN>(config) else {
        // The flash failed under a swap: stop here rather than start a
        // half-copied image (the watchdog resets; the swap resumes).
        halt()
    };
    flash.lock(|flash| flash.borrow_mut().watchdog.pet());
    // SAFETY: ACTIVE holds the image's vector table at its start (memory.x);
    // `load` sets VTOR to it and jumps to its reset handler.
    unsafe { bootloader.load(FLASH_BASE as u32 + active) }
}

/// The flash, petting the watchdog before each erase and write, and
/// erasing one sector at a time at x32.
struct Petting {
    flash: Flash<'static, Blocking>,
    watchdog: IndependentWatchdog<'static, IWDG>,
}

impl ErrorType for Petting {
    type Error = Error;
}

impl ReadNorFlash for Petting {
    const READ_SIZE: usize = <Flash<'static, Blocking> as ReadNorFlash>::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Error> {
        self.flash.read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl NorFlash for Petting {
    const WRITE_SIZE: usize = <Flash<'static, Blocking> as NorFlash>::WRITE_SIZE;
    const ERASE_SIZE: usize = <Flash<'static, Blocking> as NorFlash>::ERASE_SIZE;

    /// Sector by sector (embassy-boot erases a page, 128 KiB, or the
    /// state's sector), each at x32 with the watchdog petted first.
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Error> {
        let mut at = from;
        while at < to {
            let address = FLASH_BASE as u32 + at;
            let region = get_flash_regions()
                .iter()
                .find(|region| (region.base()..region.end()).contains(&address))
                .ok_or(Error::Size)?;
            // Checked before the flash is unlocked.
            if !(address - region.base()).is_multiple_of(region.erase_size) {
                return Err(Error::Unaligned);
            }
            let next = at + region.erase_size;
            self.watchdog.pet();
            silicon::erase_at_x32();
            self.flash.blocking_erase(at, next)?;
            at = next;
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Error> {
        self.watchdog.pet();
        self.flash.write(offset, bytes)
    }
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
