//! Firmware update (docs/update.md): an update file
//! ([`update_image`]'s format) taken in chunks as it arrives, its payload
//! written into the DFU partition, its signature checked against the
//! public key built into this firmware ([`PUBLIC_KEY`]), and only then the
//! swap armed for embassy-boot's bootloader; the new image's confirmation
//! after the swap; the boot state.
//!
//! The HTTP side drives one upload at a time:
//!
//! ```ignore
//! updater.begin().await?;                  // refused while an update is armed or on trial
//! while let Some(chunk) = body.next().await {
//!     let progress = updater.write(chunk).await?;   // header checked first, then DFU written
//! }
//! let accepted = updater.finish().await?;  // length, signature; then the swap is armed
//! platform.reboot();                       // the bootloader swaps, the new image runs on trial
//! // ... in the new image, once the network is up and Modbus serves:
//! updater.confirm().await?;                // else the next reset rolls back
//! ```
//!
//! What is refused, and when (each leaves the running image and nothing
//! armed; [`Error`] says why, [`Error::kind`] whose fault it is):
//!
//! | check | when | error |
//! |---|---|---|
//! | magic, format, header fields | the header's 128th byte, before anything is written | [`Error::Format`] |
//! | board id is this board's | the same | [`Error::WrongBoard`] |
//! | payload fits the ACTIVE partition | the same | [`Error::TooLarge`] |
//! | no more bytes than the header says | as they come | [`Error::TooLong`] |
//! | all the bytes the header says | [`Updater::finish`] | [`Error::CutOff`] |
//! | the signature, over the header and the payload as read back from DFU | [`Updater::finish`], before arming | [`Error::Signature`] |
//!
//! The boot state is embassy-boot's (its [`FirmwareState`]: the magic word
//! and the swap progress the bootloader reads). The payload goes into DFU
//! through this module's own erase-as-you-go writer rather than
//! `FirmwareUpdater::write_firmware`, whose record of the last sector it
//! erased outlives an upload: an upload after one that failed within the
//! first sector (any upload cut in its first 128 KiB on the NUCLEO) would
//! not erase that sector again and write over the failed one's bytes. And the signature is checked here rather than
//! by `verify_and_mark_updated`, which signs the payload alone (the board
//! and version would not be signed) and asserts (panics) on a length.

use core::fmt;

use embassy_boot::{FirmwareState, FirmwareUpdaterError, State};
use embedded_storage_async::nor_flash::{NorFlash, NorFlashError, NorFlashErrorKind};

pub mod boot;

pub use crate::device::{BootState, FirmwareStatus};
use crate::io::Version;
pub use update_image::{self as image, Board, FormatError, HEADER_LEN, Header, SignatureError};

// PUBLIC_KEY and DEVELOPMENT_KEY, from the key file build.rs read.
include!(concat!(env!("OUT_DIR"), "/update_key.rs"));

/// Payload bytes gathered before one write into DFU, and read back at a
/// time to check the signature. A multiple of every flash word in use.
pub const BLOCK_LEN: usize = 512;

/// The longest state-partition word (embassy-boot's aligned buffer): the
/// buffer [`Updater::new`] takes must hold the state flash's word.
pub const MAX_STATE_WORD: usize = 32;

/// Why an upload, or a state change, was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// Not an update file, or one whose header this firmware cannot read.
    Format(FormatError),
    /// The image is for another board.
    WrongBoard(Board),
    /// The payload is larger than the ACTIVE partition.
    TooLarge {
        /// The payload's length, from the header.
        len: u32,
        /// The largest payload this board takes.
        max: u32,
    },
    /// More bytes came than the header announced.
    TooLong,
    /// The upload ended before the header's length: `received` of `expected`
    /// bytes of the file (header included).
    CutOff { received: u32, expected: u32 },
    /// The signature does not verify against the built-in public key.
    Signature(SignatureError),
    /// `write` or `finish` without `begin`.
    NotStarted,
    /// An update is armed and installs at the next reset: no other upload
    /// until then.
    Armed,
    /// The running image is on trial (swapped in, not yet confirmed): no
    /// upload until it confirms itself.
    OnTrial,
    /// The flash failed.
    Flash(NorFlashErrorKind),
    /// The board's partitions do not fit the updater: the state buffer is
    /// too short, the board id is not one, or the ACTIVE size is larger
    /// than DFU.
    Config,
}

