//! Settings that live on the device (docs/settings.md): the saved
//! [`Settings`] and the admin password's hash, power-fail safe, over any
//! `embedded-storage-async` [`NorFlash`] a board gives.
//!
//! - [`Store`]: the two records in a flash range, as a log of records
//!   (sequential-storage's map): a change is written as a new record and
//!   never erased in place, so a save cut at any instant leaves the old
//!   record or the new one.
//! - [`record`]: the settings record, text lines `group.field=value`,
//!   taken whole or not at all.
//! - [`password`]: [`PasswordHash`], PBKDF2-HMAC-SHA256 with a salt.
//! - [`flash`]: [`RuleFlash`](flash::RuleFlash), a NOR flash with real flash
//!   rules over a byte slice (QEMU's PSRAM, hal-sim's state file, tests).
//!
//! How a board uses it:
//!
//! ```ignore
//! let mut store = Store::new(flash, SETTINGS_RANGE)?;
//! let loaded = store.load(&FACTORY).await;
//! if let Some(error) = loaded.error { warn!("settings storage: {}", error) }
//! // ... later, from the HTTP API:
//! store.save_settings(&changed).await?;
//! ```

pub mod flash;
pub mod password;
pub mod record;

use core::fmt;
use core::ops::Range;

use embedded_storage_async::nor_flash::{ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash};
use sequential_storage::Error as MapError;
use sequential_storage::cache::{Cache, Uncached};
use sequential_storage::map::{MapConfig, MapStorage, SerializationError, Value};

pub use self::password::{PasswordError, PasswordHash, check_password};
pub use self::record::{MAX_RECORD_LEN, RecordError};
use crate::settings::Settings;

/// The records' keys in the map. A key this firmware does not know (a
/// newer firmware's record) is kept as it is.
pub mod key {
    pub const SETTINGS: u8 = 1;
    pub const PASSWORD: u8 = 2;
    /// The device's TLS private key (docs/tls.md).
    pub const TLS_KEY: u8 = 3;
    /// The device's TLS certificate, self-signed or installed.
    pub const TLS_CERTIFICATE: u8 = 4;
    /// The CA that Modbus/TCP Security clients' certificates chain to.
    pub const TLS_CLIENT_CA: u8 = 5;
}

/// The longest record under a key other than the settings' (a certificate
/// with its version and origin bytes).
pub const MAX_OTHER_RECORD_LEN: usize = 1280;

/// The largest flash word sequential-storage supports, which the buffer
/// is padded and aligned to.
const MAX_WORD_SIZE: usize = 32;

/// The working buffer: a key byte and the longest record, rounded up to a
/// flash word.
const BUFFER_LEN: usize =
    (1 + if MAX_RECORD_LEN > MAX_OTHER_RECORD_LEN { MAX_RECORD_LEN } else { MAX_OTHER_RECORD_LEN })
        .next_multiple_of(MAX_WORD_SIZE);

/// The smallest flash page the store takes: the map moves the live records
/// of the oldest page forward before erasing it, so a page must hold both
/// records and the record being saved, with their headers.
pub const MIN_PAGE_LEN: usize = 4096;

/// What the storage holds, for `/api/status` (`storage {ok, records, erases}`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StorageStatus {
    /// Every record read back whole at the last load, and every save
    /// since succeeded (a successful save of a record, or a factory reset,
    /// mends what was wrong with it).
    pub ok: bool,
    /// Records in the flash range, superseded ones included: each save adds
    /// one; reclaiming a page drops the superseded records it held.
    pub records: u32,
    /// Flash pages this store erased since it was made.
    pub erases: u32,
}

/// The admin password as the store found it.
#[derive(Clone, Copy, Debug)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Password {
    /// None set (factory).
    Unset,
    /// Set: check attempts with [`PasswordHash::verify`].
    Set(PasswordHash),
    /// A password record is there but cannot be read (a newer firmware's
    /// format). No password verifies: changes stay locked until a factory
    /// reset or a new password is saved, never open to everyone.
    Unreadable,
}

