//! A NOR flash with real flash rules over a byte slice: what QEMU's
//! mps2-an386 (file-backed PSRAM), hal-sim (a state file) and the host
//! tests store settings in, so code that would break a real flash breaks
//! here too.
//!
//! The rules, each enforced with an error that changes nothing (never
//! silently):
//!
//! - **Erase** sets whole pages of `ERASE_SIZE` bytes to `0xFF`; both ends
//!   of the range must lie on page boundaries ([`FlashError::NotAligned`]).
//! - **Write** only clears bits: a write whose data has a 1 where the flash
//!   holds a 0 fails ([`FlashError::SetsBit`]) and writes nothing. Offset and
//!   length must be multiples of `WRITE_SIZE` ([`FlashError::NotAligned`]).
//! - **Read** takes any offset and length (`READ_SIZE` is 1).
//! - Every range must lie inside the flash ([`FlashError::OutOfBounds`]): the
//!   whole pages of the slice (a tail shorter than a page is never used).
//!
//! Because a write only has to clear bits, writing a word again with data
//! that only clears more of its bits is legal, and checked the same way:
//! this flash is a [`MultiwriteNorFlash`](nor::MultiwriteNorFlash). (The
//! STM32F4's flash allows that too; flash with ECC, such as the STM32H7's,
//! does not, and the settings store never needs it.)

use core::fmt;

use embedded_storage::nor_flash as nor;
use embedded_storage_async::nor_flash as nor_async;

/// A broken flash rule.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FlashError {
    /// The range does not lie inside the flash.
    OutOfBounds,
    /// A write's offset or length is not a multiple of the write size, or
    /// an erase's ends are not on page boundaries.
    NotAligned,
    /// The write would turn a 0 bit at `offset` back into 1, which only an
    /// erase can do.
    SetsBit {
        /// The first byte that would change so.
        offset: u32,
    },
    /// The flash is worn out ([`Wearing`]): it takes no write or erase.
    Worn,
}

impl fmt::Display for FlashError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::OutOfBounds => f.write_str("outside the flash"),
            Self::NotAligned => f.write_str("not aligned to the write size or the page size"),
            Self::SetsBit { offset } => write!(f, "a write would set a cleared bit at offset {offset}"),
            Self::Worn => f.write_str("the flash is worn out"),
        }
    }
}

impl core::error::Error for FlashError {}

impl nor::NorFlashError for FlashError {
    fn kind(&self) -> nor::NorFlashErrorKind {
        match self {
            Self::OutOfBounds => nor::NorFlashErrorKind::OutOfBounds,
            Self::NotAligned => nor::NorFlashErrorKind::NotAligned,
            Self::SetsBit { .. } | Self::Worn => nor::NorFlashErrorKind::Other,
        }
    }
}

/// A NOR flash with pages of `ERASE_SIZE` bytes written in words of
/// `WRITE_SIZE` bytes, over `&'a mut [u8]` (see the module's rules).
#[derive(Debug)]
pub struct RuleFlash<'a, const WRITE_SIZE: usize, const ERASE_SIZE: usize> {
    memory: &'a mut [u8],
    erases: u32,
    writes: u32,
}

impl<'a, const WRITE_SIZE: usize, const ERASE_SIZE: usize> RuleFlash<'a, WRITE_SIZE, ERASE_SIZE> {
    /// The flash over `memory`, as it is (a fresh one is all `0xFF`: erase
    /// it, or fill it so). Its capacity is the whole pages of `memory`.
    pub const fn new(memory: &'a mut [u8]) -> Self {
        const {
            assert!(WRITE_SIZE > 0 && ERASE_SIZE > 0 && ERASE_SIZE.is_multiple_of(WRITE_SIZE));
            assert!(ERASE_SIZE <= u32::MAX as usize);
        }
        Self { memory, erases: 0, writes: 0 }
    }

    /// Pages erased since [`Self::new`] (saturating).
    pub const fn erases(&self) -> u32 {
        self.erases
    }

    /// Write operations since [`Self::new`] that succeeded (saturating).
    pub const fn writes(&self) -> u32 {
        self.writes
    }

    /// The bytes under the flash, as they are.
    pub fn memory(&self) -> &[u8] {
        self.memory
    }

    /// The bytes under the flash, to change behind its back: a test's
    /// interrupted erase.
    #[cfg(test)]
    pub(crate) fn memory_mut(&mut self) -> &mut [u8] {
        self.memory
    }

    /// Bytes the flash holds: the whole pages of its memory.
    pub const fn capacity(&self) -> usize {
        self.memory.len() - self.memory.len() % ERASE_SIZE
    }

    /// `offset..offset + len` as indices, when it lies inside the flash.
    fn range(&self, offset: u32, len: usize) -> Result<core::ops::Range<usize>, FlashError> {
        let start = usize::try_from(offset).map_err(|_| FlashError::OutOfBounds)?;
        match start.checked_add(len) {
            Some(end) if end <= self.capacity() => Ok(start..end),
            _ => Err(FlashError::OutOfBounds),
        }
    }

    fn read_bytes(&self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        let range = self.range(offset, bytes.len())?;
        let source = self.memory.get(range).ok_or(FlashError::OutOfBounds)?;
        bytes.copy_from_slice(source);
        Ok(())
    }