/// Whose fault an [`Error`] is, for the HTTP side's status code.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ErrorKind {
    /// The upload is not a good image for this device (a client error).
    Image,
    /// Not now: the device's state refuses an upload (a conflict).
    State,
    /// The device failed (a server error).
    Device,
}

impl Error {
    /// Whose fault the error is.
    pub const fn kind(&self) -> ErrorKind {
        match self {
            // No check to run: the device's fault, not the image's.
            Self::Signature(SignatureError::Unavailable) => ErrorKind::Device,
            Self::Format(_)
            | Self::WrongBoard(_)
            | Self::TooLarge { .. }
            | Self::TooLong
            | Self::CutOff { .. }
            | Self::Signature(_) => ErrorKind::Image,
            Self::NotStarted | Self::Armed | Self::OnTrial => ErrorKind::State,
            Self::Flash(_) | Self::Config => ErrorKind::Device,
        }
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Format(e) => write!(f, "not a valid update file: {e}"),
            Self::WrongBoard(board) => write!(f, "the image is for the board {board}"),
            Self::TooLarge { len, max } => write!(f, "the image is too large: {len} bytes, at most {max}"),
            Self::TooLong => f.write_str("more bytes than the image's header says"),
            Self::CutOff { received, expected } => write!(f, "the upload was cut off: {received} of {expected} bytes"),
            Self::Signature(SignatureError::Unavailable) => {
                f.write_str("the signature cannot be checked: the bootloader offers no signature check")
            }
            Self::Signature(e) => write!(f, "the image's signature is not valid: {e}"),
            Self::NotStarted => f.write_str("no upload in progress"),
            Self::Armed => f.write_str("an update is armed and installs at the next reboot"),
            Self::OnTrial => f.write_str("the running firmware is on trial and not yet confirmed"),
            Self::Flash(kind) => write!(f, "flash error: {kind:?}"),
            Self::Config => f.write_str("the update partitions are not configured right"),
        }
    }
}

impl core::error::Error for Error {}

impl From<FirmwareUpdaterError> for Error {
    fn from(error: FirmwareUpdaterError) -> Self {
        match error {
            FirmwareUpdaterError::Flash(kind) => Self::Flash(kind),
            FirmwareUpdaterError::BadState => Self::OnTrial,
            FirmwareUpdaterError::Signature(_) => Self::Signature(SignatureError::Mismatch),
        }
    }
}

fn flash_error(error: impl NorFlashError) -> Error {
    Error::Flash(error.kind())
}

/// How far an upload is, in bytes of the update file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Progress {
    /// Bytes taken so far (header included).
    pub received: u32,
    /// The file's length, once its header is in.
    pub total: Option<u32>,
}

/// An update that passed every check and is armed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Accepted {
    pub version: Version,
    /// The payload's length in bytes.
    pub len: u32,
}

/// What the updater checks images against.
#[derive(Clone, Copy, Debug)]
pub struct Config<'a> {
    /// This board's id (its crate's name): images for another are refused.
    pub board: &'a str,
    /// The ACTIVE partition's size: the largest payload.
    pub max_len: u32,
    /// The key images must be signed with.
    pub public_key: [u8; image::PUBLIC_KEY_LEN],
    /// What checks the signature: on the boards, the bootloader's check
    /// ([`image::service`]), which the image does not carry itself.
    pub check: image::Check,
}

impl<'a> Config<'a> {
    /// Images for `board` of at most `max_len` bytes, signed for
    /// [`PUBLIC_KEY`] as `check` finds.
    pub const fn new(board: &'a str, max_len: u32, check: image::Check) -> Self {
        Self { board, max_len, public_key: PUBLIC_KEY, check }
    }
}