impl Password {
    /// Whether changes need a password (set, or there but unreadable).
    pub const fn is_set(&self) -> bool {
        !matches!(self, Self::Unset)
    }

    /// Whether `password` is the one set (never when unset or unreadable).
    pub fn verify(&self, password: &[u8]) -> bool {
        match self {
            Self::Set(hash) => hash.verify(password),
            Self::Unset | Self::Unreadable => false,
        }
    }
}

/// What [`Store::load`] found.
#[derive(Clone, Copy, Debug)]
pub struct Loaded {
    /// The saved settings, or the factory settings when none are saved or
    /// the saved ones could not be taken whole.
    pub settings: Settings,
    /// The admin password.
    pub password: Password,
    /// Lines of the settings record skipped because this firmware does
    /// not know their key (a newer firmware's settings).
    pub skipped: u32,
    /// Why the storage is not ok, for the log (and [`StorageStatus::ok`]
    /// is false); `None` when it is.
    pub error: Option<LoadError>,
    /// The storage's state after the load.
    pub status: StorageStatus,
}

/// Why a load fell back to the factory settings, or could not read the
/// password: the caller logs it and counts it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LoadError {
    /// The settings record was there and was rejected whole.
    Settings(RecordError),
    /// The password record was there and could not be read.
    Password,
    /// The flash range holds no record of this store and is not erased
    /// (never formatted, or overwritten).
    Unformatted,
    /// The flash or the records' log failed.
    Storage(StoreError),
}

impl fmt::Display for LoadError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Settings(e) => write!(f, "the saved settings were rejected ({e}); factory settings"),
            Self::Password => f.write_str("the saved password cannot be read; changes are locked"),
            Self::Unformatted => f.write_str("the settings flash holds something else; factory settings"),
            Self::Storage(e) => write!(f, "the settings flash cannot be read ({e}); factory settings"),
        }
    }
}

impl core::error::Error for LoadError {}

/// Why a save or a reset failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreError {
    /// The flash range is not whole pages of at least [`MIN_PAGE_LEN`]
    /// bytes, or fewer than 2 of them, or outside the flash.
    Range,
    /// The settings cannot be saved: they do not validate, or do not read
    /// back whole from their record. Nothing was written.
    Record(RecordError),
    /// The settings' record would not read back as these settings (a
    /// value that does not show as its parser takes it: a bug of the
    /// settings table). Nothing was written.
    ReadBack,
    /// The flash failed.
    Flash(NorFlashErrorKind),
    /// The records do not fit the range (not with the two records of
    /// this firmware in a range [`Store::new`] took).
    Full,
    /// The log is corrupt beyond sequential-storage's repair.
    Corrupted,
    /// sequential-storage reported an internal error.
    Internal,
}

impl fmt::Display for StoreError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Range => f.write_str("the flash range is not at least 2 whole pages of at least 4 KiB"),
            Self::Record(e) => write!(f, "{e}"),
            Self::ReadBack => f.write_str("the settings would not read back from their record"),
            Self::Flash(kind) => write!(f, "flash error ({kind:?})"),
            Self::Full => f.write_str("the flash range is full"),
            Self::Corrupted => f.write_str("the records are corrupt"),
            Self::Internal => f.write_str("internal error of the records' log"),
        }
    }
}

impl core::error::Error for StoreError {}

impl<E: NorFlashError> From<MapError<E>> for StoreError {
    fn from(error: MapError<E>) -> Self {
        match error {
            MapError::Storage { value, .. } => Self::Flash(value.kind()),
            MapError::FullStorage => Self::Full,
            MapError::Corrupted { .. } => Self::Corrupted,
            MapError::SerializationError(_) | MapError::BufferTooSmall(_) | MapError::ItemTooBig => {
                Self::Record(RecordError::TooLong)
            }
            _ => Self::Internal,
        }
    }
}

/// The word-aligned working buffer.
#[repr(C, align(32))]
struct Buffer([u8; BUFFER_LEN]);

type NoCache = Cache<Uncached, Uncached, Uncached, u8>;

