//! The adapter's firmware update file (docs/update.md):
//! a fixed header with an ed25519 signature, then the payload, the
//! application binary for the board's ACTIVE partition.
//!
//! ```text
//! | offset | len | field                                                        |
//! |-------:|----:|--------------------------------------------------------------|
//! |      0 |   8 | magic "MBIOFW\r\n" (a text-mode transfer mangles the \r\n)   |
//! |      8 |   2 | format version, u16 LE: 2                                    |
//! |     10 |   2 | header length, u16 LE: 128                                   |
//! |     12 |  32 | board id: the board crate's name, ASCII a-z 0-9 -, NUL-padded |
//! |     44 |   6 | firmware version major, minor, patch: u16 LE each            |
//! |     50 |   2 | reserved, 0                                                  |
//! |     52 |   4 | payload length in bytes, u32 LE, at least 1                  |
//! |     56 |   8 | reserved, 0                                                  |
//! |     64 |  64 | signature: ed25519 (RFC 8032) over the image's digest        |
//! |    128 |   n | payload                                                      |
//! ```
//!
//! **What is signed**: the digest is SHA-256 over the header's first 64
//! bytes (everything but the signature) followed by the payload, and the
//! signature is plain ed25519 with those 32 bytes as its message. So the
//! board, the version and the length are signed with the code: an image
//! for another board cannot be relabelled, nor a version changed. It is
//! embassy-boot's construction (`verify_and_mark_updated` signs a digest
//! of the DFU contents) with the header in front of the payload, and with
//! SHA-256, the hash the device already carries for its password (format
//! 1 used SHA-512, which an image then carried for this alone).
//!
//! The contract is smoltcp's: [`Header::parse`] reads by length and never
//! panics; [`Header::emit`] fills exactly [`HEADER_LEN`] bytes.
#![cfg_attr(not(test), no_std)]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing))]

use core::fmt;

#[cfg(feature = "verify")]
use ed25519_dalek::{Signature, VerifyingKey};
use sha2::{Digest as _, Sha256};

/// The file's first bytes.
pub const MAGIC: [u8; 8] = *b"MBIOFW\r\n";
/// The header format this crate reads and writes: 2, whose digest is
/// SHA-256 (format 1's was SHA-512; its files are refused as another format).
pub const FORMAT_VERSION: u16 = 2;
/// The header's length in format 2: the payload starts here.
pub const HEADER_LEN: usize = 128;
/// The header's bytes the digest covers: all but the signature.
pub const SIGNED_LEN: usize = 64;
/// An ed25519 signature's length.
pub const SIGNATURE_LEN: usize = 64;
/// An ed25519 public key's length.
pub const PUBLIC_KEY_LEN: usize = 32;
/// The digest's length (SHA-256).
pub const DIGEST_LEN: usize = 32;
/// The longest board id.
pub const MAX_BOARD_LEN: usize = 32;

/// Where each field lies in the header.
mod field {
    use core::ops::Range;
    pub const MAGIC: Range<usize> = 0..8;
    pub const FORMAT_VERSION: Range<usize> = 8..10;
    pub const HEADER_LEN: Range<usize> = 10..12;
    pub const BOARD: Range<usize> = 12..44;
    pub const MAJOR: Range<usize> = 44..46;
    pub const MINOR: Range<usize> = 46..48;
    pub const PATCH: Range<usize> = 48..50;
    pub const RESERVED_1: Range<usize> = 50..52;
    pub const PAYLOAD_LEN: Range<usize> = 52..56;
    pub const RESERVED_2: Range<usize> = 56..64;
    pub const SIGNATURE: Range<usize> = 64..128;
}

const _: () = {
    assert!(field::BOARD.end - field::BOARD.start == MAX_BOARD_LEN);
    assert!(field::SIGNATURE.start == SIGNED_LEN && field::SIGNATURE.end == HEADER_LEN);
    assert!(SIGNED_LEN + SIGNATURE_LEN == HEADER_LEN);
};

/// Why bytes are not an update header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FormatError {
    /// Fewer than [`HEADER_LEN`] bytes.
    Truncated,
    /// Not an update file: the magic is wrong.
    Magic,
    /// A header format this firmware does not read.
    FormatVersion(u16),
    /// The header length does not match the format's.
    HeaderLen(u16),
    /// The board id is empty, too long, not NUL-padded or holds a byte
    /// outside `a-z 0-9 -`.
    Board,
    /// A reserved field is not zero.
    Reserved,
    /// The payload length is 0.
    Empty,
}