/// An upload's receiving state (the payload's block is [`Updater`]'s).
#[derive(Clone, Copy, Debug)]
struct Receiving {
    header: Header,
    /// The header's bytes the digest covers, as they came (kept rather
    /// than written out again from `header`: 368 B of code less on the
    /// NUCLEO, for 64 B of RAM).
    signed: [u8; image::SIGNED_LEN],
    /// Payload bytes taken, the buffered ones included.
    received: u32,
    /// Payload bytes in the block, not yet written.
    buffered: usize,
    /// DFU bytes erased by this upload, from 0.
    erased_to: u32,
}

#[derive(Clone, Copy, Debug)]
enum Upload {
    Idle,
    /// The header's first `len` bytes are in the block.
    Header {
        len: usize,
    },
    Payload(Receiving),
    Failed(Error),
    Armed(Accepted),
}

/// The device's side of a firmware update over the DFU partition `DFU`
/// and the bootloader's state partition `STATE` (see the module's documentation).
pub struct Updater<'d, DFU: NorFlash, STATE: NorFlash> {
    dfu: DFU,
    state: FirmwareState<'d, STATE>,
    board: Board,
    max_len: u32,
    public_key: [u8; image::PUBLIC_KEY_LEN],
    check: image::Check,
    upload: Upload,
    /// The header as it arrives, then the payload's next block; read-back space.
    block: [u8; BLOCK_LEN],
}

impl<DFU: NorFlash, STATE: NorFlash> fmt::Debug for Updater<'_, DFU, STATE> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Updater")
            .field("board", &self.board)
            .field("max_len", &self.max_len)
            .field("upload", &self.upload)
            .finish_non_exhaustive()
    }
}

impl<'d, DFU: NorFlash, STATE: NorFlash> Updater<'d, DFU, STATE> {
    /// The largest update file this updater takes: the header and the
    /// longest payload ACTIVE holds.
    pub fn capacity(&self) -> usize {
        HEADER_LEN.saturating_add(usize::try_from(self.max_len).unwrap_or(usize::MAX))
    }

    /// The updater over `dfu` and `state`, with `aligned` (at least the
    /// state flash's word, [`MAX_STATE_WORD`] will do) as embassy-boot's
    /// state buffer. [`Error::Config`] when the partitions do not fit.
    pub fn new(dfu: DFU, state: STATE, aligned: &'d mut [u8], config: Config<'_>) -> Result<Self, Error> {
        const {
            assert!(BLOCK_LEN.is_multiple_of(DFU::WRITE_SIZE) && BLOCK_LEN.is_multiple_of(DFU::READ_SIZE));
            assert!(BLOCK_LEN >= HEADER_LEN);
        }
        let word = STATE::WRITE_SIZE.max(STATE::READ_SIZE);
        let aligned = aligned.get_mut(..word).ok_or(Error::Config)?;
        let board = Board::new(config.board).ok_or(Error::Config)?;
        if usize::try_from(config.max_len).map_or(true, |max| max > dfu.capacity()) {
            return Err(Error::Config);
        }
        Ok(Self {
            dfu,
            state: FirmwareState::new(state, aligned),
            board,
            max_len: config.max_len,
            public_key: config.public_key,
            check: config.check,
            upload: Upload::Idle,
            block: [0xff; BLOCK_LEN],
        })
    }

    /// What the state partition says (see [`BootState`]).
    pub async fn boot_state(&mut self) -> Result<BootState, Error> {
        Ok(match self.state.get_state().await? {
            State::Boot => BootState::Confirmed,
            State::Swap if matches!(self.upload, Upload::Armed(_)) => BootState::Armed,
            State::Swap => BootState::Trial,
            State::Revert => BootState::RolledBack,
            State::DfuDetach => BootState::DfuDetach,
        })
    }

    /// Confirms the running image when it is on trial (embassy-boot's
    /// `mark_booted`): the bootloader keeps it from now on. `Ok(true)` when
    /// it was on trial and is confirmed now; `Ok(false)` when there was
    /// nothing to confirm (it writes nothing then, and a swap this run
    /// armed stays armed).
    pub async fn confirm(&mut self) -> Result<bool, Error> {
        if self.boot_state().await? != BootState::Trial {
            return Ok(false);
        }
        self.state.mark_booted().await?;
        Ok(true)
    }