/// The settings and the admin password's hash in a flash range.
///
/// No cache: the map's caches either allocate or need the page count as a
/// constant (and panic when it is wrong), and the store reads its range
/// once at start and on the rare save, so caching saves nothing that matters.
///
/// Each operation is one future; dropping it midway is a power cut (the
/// next operation repairs the log, and the record is the old or the new).
pub struct Store<F: NorFlash> {
    map: MapStorage<u8, Counting<F>, NoCache>,
    buffer: Buffer,
    status: StorageStatus,
    /// What the last load found wrong, until a save or a reset mends it.
    settings_bad: bool,
    password_bad: bool,
    flash_bad: bool,
    /// The range holds no record and is not erased: the next save erases it first.
    unformatted: bool,
}

impl<F: NorFlash> fmt::Debug for Store<F> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Store").field("range", &self.map.flash_range()).field("status", &self.status).finish()
    }
}

impl<F: NorFlash> Store<F> {
    /// The store over `range` of `flash`: at least 2 whole pages of at least
    /// [`MIN_PAGE_LEN`] bytes, inside the flash, used by nothing else.
    /// Reads nothing yet: [`Self::load`] does.
    pub fn new(flash: F, range: Range<u32>) -> Result<Self, StoreError> {
        let inside = usize::try_from(range.end).is_ok_and(|end| end <= flash.capacity());
        if F::ERASE_SIZE < MIN_PAGE_LEN || F::WRITE_SIZE > MAX_WORD_SIZE || !inside {
            return Err(StoreError::Range);
        }
        let config = MapConfig::try_new(range).map_err(|_| StoreError::Range)?;
        let flash = Counting { flash, erases: 0 };
        Ok(Self {
            map: MapStorage::new(flash, config, Cache::new_uncached()),
            buffer: Buffer([0; BUFFER_LEN]),
            status: StorageStatus { ok: true, records: 0, erases: 0 },
            settings_bad: false,
            password_bad: false,
            flash_bad: false,
            unformatted: false,
        })
    }

    /// What the storage holds, as of the last operation.
    pub fn status(&self) -> StorageStatus {
        self.status
    }

    /// The flash under the store (a test looks at it; nothing else should
    /// write the store's range).
    pub fn flash(&mut self) -> &mut F {
        &mut self.map.flash().flash
    }

    /// The flash back, the store done with.
    pub fn into_flash(self) -> F {
        self.map.destroy().0.flash
    }

    /// Reads the saved settings over `factory` and the password's hash.
    ///
    /// Never fails: what cannot be read is reported in [`Loaded::error`]
    /// and [`StorageStatus::ok`], and the factory settings stand in for
    /// settings that cannot be taken whole. A fresh (erased) range is ok
    /// and gives the factory settings.
    pub async fn load(&mut self, factory: &Settings) -> Loaded {
        self.settings_bad = false;
        self.password_bad = false;
        self.flash_bad = false;
        self.unformatted = false;
        let mut error = None;
        let mut settings = *factory;
        let mut skipped = 0;
        let mut password = Password::Unset;
        let mut found = false;
        // An erased range: the factory settings, nothing to read. (Checked
        // first: a fetch may repair, and so erase, pages of garbage.)
        match self.is_erased().await {
            Ok(true) => {
                self.status.records = 0;
                self.update_status();
                return Loaded { settings, password, skipped, error, status: self.status };
            }
            Ok(false) => {}
            Err(e) => {
                self.flash_bad = true;
                error = Some(LoadError::Storage(e));
            }
        }
        // The fetches next: a fetch repairs what a cut operation left.
        match self.map.fetch_item::<&[u8]>(&mut self.buffer.0, &key::SETTINGS).await {
            Ok(None) => {}
            Ok(Some(record)) => {
                found = true;
                match record::decode(record, factory) {
                    Ok(decoded) => {
                        settings = decoded.settings;
                        skipped = decoded.skipped;
                    }
                    Err(e) => {
                        self.settings_bad = true;
                        error = Some(LoadError::Settings(e));
                    }
                }
            }
            Err(e) => {
                self.flash_bad = true;
                error = Some(LoadError::Storage(e.into()));
            }
        }
        match self.map.fetch_item::<&[u8]>(&mut self.buffer.0, &key::PASSWORD).await {
            Ok(None) => {}
            Ok(Some(record)) => {
                found = true;
                if let Some(hash) = PasswordHash::from_record(record) {
                    password = Password::Set(hash);
                } else {
                    self.password_bad = true;
                    password = Password::Unreadable;
                    error = error.or(Some(LoadError::Password));
                }
            }
            Err(e) => {
                self.flash_bad = true;
                error = error.or(Some(LoadError::Storage(e.into())));
            }
        }
        let counted = self.count_records().await;
        if let Err(e) = counted {
            self.flash_bad = true;
            error = error.or(Some(LoadError::Storage(e)));
        }
        if !found && matches!(counted, Ok(0) | Err(_)) {
            // No record could be read, and the range was not erased.
            self.unformatted = true;
            error = error.or(Some(LoadError::Unformatted));
        }
        self.update_status();
        Loaded { settings, password, skipped, error, status: self.status }
    }