impl fmt::Display for FormatError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Truncated => f.write_str("shorter than an update header"),
            Self::Magic => f.write_str("not a firmware update file"),
            Self::FormatVersion(v) => write!(f, "update file format {v} is not supported"),
            Self::HeaderLen(len) => write!(f, "header length {len} does not match the format"),
            Self::Board => f.write_str("the board id is not valid"),
            Self::Reserved => f.write_str("a reserved header field is not zero"),
            Self::Empty => f.write_str("the payload is empty"),
        }
    }
}

impl core::error::Error for FormatError {}

/// A firmware version, major.minor.patch: the hardware seam's
/// (`adapter_io::Version`), which the adapter reports too.
pub use adapter_io::Version;

/// A board id: 1 to [`MAX_BOARD_LEN`] bytes of `a-z 0-9 -` (the board
/// crate's name, `mps2-an386`, `nucleo-f429zi`).
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Board {
    bytes: [u8; MAX_BOARD_LEN],
    len: u8,
}

impl Board {
    /// The id `name`, if it follows the rule.
    pub fn new(name: &str) -> Option<Self> {
        let len = name.len();
        let valid = |b: &u8| b.is_ascii_lowercase() || b.is_ascii_digit() || *b == b'-';
        if len == 0 || len > MAX_BOARD_LEN || !name.bytes().all(|b| valid(&b)) {
            return None;
        }
        let mut bytes = [0; MAX_BOARD_LEN];
        bytes.get_mut(..len)?.copy_from_slice(name.as_bytes());
        Some(Self { bytes, len: u8::try_from(len).ok()? })
    }

    /// The field's 32 bytes: the id, then NUL up to the end.
    fn from_field(field: &[u8]) -> Option<Self> {
        let len = field.iter().position(|&b| b == 0).unwrap_or(field.len());
        let (name, padding) = field.split_at_checked(len)?;
        if padding.iter().any(|&b| b != 0) {
            return None;
        }
        Self::new(core::str::from_utf8(name).ok()?)
    }

    /// The id as text.
    pub fn as_str(&self) -> &str {
        let name = self.bytes.get(..usize::from(self.len)).unwrap_or_default();
        core::str::from_utf8(name).unwrap_or_default()
    }
}

impl fmt::Debug for Board {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Debug::fmt(self.as_str(), f)
    }
}

impl fmt::Display for Board {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for Board {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "{=str}", self.as_str())
    }
}

/// An update file's header, parsed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Header {
    /// The board the payload is built for.
    pub board: Board,
    /// The payload's firmware version.
    pub version: Version,
    /// The payload's length in bytes.
    pub payload_len: u32,
    /// The signature over the image's [digest](Digest).
    pub signature: [u8; SIGNATURE_LEN],
}

/// `bytes[range]` as an array, or `None` when it does not lie inside.
fn array<const N: usize>(bytes: &[u8], range: core::ops::Range<usize>) -> Option<[u8; N]> {
    bytes.get(range)?.try_into().ok()
}

fn u16_at(bytes: &[u8], range: core::ops::Range<usize>) -> Option<u16> {
    array(bytes, range).map(u16::from_le_bytes)
}

impl Header {
    /// Reads the header at the start of `bytes` (what follows is the
    /// payload and is not looked at). Checks in the order of the fields:
    /// length, magic, format, header length, board, reserved fields,
    /// payload length.
    pub fn parse(bytes: &[u8]) -> Result<Self, FormatError> {
        let bytes = bytes.get(..HEADER_LEN).ok_or(FormatError::Truncated)?;
        let t = FormatError::Truncated;
        if bytes.get(field::MAGIC) != Some(&MAGIC[..]) {
            return Err(FormatError::Magic);
        }
        let format = u16_at(bytes, field::FORMAT_VERSION).ok_or(t)?;
        if format != FORMAT_VERSION {
            return Err(FormatError::FormatVersion(format));
        }
        let header_len = u16_at(bytes, field::HEADER_LEN).ok_or(t)?;
        if usize::from(header_len) != HEADER_LEN {
            return Err(FormatError::HeaderLen(header_len));
        }
        let board = Board::from_field(bytes.get(field::BOARD).ok_or(t)?).ok_or(FormatError::Board)?;
        let version = Version {
            major: u16_at(bytes, field::MAJOR).ok_or(t)?,
            minor: u16_at(bytes, field::MINOR).ok_or(t)?,
            patch: u16_at(bytes, field::PATCH).ok_or(t)?,
        };
        let reserved = [field::RESERVED_1, field::RESERVED_2];
        if reserved.into_iter().any(|range| bytes.get(range).is_none_or(|r| r.iter().any(|&b| b != 0))) {
            return Err(FormatError::Reserved);
        }
        let payload_len = array(bytes, field::PAYLOAD_LEN).map(u32::from_le_bytes).ok_or(t)?;
        if payload_len == 0 {
            return Err(FormatError::Empty);
        }
        let signature = array(bytes, field::SIGNATURE).ok_or(t)?;
        Ok(Self { board, version, payload_len, signature })
    }