    /// Starts an upload (a running one is dropped). Writes nothing.
    /// Refused while an update is armed ([`Error::Armed`]) or the running
    /// image is on trial ([`Error::OnTrial`]).
    pub async fn begin(&mut self) -> Result<(), Error> {
        match self.boot_state().await? {
            BootState::Armed => return Err(Error::Armed),
            BootState::Trial => return Err(Error::OnTrial),
            BootState::Confirmed | BootState::RolledBack | BootState::DfuDetach => {}
        }
        self.upload = Upload::Header { len: 0 };
        Ok(())
    }

    /// Drops the upload in progress; nothing is armed.
    pub fn abort(&mut self) {
        if !matches!(self.upload, Upload::Armed(_)) {
            self.upload = Upload::Idle;
        }
    }

    /// The update this run armed, if any: it installs at the next reset.
    pub fn armed(&self) -> Option<Accepted> {
        match self.upload {
            Upload::Armed(accepted) => Some(accepted),
            _ => None,
        }
    }

    /// How far the upload is (`None`: none in progress).
    pub fn progress(&self) -> Option<Progress> {
        match self.upload {
            Upload::Idle | Upload::Failed(_) | Upload::Armed(_) => None,
            Upload::Header { len } => Some(Progress { received: len_u32(len), total: None }),
            Upload::Payload(r) => Some(Progress {
                received: r.received.saturating_add(len_u32(HEADER_LEN)),
                total: Some(r.header.payload_len.saturating_add(len_u32(HEADER_LEN))),
            }),
        }
    }

    /// Takes the upload's next bytes. The header is checked as soon as it
    /// is in, before anything is written; then the payload goes into DFU
    /// a block at a time. An error ends the upload: every later call
    /// returns it, until [`Self::begin`].
    pub async fn write(&mut self, chunk: &[u8]) -> Result<Progress, Error> {
        let taken = self.take(chunk).await;
        if let Err(error) = taken {
            self.upload = Upload::Failed(error);
        }
        taken
    }

    /// Ends the upload: every byte the header announced must have come;
    /// the payload is read back from DFU and the signature checked over the
    /// header and it; only then is the swap armed (embassy-boot's
    /// `mark_updated`). On any error nothing is armed.
    pub async fn finish(&mut self) -> Result<Accepted, Error> {
        let finished = self.check_and_arm().await;
        self.upload = match finished {
            Ok(accepted) => Upload::Armed(accepted),
            Err(error) => Upload::Failed(error),
        };
        finished
    }

    /// Takes a whole upload from `source` (begin, each chunk, finish): the
    /// version of the image it armed. On any error the upload is dropped
    /// and nothing is armed.
    pub async fn receive<S: boot::Source>(
        &mut self,
        source: &mut S,
    ) -> Result<crate::io::Version, boot::Refused<S::Error>> {
        self.begin().await.map_err(boot::Refused::Update)?;
        loop {
            match source.chunk().await {
                Ok(Some(chunk)) => {
                    if let Err(error) = self.write(chunk).await {
                        self.abort();
                        return Err(boot::Refused::Update(error));
                    }
                }
                Ok(None) => break,
                Err(error) => {
                    self.abort();
                    return Err(boot::Refused::Source(error));
                }
            }
        }
        let accepted = self.finish().await.map_err(boot::Refused::Update)?;
        Ok(accepted.version)
    }