    /// Saves `settings` as a new record. They must validate and read back
    /// whole from their record (checked before anything is written); on
    /// any error the saved settings are still the old ones.
    pub async fn save_settings(&mut self, settings: &Settings) -> Result<(), StoreError> {
        if let Err(errors) = settings.validate() {
            let field = errors.iter().next().map_or(crate::settings::Field::NetworkMode, |(field, _)| *field);
            return Err(StoreError::Record(RecordError::Inconsistent(field)));
        }
        // What will be written must load back as exactly these settings.
        let len = record::encode(settings, &mut self.buffer.0).map_err(StoreError::Record)?;
        let record = self.buffer.0.get(..len).unwrap_or_default();
        match record::decode(record, &Settings::DEFAULT) {
            Ok(decoded) if decoded.settings == *settings => {}
            Ok(_) => return Err(StoreError::ReadBack),
            Err(e) => return Err(StoreError::Record(e)),
        }
        let result = self.store(key::SETTINGS, &SettingsValue(settings)).await;
        if result.is_ok() {
            self.settings_bad = false;
        }
        self.finish(result).await
    }

    /// Saves the admin password's hash as a new record.
    pub async fn save_password(&mut self, hash: &PasswordHash) -> Result<(), StoreError> {
        let record = hash.to_record();
        let result = self.store(key::PASSWORD, &record.as_slice()).await;
        if result.is_ok() {
            self.password_bad = false;
        }
        self.finish(result).await
    }

