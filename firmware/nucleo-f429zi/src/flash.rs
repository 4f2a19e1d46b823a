//! The settings flash: bank 2's first two 16 KiB sectors (12 and 13,
//! `0x0810_0000`, 32 KiB), the `SETTINGS` region of `memory.x`, outside the
//! image.
//!
//! [`SettingsFlash`] is an `embedded-storage-async` NorFlash over that range
//! and nothing else: its offset 0 is the region's first byte, and a read,
//! write or erase that would reach past its end is refused
//! ([`Error::Size`]), so the settings store cannot touch the image.
//!
//! It runs on embassy-stm32's interrupt-driven flash driver (bank 2's
//! region of 16 KiB sectors): a sector erase takes hundreds of
//! milliseconds, and the executor keeps running the other tasks meanwhile
//! (the code runs from bank 1, which stays readable while bank 2 is erased).
//! A blocking driver would stall the network and the watchdog's feeding for
//! as long.

use embassy_stm32::Peri;
use embassy_stm32::flash::{Async, BANK2_REGION1, Bank2Region1, Error, FLASH_BASE, FLASH_SIZE, Flash, FlashBank};
use embassy_stm32::peripherals::FLASH;
use embedded_storage_async::nor_flash::{ErrorType, NorFlash, ReadNorFlash};

use crate::board::Irqs;

// SETTINGS_START and SETTINGS_LEN, read from memory.x by build.rs.
include!(concat!(env!("OUT_DIR"), "/memory.rs"));

/// Bank 2 is the upper half: a 2 MiB STM32F429 always has two banks.
const BANK2_START: u32 = FLASH_BASE as u32 + FLASH_SIZE as u32 / 2;
/// The erase unit of bank 2's first region (sectors 12-15).
const SECTOR: u32 = BANK2_REGION1.erase_size;

const _: () = {
    assert!(matches!(BANK2_REGION1.bank, FlashBank::Bank2) && BANK2_REGION1.offset == 0);
    assert!(SETTINGS_START >= BANK2_START, "memory.x: SETTINGS must be in bank 2");
    assert!((SETTINGS_START - BANK2_START).is_multiple_of(SECTOR), "memory.x: SETTINGS must start a sector");
    assert!(SETTINGS_LEN > 0 && SETTINGS_LEN.is_multiple_of(SECTOR), "memory.x: SETTINGS must be whole sectors");
    assert!(
        SETTINGS_START - BANK2_START + SETTINGS_LEN <= BANK2_REGION1.size,
        "memory.x: SETTINGS must lie in bank 2's 16 KiB sectors (12-15)"
    );
};

/// Where the settings start in bank 2's first region (the driver counts from its base).
const OFFSET: u32 = SETTINGS_START - BANK2_START;

/// The flash of the settings store (see the module's documentation). Made
/// once, by [`settings_flash`].
pub struct SettingsFlash {
    region: Bank2Region1<'static, Async>,
}

impl core::fmt::Debug for SettingsFlash {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("SettingsFlash").field("start", &SETTINGS_START).field("len", &SETTINGS_LEN).finish()
    }
}

/// The settings flash over the chip's flash controller; its interrupt is
/// bound in [`Irqs`].
pub fn settings_flash(flash: Peri<'static, FLASH>) -> SettingsFlash {
    SettingsFlash { region: Flash::new(flash, Irqs).into_regions().bank2_region1 }
}

impl SettingsFlash {
    /// The region offset of `len` bytes at `offset` of the settings, if all of them lie inside.
    fn locate(offset: u32, len: usize) -> Result<u32, Error> {
        let end = u32::try_from(len).ok().and_then(|len| offset.checked_add(len));
        match end {
            Some(end) if end <= SETTINGS_LEN => Ok(OFFSET + offset),
            _ => Err(Error::Size),
        }
    }
}

impl ErrorType for SettingsFlash {
    type Error = Error;
}

impl ReadNorFlash for SettingsFlash {
    const READ_SIZE: usize = <Bank2Region1<'static, Async> as ReadNorFlash>::READ_SIZE;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Error> {
        let at = Self::locate(offset, bytes.len())?;
        self.region.read(at, bytes).await
    }

    fn capacity(&self) -> usize {
        SETTINGS_LEN as usize
    }
}

impl NorFlash for SettingsFlash {
    const WRITE_SIZE: usize = <Bank2Region1<'static, Async> as NorFlash>::WRITE_SIZE;
    const ERASE_SIZE: usize = <Bank2Region1<'static, Async> as NorFlash>::ERASE_SIZE;

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Error> {
        let at = Self::locate(offset, bytes.len())?;
        self.region.write(at, bytes).await
    }

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Error> {
        let len = to.checked_sub(from).ok_or(Error::Size)?;
        let at = Self::locate(from, len as usize)?;
        self.region.erase(at, at + len).await
    }
}