    fn erase_pages(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        let len = to.checked_sub(from).ok_or(FlashError::OutOfBounds)?;
        let range = self.range(from, len as usize)?;
        if !range.start.is_multiple_of(ERASE_SIZE) || !range.end.is_multiple_of(ERASE_SIZE) {
            return Err(FlashError::NotAligned);
        }
        let pages = range.len() / ERASE_SIZE;
        self.memory.get_mut(range).ok_or(FlashError::OutOfBounds)?.fill(0xff);
        self.erases = self.erases.saturating_add(u32::try_from(pages).unwrap_or(u32::MAX));
        Ok(())
    }

    fn write_bytes(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        let range = self.range(offset, bytes.len())?;
        if !range.start.is_multiple_of(WRITE_SIZE) || !bytes.len().is_multiple_of(WRITE_SIZE) {
            return Err(FlashError::NotAligned);
        }
        let target = self.memory.get_mut(range).ok_or(FlashError::OutOfBounds)?;
        // Check every byte before changing any: a refused write changes nothing.
        if let Some(at) = target.iter().zip(bytes).position(|(old, new)| new & !old != 0) {
            let at = u32::try_from(at).unwrap_or(u32::MAX);
            return Err(FlashError::SetsBit { offset: offset.saturating_add(at) });
        }
        target.copy_from_slice(bytes);
        self.writes = self.writes.saturating_add(1);
        Ok(())
    }
}

impl<const WRITE_SIZE: usize, const ERASE_SIZE: usize> nor::ErrorType for RuleFlash<'_, WRITE_SIZE, ERASE_SIZE> {
    type Error = FlashError;
}

impl<const WRITE_SIZE: usize, const ERASE_SIZE: usize> nor::ReadNorFlash for RuleFlash<'_, WRITE_SIZE, ERASE_SIZE> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        self.read_bytes(offset, bytes)
    }

    fn capacity(&self) -> usize {
        RuleFlash::capacity(self)
    }
}

impl<const WRITE_SIZE: usize, const ERASE_SIZE: usize> nor::NorFlash for RuleFlash<'_, WRITE_SIZE, ERASE_SIZE> {
    const WRITE_SIZE: usize = WRITE_SIZE;
    const ERASE_SIZE: usize = ERASE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        self.erase_pages(from, to)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        self.write_bytes(offset, bytes)
    }
}

impl<const WRITE_SIZE: usize, const ERASE_SIZE: usize> nor::MultiwriteNorFlash
    for RuleFlash<'_, WRITE_SIZE, ERASE_SIZE>
{
}

impl<const WRITE_SIZE: usize, const ERASE_SIZE: usize> nor_async::ReadNorFlash
    for RuleFlash<'_, WRITE_SIZE, ERASE_SIZE>
{
    const READ_SIZE: usize = 1;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        self.read_bytes(offset, bytes)
    }

    fn capacity(&self) -> usize {
        RuleFlash::capacity(self)
    }
}

impl<const WRITE_SIZE: usize, const ERASE_SIZE: usize> nor_async::NorFlash for RuleFlash<'_, WRITE_SIZE, ERASE_SIZE> {
    const WRITE_SIZE: usize = WRITE_SIZE;
    const ERASE_SIZE: usize = ERASE_SIZE;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        self.erase_pages(from, to)
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        self.write_bytes(offset, bytes)
    }
}

impl<const WRITE_SIZE: usize, const ERASE_SIZE: usize> nor_async::MultiwriteNorFlash
    for RuleFlash<'_, WRITE_SIZE, ERASE_SIZE>
{
}

/// A [`RuleFlash`] that wears out on demand: while its flag is set, every
/// write and erase fails ([`FlashError::Worn`]) and changes nothing, as a
/// worn-out flash's would. What the tests and the fuzz targets make a
/// failed save with.
#[derive(Debug)]
pub struct Wearing<'a, const WRITE_SIZE: usize, const ERASE_SIZE: usize> {
    flash: RuleFlash<'a, WRITE_SIZE, ERASE_SIZE>,
    worn: &'a core::cell::Cell<bool>,
}

impl<'a, const WRITE_SIZE: usize, const ERASE_SIZE: usize> Wearing<'a, WRITE_SIZE, ERASE_SIZE> {
    /// `flash`, worn out while `worn` is set.
    pub const fn new(flash: RuleFlash<'a, WRITE_SIZE, ERASE_SIZE>, worn: &'a core::cell::Cell<bool>) -> Self {
        Self { flash, worn }
    }

    fn usable(&self) -> Result<(), FlashError> {
        if self.worn.get() { Err(FlashError::Worn) } else { Ok(()) }
    }
}

impl<const WRITE_SIZE: usize, const ERASE_SIZE: usize> nor::ErrorType for Wearing<'_, WRITE_SIZE, ERASE_SIZE> {
    type Error = FlashError;
}

impl<const WRITE_SIZE: usize, const ERASE_SIZE: usize> nor_async::ReadNorFlash for Wearing<'_, WRITE_SIZE, ERASE_SIZE> {
    const READ_SIZE: usize = 1;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        self.flash.read_bytes(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl<const WRITE_SIZE: usize, const ERASE_SIZE: usize> nor_async::NorFlash for Wearing<'_, WRITE_SIZE, ERASE_SIZE> {
    const WRITE_SIZE: usize = WRITE_SIZE;
    const ERASE_SIZE: usize = ERASE_SIZE;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        self.usable()?;
        self.flash.erase_pages(from, to)
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        self.usable()?;
        self.flash.write_bytes(offset, bytes)
    }
}

#[cfg(test)]
mod tests;