    async fn take(&mut self, mut chunk: &[u8]) -> Result<Progress, Error> {
        loop {
            match self.upload {
                Upload::Idle => return Err(Error::NotStarted),
                Upload::Failed(error) => return Err(error),
                Upload::Armed(_) => return Err(Error::Armed),
                _ if chunk.is_empty() => break,
                Upload::Header { len } => {
                    let (head, rest) = chunk.split_at(chunk.len().min(HEADER_LEN.saturating_sub(len)));
                    let end = len + head.len();
                    self.block.get_mut(len..end).ok_or(Error::Config)?.copy_from_slice(head);
                    chunk = rest;
                    self.upload = if end < HEADER_LEN {
                        Upload::Header { len: end }
                    } else {
                        let header = self.check_header()?;
                        let signed = *self.block.first_chunk().ok_or(Error::Config)?;
                        Upload::Payload(Receiving { header, signed, received: 0, buffered: 0, erased_to: 0 })
                    };
                }
                Upload::Payload(mut r) => {
                    let left = r.header.payload_len.saturating_sub(r.received);
                    if u32::try_from(chunk.len()).map_or(true, |len| len > left) {
                        return Err(Error::TooLong);
                    }
                    let (part, rest) = chunk.split_at(chunk.len().min(BLOCK_LEN.saturating_sub(r.buffered)));
                    let end = r.buffered + part.len();
                    self.block.get_mut(r.buffered..end).ok_or(Error::Config)?.copy_from_slice(part);
                    r.buffered = end;
                    r.received = r.received.saturating_add(len_u32(part.len()));
                    chunk = rest;
                    if r.buffered == BLOCK_LEN {
                        self.flush(&mut r).await?;
                    }
                    self.upload = Upload::Payload(r);
                }
            }
        }
        self.progress().ok_or(Error::NotStarted)
    }

    /// The header in the block, checked against this board.
    fn check_header(&self) -> Result<Header, Error> {
        let header = Header::parse(&self.block).map_err(Error::Format)?;
        if header.board != self.board {
            return Err(Error::WrongBoard(header.board));
        }
        if header.payload_len > self.max_len {
            return Err(Error::TooLarge { len: header.payload_len, max: self.max_len });
        }
        Ok(header)
    }

    /// Writes the buffered payload bytes (padded with 0xFF to a flash word)
    /// at their place in DFU, erasing the sectors they reach first.
    async fn flush(&mut self, r: &mut Receiving) -> Result<(), Error> {
        let offset = r.received.saturating_sub(len_u32(r.buffered));
        let len = r.buffered.next_multiple_of(DFU::WRITE_SIZE);
        let data = self.block.get_mut(..len).ok_or(Error::Config)?;
        data.get_mut(r.buffered..).unwrap_or_default().fill(0xff);
        let end = offset.checked_add(len_u32(len)).ok_or(Error::TooLong)?;
        let sector = len_u32(DFU::ERASE_SIZE);
        while r.erased_to < end {
            let next = r.erased_to.checked_add(sector).ok_or(Error::TooLong)?;
            self.dfu.erase(r.erased_to, next).await.map_err(flash_error)?;
            r.erased_to = next;
        }
        self.dfu.write(offset, data).await.map_err(flash_error)?;
        r.buffered = 0;
        Ok(())
    }

    async fn check_and_arm(&mut self) -> Result<Accepted, Error> {
        let mut r = match self.upload {
            Upload::Idle => return Err(Error::NotStarted),
            Upload::Failed(error) => return Err(error),
            Upload::Armed(_) => return Err(Error::Armed),
            Upload::Header { len } => {
                return Err(Error::CutOff { received: len_u32(len), expected: len_u32(HEADER_LEN) });
            }
            Upload::Payload(r) => r,
        };
        let header = r.header;
        if r.received < header.payload_len {
            let head = len_u32(HEADER_LEN);
            return Err(Error::CutOff {
                received: r.received.saturating_add(head),
                expected: header.payload_len.saturating_add(head),
            });
        }
        if r.buffered > 0 {
            self.flush(&mut r).await?;
        }
        let digest = self.digest_dfu(&r.signed, header.payload_len).await?;
        (self.check)(&self.public_key, &digest, &header.signature).map_err(Error::Signature)?;
        self.state.mark_updated().await?;
        Ok(Accepted { version: header.version, len: header.payload_len })
    }

