//! Bank 2's partitions, outside the image: the settings (sectors 12-13,
//! `0x0810_0000`, 32 KiB, the `SETTINGS` region of the memory map) and,
//! with `update`, embassy-boot's state (sector 16) and DFU (sectors 17-19).
//!
//! A [`Partition`] is an `embedded-storage-async` NorFlash over its range
//! of one region of the flash driver and nothing else: its offset 0 is the
//! partition's first byte, and a read, write or erase that would reach past
//! its end is refused ([`Error::Size`]), so the settings store and the
//! updater cannot touch the image or each other. Bank 2's three regions
//! (16, 64 and 128 KiB sectors) hold one partition each, so each partition
//! owns its region.
//!
//! It runs on embassy-stm32's interrupt-driven flash driver: a sector erase
//! takes hundreds of milliseconds (a 128 KiB one 1 s typical, 2 s at most,
//! at the x32 parallelism set here), and the executor keeps running the
//! other tasks meanwhile (the code runs from bank 1, which stays readable
//! while bank 2 is erased). A blocking driver would stall the network and
//! the watchdog's feeding for as long.
//!
//! Bank 2 has one owner, [`BANK2`]: every read, write and erase of every
//! partition takes it. The flash reads while writing only across banks
//! (RM0090, read-while-write): a read of bank 2 while a sector of bank 2 is
//! erased stalls the bus, and with it the core, for the rest of the erase
//! (embassy's reads take no lock), so a settings load during an upload's
//! erase of DFU would stop the network and the watchdog's feeding for up
//! to 2 s. Holding the lock, a reader waits for the erase to end instead,
//! and the other tasks run. Every caller erases one sector a call (the
//! settings store a 16 KiB page, the updater a 128 KiB DFU sector as the
//! upload reaches it, embassy-boot's state its one 64 KiB sector), so a
//! reader waits for one sector at most, not for all of DFU.
//!
//! Erases run at x32 parallelism ([`crate::silicon::erase_at_x32`]), set
//! under the same lock right before the erase: nothing rewrites FLASH_CR
//! in between (only a write would, and writes take the lock), and
//! embassy's erase keeps PSIZE from one sector to the next (it only
//! modifies FLASH_CR, and its unlock writes KEYR alone).

use embassy_stm32::Peri;
use embassy_stm32::flash::{Async, BANK2_REGION1, Bank2Region1, Error, FLASH_BASE, FLASH_SIZE, Flash, FlashRegion};
#[cfg(feature = "update")]
use embassy_stm32::flash::{BANK2_REGION2, BANK2_REGION3, Bank2Region2, Bank2Region3};
use embassy_stm32::peripherals::FLASH;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embedded_storage_async::nor_flash::{ErrorType, NorFlash, ReadNorFlash};

use crate::board::Irqs;

// SETTINGS_START and SETTINGS_LEN (and with `update` the partitions'),
// read from the memory map by build.rs.
include!(concat!(env!("OUT_DIR"), "/memory.rs"));

/// Bank 2 is the upper half: a 2 MiB STM32F429 always has two banks.
const BANK2_START: u32 = FLASH_BASE as u32 + FLASH_SIZE as u32 / 2;

/// Bank 2's owner: held across every read, write and erase of
/// every [`Partition`], so no read of bank 2 meets an erase of it.
static BANK2: Mutex<CriticalSectionRawMutex, ()> = Mutex::new(());

/// Whether `start..start + len` is whole sectors of `region` (in bank 2).
const fn fits(region: &FlashRegion, start: u32, len: u32) -> bool {
    let base = BANK2_START + region.offset;
    start >= base
        && (start - base).is_multiple_of(region.erase_size)
        && len > 0
        && len.is_multiple_of(region.erase_size)
        && start - base + len <= region.size
}

const _: () = {
    assert!(matches!(BANK2_REGION1.bank, embassy_stm32::flash::FlashBank::Bank2) && BANK2_REGION1.offset == 0);
    assert!(fits(&BANK2_REGION1, SETTINGS_START, SETTINGS_LEN), "memory map: SETTINGS must be whole sectors 12-15");
};
#[cfg(feature = "update")]
const _: () = {
    assert!(fits(&BANK2_REGION2, BOOTLOADER_STATE_START, BOOTLOADER_STATE_LEN), "BOOTLOADER_STATE must be sector 16");
    assert!(fits(&BANK2_REGION3, DFU_START, DFU_LEN), "memory map: DFU must be whole sectors of 17-23");
};

/// `LEN` bytes of a region `R` of the flash driver from its byte `OFFSET`
/// (constants: the bounds checks compile to comparisons with immediates).
pub struct Partition<R, const OFFSET: u32, const LEN: u32> {
    region: R,
}