    /// The header's [`HEADER_LEN`] bytes.
    pub fn emit(&self) -> [u8; HEADER_LEN] {
        let mut out = [0u8; HEADER_LEN];
        let fields: [(core::ops::Range<usize>, &[u8]); 9] = [
            (field::MAGIC, &MAGIC),
            (field::FORMAT_VERSION, &FORMAT_VERSION.to_le_bytes()),
            (field::HEADER_LEN, &(HEADER_LEN as u16).to_le_bytes()),
            (field::BOARD, &self.board.bytes),
            (field::MAJOR, &self.version.major.to_le_bytes()),
            (field::MINOR, &self.version.minor.to_le_bytes()),
            (field::PATCH, &self.version.patch.to_le_bytes()),
            (field::PAYLOAD_LEN, &self.payload_len.to_le_bytes()),
            (field::SIGNATURE, &self.signature),
        ];
        for (range, value) in fields {
            if let Some(target) = out.get_mut(range) {
                target.copy_from_slice(value);
            }
        }
        out
    }

    /// The header's bytes the digest covers (all but the signature).
    pub fn signed_bytes(&self) -> [u8; SIGNED_LEN] {
        let header = self.emit();
        array(&header, 0..SIGNED_LEN).unwrap_or([0; SIGNED_LEN])
    }

    /// A [`Digest`] started over this header: feed it the payload.
    pub fn digest(&self) -> Digest {
        Digest::new(&self.signed_bytes())
    }

    /// Checks [`Self::signature`] over `digest` (of this header and the
    /// payload) against `public_key`.
    #[cfg(feature = "verify")]
    pub fn verify(&self, public_key: &[u8; PUBLIC_KEY_LEN], digest: &[u8; DIGEST_LEN]) -> Result<(), SignatureError> {
        verify(public_key, digest, &self.signature)
    }
}

/// The image's digest, fed as the bytes arrive: SHA-256 over the header's
/// first [`SIGNED_LEN`] bytes, then the payload.
#[derive(Clone, Debug)]
pub struct Digest(Sha256);

impl Digest {
    /// A digest over the header's signed bytes; the payload follows.
    pub fn new(signed: &[u8; SIGNED_LEN]) -> Self {
        let mut sha = Sha256::new();
        sha.update(signed);
        Self(sha)
    }

    /// Adds payload bytes.
    pub fn update(&mut self, payload: &[u8]) {
        self.0.update(payload);
    }

    /// The 32 bytes the signature signs.
    pub fn finalize(self) -> [u8; DIGEST_LEN] {
        self.0.finalize().into()
    }
}

/// The signature does not verify, or the public key is not a valid one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SignatureError {
    /// The public key is not a point of the curve.
    PublicKey,
    /// The signature is not this key's over this digest.
    Mismatch,
    /// Nothing here checks signatures: the image found no bootloader
    /// serving the check ([`service`]).
    Unavailable,
}

impl fmt::Display for SignatureError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::PublicKey => f.write_str("the public key is not valid"),
            Self::Mismatch => f.write_str("the signature does not match"),
            Self::Unavailable => f.write_str("the bootloader offers no signature check"),
        }
    }
}

impl core::error::Error for SignatureError {}

/// A signature check: [`verify`] where the crate carries it, or a
/// bootloader's ([`service::Service::verify`]) in an image that does not.
pub type Check = fn(
    public_key: &[u8; PUBLIC_KEY_LEN],
    digest: &[u8; DIGEST_LEN],
    signature: &[u8; SIGNATURE_LEN],
) -> Result<(), SignatureError>;

/// Checks `signature` over `digest` against `public_key` (ed25519, strict:
/// small-order keys and non-canonical signatures are refused).
#[cfg(feature = "verify")]
pub fn verify(
    public_key: &[u8; PUBLIC_KEY_LEN],
    digest: &[u8; DIGEST_LEN],
    signature: &[u8; SIGNATURE_LEN],
) -> Result<(), SignatureError> {
    let key = VerifyingKey::from_bytes(public_key).map_err(|_| SignatureError::PublicKey)?;
    let signature = Signature::from_bytes(signature);
    key.verify_strict(digest, &signature).map_err(|_| SignatureError::Mismatch)
}

pub mod service;

#[cfg(test)]
mod tests;