    /// The image's digest over the header's `signed` bytes and the
    /// `payload_len` bytes of payload as DFU holds them.
    async fn digest_dfu(
        &mut self,
        signed: &[u8; image::SIGNED_LEN],
        payload_len: u32,
    ) -> Result<[u8; image::DIGEST_LEN], Error> {
        let mut digest = image::Digest::new(signed);
        let mut offset = 0u32;
        while offset < payload_len {
            let len = usize::try_from(payload_len - offset).map_or(BLOCK_LEN, |left| left.min(BLOCK_LEN));
            let read = self.block.get_mut(..len.next_multiple_of(DFU::READ_SIZE)).ok_or(Error::Config)?;
            self.dfu.read(offset, read).await.map_err(flash_error)?;
            digest.update(read.get(..len).unwrap_or_default());
            offset = offset.saturating_add(len_u32(len));
            // Hashing a large image takes a while: let the other tasks run.
            embassy_futures::yield_now().await;
        }
        Ok(digest.finalize())
    }
}

/// The record every image with `update` carries at the same place (each
/// board puts it right after its vector table, with a linker section of its
/// own): how an image's version is read from its bytes in DFU, where a swap
/// leaves the image it replaced. 8 bytes of magic, the version's three
/// numbers little-endian, 2 bytes of zeros.
pub const IMAGE_INFO_LEN: usize = 16;

/// The record's first bytes ("mbio image", format 1).
const IMAGE_INFO_MAGIC: [u8; 8] = *b"MBIOIMG\x01";

/// The record of an image of `version` (for its `.image_info` section).
pub const fn image_info(version: crate::io::Version) -> [u8; IMAGE_INFO_LEN] {
    let [a, b, c, d, e, f, g, h] = IMAGE_INFO_MAGIC;
    let [m0, m1] = version.major.to_le_bytes();
    let [n0, n1] = version.minor.to_le_bytes();
    let [p0, p1] = version.patch.to_le_bytes();
    [a, b, c, d, e, f, g, h, m0, m1, n0, n1, p0, p1, 0, 0]
}

/// The version an image's record says; `None` for bytes that are not a
/// record (an image from before records, or no image).
pub fn parse_image_info(record: &[u8]) -> Option<crate::io::Version> {
    let [magic @ .., m0, m1, n0, n1, p0, p1, 0, 0] = *<&[u8; IMAGE_INFO_LEN]>::try_from(record).ok()? else {
        return None;
    };
    (magic == IMAGE_INFO_MAGIC).then(|| crate::io::Version {
        major: u16::from_le_bytes([m0, m1]),
        minor: u16::from_le_bytes([n0, n1]),
        patch: u16::from_le_bytes([p0, p1]),
    })
}

/// Where the images' records are and how the bootloader swaps: what
/// [`Updater::other_image`] needs to find the other image's record in DFU.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageLayout {
    /// The record's offset from an image's start.
    pub info_offset: u32,
    /// The bootloader's page, its unit of swapping (the larger erase size
    /// of ACTIVE and DFU): a swap leaves the old image one page into DFU.
    pub page: u32,
}

impl<DFU: NorFlash, STATE: NorFlash> Updater<'_, DFU, STATE> {
    /// The version of the other image DFU holds, by its record: after a
    /// swap (the running image on trial or confirmed since) the image it
    /// replaced, which embassy-boot's swap leaves one page into DFU; after
    /// a rollback the image that was rolled back, at DFU's start. `None`
    /// when DFU holds no record there: nothing swapped yet, an image
    /// without one, a swap armed, or a later upload written over it.
    pub async fn other_image(&mut self, layout: ImageLayout) -> Result<Option<crate::io::Version>, Error> {
        let at = match self.boot_state().await? {
            BootState::Confirmed | BootState::Trial => layout.page.checked_add(layout.info_offset),
            BootState::RolledBack => Some(layout.info_offset),
            BootState::Armed | BootState::DfuDetach => None,
        };
        let Some(at) = at.filter(|at| {
            at.checked_add(len_u32(IMAGE_INFO_LEN)).is_some_and(|end| end as usize <= self.dfu.capacity())
        }) else {
            return Ok(None);
        };
        let mut record = [0u8; IMAGE_INFO_LEN];
        self.dfu.read(at, &mut record).await.map_err(flash_error)?;
        Ok(parse_image_info(&record))
    }
}

/// A length within a buffer, as `u32` (saturating: it never is larger).
fn len_u32(len: usize) -> u32 {
    u32::try_from(len).unwrap_or(u32::MAX)
}

#[cfg(test)]
mod tests;