impl<R, const OFFSET: u32, const LEN: u32> core::fmt::Debug for Partition<R, OFFSET, LEN> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Partition").field("offset", &OFFSET).field("len", &LEN).finish()
    }
}

/// A partition's offset in its region.
const fn within(region: &FlashRegion, start: u32) -> u32 {
    start - BANK2_START - region.offset
}

/// The settings store's flash.
pub type SettingsFlash =
    Partition<Bank2Region1<'static, Async>, { within(&BANK2_REGION1, SETTINGS_START) }, SETTINGS_LEN>;
/// embassy-boot's state partition.
#[cfg(feature = "update")]
pub type StateFlash =
    Partition<Bank2Region2<'static, Async>, { within(&BANK2_REGION2, BOOTLOADER_STATE_START) }, BOOTLOADER_STATE_LEN>;
/// The DFU partition: the next image.
#[cfg(feature = "update")]
pub type DfuFlash = Partition<Bank2Region3<'static, Async>, { within(&BANK2_REGION3, DFU_START) }, DFU_LEN>;

/// Bank 2's partitions.
#[derive(Debug)]
pub struct Partitions {
    pub settings: SettingsFlash,
    #[cfg(feature = "update")]
    pub state: StateFlash,
    #[cfg(feature = "update")]
    pub dfu: DfuFlash,
}

/// The partitions over the chip's flash controller; its interrupt is
/// bound in [`Irqs`].
pub fn partitions(flash: Peri<'static, FLASH>) -> Partitions {
    let regions = Flash::new(flash, Irqs).into_regions();
    Partitions {
        settings: Partition { region: regions.bank2_region1 },
        #[cfg(feature = "update")]
        state: Partition { region: regions.bank2_region2 },
        #[cfg(feature = "update")]
        dfu: Partition { region: regions.bank2_region3 },
    }
}

impl<R, const OFFSET: u32, const LEN: u32> Partition<R, OFFSET, LEN> {
    /// The region offset of `len` bytes at `offset` of the partition, if all of them lie inside.
    fn locate(offset: u32, len: usize) -> Result<u32, Error> {
        let end = u32::try_from(len).ok().and_then(|len| offset.checked_add(len));
        match end {
            Some(end) if end <= LEN => Ok(OFFSET + offset),
            _ => Err(Error::Size),
        }
    }
}

impl<R, const OFFSET: u32, const LEN: u32> ErrorType for Partition<R, OFFSET, LEN> {
    type Error = Error;
}

/// The NorFlash traits over a region type, calling its own async methods
/// (through its trait impls each call would be one more state machine:
/// 300 B more on the settings store alone).
macro_rules! partition_of {
    ($region:ident) => {
        impl<const OFFSET: u32, const LEN: u32> ReadNorFlash for Partition<$region<'static, Async>, OFFSET, LEN> {
            const READ_SIZE: usize = <$region<'static, Async> as ReadNorFlash>::READ_SIZE;

            async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Error> {
                let at = Self::locate(offset, bytes.len())?;
                // A read is a copy: it ends before anything else runs, so
                // the lock is held across no await (cheaper futures).
                let _bank = BANK2.lock().await;
                self.region.blocking_read(at, bytes)
            }

            fn capacity(&self) -> usize {
                LEN as usize
            }
        }

        impl<const OFFSET: u32, const LEN: u32> NorFlash for Partition<$region<'static, Async>, OFFSET, LEN> {
            const WRITE_SIZE: usize = <$region<'static, Async> as NorFlash>::WRITE_SIZE;
            const ERASE_SIZE: usize = <$region<'static, Async> as NorFlash>::ERASE_SIZE;

            async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Error> {
                let at = Self::locate(offset, bytes.len())?;
                let _bank = BANK2.lock().await;
                self.region.write(at, bytes).await
            }

            /// At x32, under [`BANK2`] from the parallelism's setting to
            /// the erase's end.
            async fn erase(&mut self, from: u32, to: u32) -> Result<(), Error> {
                const SECTOR: u32 = <$region<'static, Async> as NorFlash>::ERASE_SIZE as u32;
                let len = to.checked_sub(from).ok_or(Error::Size)?;
                let at = Self::locate(from, len as usize)?;
                // Checked before the flash is unlocked (the partition's
                // start is a sector's, checked at compile time).
                if !at.is_multiple_of(SECTOR) || !len.is_multiple_of(SECTOR) {
                    return Err(Error::Unaligned);
                }
                let _bank = BANK2.lock().await;
                crate::silicon::erase_at_x32();
                self.region.erase(at, at + len).await
            }
        }
    };
}

partition_of!(Bank2Region1);
#[cfg(feature = "update")]
partition_of!(Bank2Region2);
#[cfg(feature = "update")]
partition_of!(Bank2Region3);