    /// The record under `key` (not the settings' or the password's), read
    /// into `out`; `None` when there is none.
    pub async fn fetch_record<'o>(&mut self, key: u8, out: &'o mut [u8]) -> Result<Option<&'o [u8]>, StoreError> {
        let found = self.map.fetch_item::<&[u8]>(&mut self.buffer.0, &key).await;
        let record = match found {
            Ok(record) => record,
            Err(e) => {
                self.flash_bad = true;
                self.update_status();
                return Err(e.into());
            }
        };
        let Some(record) = record else { return Ok(None) };
        let to = out.get_mut(..record.len()).ok_or(StoreError::Record(RecordError::TooLong))?;
        to.copy_from_slice(record);
        Ok(Some(to))
    }

    /// Calls `f` with the record under `key` (`None`: there is none), read
    /// into the store's own buffer: nothing is copied.
    pub async fn with_record<R>(&mut self, key: u8, f: impl FnOnce(Option<&[u8]>) -> R) -> Result<R, StoreError> {
        match self.map.fetch_item::<&[u8]>(&mut self.buffer.0, &key).await {
            Ok(record) => Ok(f(record)),
            Err(e) => {
                self.flash_bad = true;
                self.update_status();
                Err(e.into())
            }
        }
    }

    /// Saves `bytes` as a new record under `key` (not the settings' or the
    /// password's: they have their own, checked, saves).
    pub async fn save_record(&mut self, key: u8, bytes: &[u8]) -> Result<(), StoreError> {
        if key == key::SETTINGS || key == key::PASSWORD || bytes.len() > MAX_OTHER_RECORD_LEN {
            return Err(StoreError::Record(RecordError::TooLong));
        }
        let result = self.store(key, &bytes).await;
        self.finish(result).await
    }

    /// Erases the whole range: factory settings and no password from the
    /// next load on.
    pub async fn factory_reset(&mut self) -> Result<(), StoreError> {
        let result = self.map.erase_all().await.map_err(StoreError::from);
        if result.is_ok() {
            self.settings_bad = false;
            self.password_bad = false;
            self.unformatted = false;
        }
        self.finish(result).await
    }

    /// Stores one record, erasing an unformatted range first (it holds no
    /// record of ours, so nothing is lost).
    async fn store<'v, V: Value<'v>>(&mut self, key: u8, value: &V) -> Result<(), StoreError> {
        if self.unformatted {
            self.map.erase_all().await?;
            self.unformatted = false;
        }
        self.map.store_item(&mut self.buffer.0, &key, value).await?;
        Ok(())
    }

    /// Counts the records again and notes a failure.
    async fn finish(&mut self, result: Result<(), StoreError>) -> Result<(), StoreError> {
        self.flash_bad = result.is_err();
        if result.is_ok() {
            match self.count_records().await {
                Ok(_) => {}
                Err(_) => self.flash_bad = true,
            }
        }
        self.update_status();
        result
    }

    /// Counts every record in the range (superseded ones included).
    async fn count_records(&mut self) -> Result<u32, StoreError> {
        let mut items = self.map.fetch_all_items(&mut self.buffer.0).await?;
        let mut records = 0u32;
        while items.next::<&[u8]>(&mut self.buffer.0).await?.is_some() {
            records = records.saturating_add(1);
        }
        self.status.records = records;
        Ok(records)
    }

    /// Whether every byte of the range is erased.
    async fn is_erased(&mut self) -> Result<bool, StoreError> {
        let range = self.map.flash_range();
        let mut offset = range.start;
        while offset < range.end {
            let len = (range.end - offset).min(BUFFER_LEN as u32);
            let chunk = self.buffer.0.get_mut(..len as usize).unwrap_or_default();
            self.map.flash().read(offset, chunk).await.map_err(|e| StoreError::Flash(e.kind()))?;
            if chunk.iter().any(|&b| b != 0xff) {
                return Ok(false);
            }
            offset += len;
        }
        Ok(true)
    }

    fn update_status(&mut self) {
        self.status.ok = !(self.settings_bad || self.password_bad || self.flash_bad || self.unformatted);
        self.status.erases = self.map.flash().erases;
    }
}

/// The settings as the map stores them: their record, written straight
/// into the map's buffer. (Read back as bytes, then [`record::decode`].)
struct SettingsValue<'s>(&'s Settings);

impl<'a> Value<'a> for SettingsValue<'_> {
    fn serialize_into(&self, buffer: &mut [u8]) -> Result<usize, SerializationError> {
        record::encode(self.0, buffer).map_err(|_| SerializationError::BufferTooSmall)
    }

    fn deserialize_from(_: &'a [u8]) -> Result<(Self, usize), SerializationError> {
        // Never read as this type.
        Err(SerializationError::InvalidFormat)
    }
}

/// The board's flash, counting the pages erased.
struct Counting<F> {
    flash: F,
    erases: u32,
}

impl<F: NorFlash> ErrorType for Counting<F> {
    type Error = F::Error;
}

impl<F: NorFlash> ReadNorFlash for Counting<F> {
    const READ_SIZE: usize = F::READ_SIZE;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), F::Error> {
        self.flash.read(offset, bytes).await
    }

    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl<F: NorFlash> NorFlash for Counting<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), F::Error> {
        self.flash.erase(from, to).await?;
        let pages = to.saturating_sub(from) / (F::ERASE_SIZE as u32).max(1);
        self.erases = self.erases.saturating_add(pages);
        Ok(())
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), F::Error> {
        self.flash.write(offset, bytes).await
    }
}

#[cfg(test)]
mod tests;
