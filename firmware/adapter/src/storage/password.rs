//! The admin password (docs/http-api.md, `PUT /api/password`): 8-64 bytes
//! and no control character, kept only as a salted hash, never stored or
//! shown itself.
//!
//! The hash is PBKDF2-HMAC-SHA256 (RFC 8018) over the password and a 16-byte
//! salt the caller draws from the board's random source, [`ITERATIONS`]
//! rounds, 32 bytes out. Checking a password derives the hash again and
//! compares in constant time.
//!
//! HMAC pads a key shorter than its block with zero bytes, so over the bare
//! password `pw` and `pw\0` hash alike. Since record version 2 the key is
//! the password's length (one byte) and then the password: no two
//! passwords share a key, so none share a hash but by a SHA-256 collision.
//! Version 1 records (the bare password) still verify, and a password with
//! a control character is refused whatever the record.
//!
//! Its record (the store's second record) is fixed-size:
//!
//! ```text
//! | version = 1 or 2 (1) | salt (16) | PBKDF2-HMAC-SHA256 (32) |
//! ```
//!
//! The version names the algorithm, its key and its iterations, so a later
//! firmware that hashes otherwise still checks the passwords set before it.

use core::fmt;

use pbkdf2::pbkdf2_hmac;
use sha2::Sha256;
use subtle::ConstantTimeEq;

/// Shortest password, in bytes.
pub const MIN_PASSWORD_LEN: usize = 8;
/// Longest password, in bytes.
pub const MAX_PASSWORD_LEN: usize = 64;
/// Bytes of salt.
pub const SALT_LEN: usize = 16;
/// Bytes of hash.
pub const HASH_LEN: usize = 32;

/// PBKDF2 rounds, sized so one check takes well under 100 ms on the
/// NUCLEO's 180 MHz Cortex-M4. Measured: this crate's PBKDF2-HMAC-SHA256,
/// built as the firmware is (`opt-level = "s"`, fat LTO, thumbv7em), run in
/// QEMU's mps2-an386 with `-icount shift=0` (one instruction per ns, read
/// on SysTick): 5 580 instructions a round (two SHA-256 compressions of
/// about 2 790), 5.7 million for 1 024 rounds. At 1 to 1.5 cycles an
/// instruction (the M4 at 5 flash wait states behind the ART cache) that
/// is 32-48 ms a check; 2 048 rounds would be 64-95 ms.
pub const ITERATIONS: u32 = 1024;

/// The record format of this firmware: PBKDF2-HMAC-SHA256, [`ITERATIONS`],
/// keyed by the password's length and the password.
const VERSION: u8 = 2;
/// The first firmware's format: keyed by the bare password (still checked).
const VERSION_BARE_KEY: u8 = 1;

/// A password that breaks the rule.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PasswordError {
    /// Fewer than [`MIN_PASSWORD_LEN`] bytes.
    TooShort,
    /// More than [`MAX_PASSWORD_LEN`] bytes.
    TooLong,
    /// A control character (0x00-0x1F, 0x7F): invisible, and NUL is how a
    /// short key is padded.
    ControlCharacter,
}

impl fmt::Display for PasswordError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::TooShort => "shorter than 8 bytes",
            Self::TooLong => "longer than 64 bytes",
            Self::ControlCharacter => "holds a control character",
        })
    }
}

impl core::error::Error for PasswordError {}

/// The rule a new password must follow: 8-64 bytes, none of them a
/// control character (UTF-8's other bytes are all taken).
pub const fn check_password(password: &[u8]) -> Result<(), PasswordError> {
    if password.len() < MIN_PASSWORD_LEN {
        Err(PasswordError::TooShort)
    } else if password.len() > MAX_PASSWORD_LEN {
        Err(PasswordError::TooLong)
    } else if has_control(password) {
        Err(PasswordError::ControlCharacter)
    } else {
        Ok(())
    }
}

/// Whether `bytes` hold a control character (C0 or DEL).
const fn has_control(bytes: &[u8]) -> bool {
    let mut rest = bytes;
    while let [byte, tail @ ..] = rest {
        if *byte < 0x20 || *byte == 0x7f {
            return true;
        }
        rest = tail;
    }
    false
}

/// A password's salted hash: what the store keeps instead of the password.
///
/// No `PartialEq`: a password is checked with [`PasswordHash::verify`], in
/// constant time. `Debug` shows neither salt nor hash.
#[derive(Clone, Copy)]
pub struct PasswordHash {
    /// The record's version: how the hash was derived.
    version: u8,
    salt: [u8; SALT_LEN],
    hash: [u8; HASH_LEN],
}

impl PasswordHash {
    /// Bytes of its record.
    pub const RECORD_LEN: usize = 1 + SALT_LEN + HASH_LEN;

    /// Hashes `password` (which must follow [`check_password`]) with
    /// `salt`, drawn fresh from the board's random source for each new
    /// password.
    pub fn new(password: &[u8], salt: [u8; SALT_LEN]) -> Result<Self, PasswordError> {
        check_password(password)?;
        Ok(Self { version: VERSION, salt, hash: derive(VERSION, password, &salt) })
    }

    /// Whether `password` is the one hashed, compared in constant time (the
    /// time depends on the password's length only, never on how much of
    /// the hash matches). Never with a control character in it.
    pub fn verify(&self, password: &[u8]) -> bool {
        let hash = derive(self.version, password, &self.salt);
        bool::from(hash.ct_eq(&self.hash)) && !has_control(password)
    }

    /// Its record.
    pub fn to_record(&self) -> [u8; Self::RECORD_LEN] {
        let mut record = [0u8; Self::RECORD_LEN];
        let (version, rest) = record.split_at_mut(1);
        let (salt, hash) = rest.split_at_mut(SALT_LEN);
        version.copy_from_slice(&[self.version]);
        salt.copy_from_slice(&self.salt);
        hash.copy_from_slice(&self.hash);
        record
    }

    /// Reads a record: `None` unless it is exactly [`Self::RECORD_LEN`]
    /// bytes of a version this firmware checks (1 or 2).
    pub fn from_record(record: &[u8]) -> Option<Self> {
        let (&version, rest) = record.split_first()?;
        if version != VERSION && version != VERSION_BARE_KEY {
            return None;
        }
        let (salt, hash) = rest.split_at_checked(SALT_LEN)?;
        Some(Self { version, salt: salt.try_into().ok()?, hash: hash.try_into().ok()? })
    }
}

impl fmt::Debug for PasswordHash {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("PasswordHash(..)")
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for PasswordHash {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "PasswordHash(..)")
    }
}

/// PBKDF2-HMAC-SHA256 of `password` and `salt` as record `version` keys
/// it: version 2 by the length byte and the password (a password longer
/// than the rule is cut; it never verifies), version 1 by the bare
/// password. (HMAC takes a key of any length, so the crate's only failure
/// cannot happen.)
fn derive(version: u8, password: &[u8], salt: &[u8; SALT_LEN]) -> [u8; HASH_LEN] {
    let mut hash = [0u8; HASH_LEN];
    if version == VERSION_BARE_KEY {
        pbkdf2_hmac::<Sha256>(password, salt, ITERATIONS, &mut hash);
        return hash;
    }
    let mut key = [0u8; 1 + MAX_PASSWORD_LEN];
    let len = password.len().min(MAX_PASSWORD_LEN);
    let (prefix, rest) = key.split_at_mut(1);
    prefix.copy_from_slice(&[len as u8]);
    if let (Some(to), Some(from)) = (rest.get_mut(..len), password.get(..len)) {
        to.copy_from_slice(from);
    }
    pbkdf2_hmac::<Sha256>(key.get(..1 + len).unwrap_or_default(), salt, ITERATIONS, &mut hash);
    hash
}

#[cfg(test)]
mod tests {
    use super::*;

    const SALT: [u8; SALT_LEN] = *b"0123456789abcdef";

    #[test]
    fn the_rule_is_8_to_64_bytes() {
        assert_eq!(check_password(b""), Err(PasswordError::TooShort));
        assert_eq!(check_password(b"1234567"), Err(PasswordError::TooShort));
        assert_eq!(check_password(b"12345678"), Ok(()));
        assert_eq!(check_password(&[b'x'; 64]), Ok(()));
        assert_eq!(check_password(&[b'x'; 65]), Err(PasswordError::TooLong));
        assert_eq!(PasswordHash::new(b"short", SALT).unwrap_err(), PasswordError::TooShort);
        assert_eq!(PasswordHash::new(&[0; 65], SALT).unwrap_err(), PasswordError::TooLong);
        for control in [&b"password\0"[..], b"\0password", b"pass\tword", b"password\x7f", b"pass\nword"] {
            assert_eq!(check_password(control), Err(PasswordError::ControlCharacter), "{control:?}");
        }
        assert_eq!(check_password("é".repeat(32).as_bytes()), Ok(()), "UTF-8 is not a control");
        const { assert!(check_password(b"in a const").is_ok()) };
    }

    #[test]
    fn the_hash_is_pbkdf2_hmac_sha256() {
        // RFC 7914 section 11's PBKDF2-HMAC-SHA-256 vector ("passwd", "salt",
        // 1 round) pins the algorithm; ours runs ITERATIONS rounds.
        let mut out = [0u8; 64];
        pbkdf2_hmac::<Sha256>(b"passwd", b"salt", 1, &mut out);
        assert_eq!(out[..8], [0x55, 0xac, 0x04, 0x6e, 0x56, 0xe3, 0x08, 0x9f]);
        let hash = PasswordHash::new(b"correct horse", SALT).unwrap();
        let mut expected = [0u8; HASH_LEN];
        pbkdf2_hmac::<Sha256>(b"\x0dcorrect horse", &SALT, ITERATIONS, &mut expected);
        assert_eq!(hash.hash, expected, "keyed by the length byte, then the password");
    }

    /// HMAC pads a short key with zeros: over the bare password `pw` and
    /// `pw\0` hash alike. The length byte tells them apart.
    #[test]
    fn no_two_passwords_share_a_key() {
        let hash = |password: &[u8]| derive(VERSION, password, &SALT);
        assert_ne!(hash(b"password"), hash(b"password\0"));
        assert_ne!(hash(b"password"), hash(b"password\0\0\0"));
        let bare = |password: &[u8]| derive(VERSION_BARE_KEY, password, &SALT);
        assert_eq!(bare(b"password"), bare(b"password\0"), "why version 1 was replaced");
        let set = PasswordHash::new(b"password", SALT).unwrap();
        assert!(set.verify(b"password"));
        for trailing in [&b"password\0"[..], b"password\0\0", b"pass\0word"] {
            assert!(!set.verify(trailing), "{trailing:?}");
        }
    }

    /// A version 1 record (the first firmware's, bare key) still verifies
    /// its password, and never one with a control character.
    #[test]
    fn a_version_1_record_still_verifies() {
        let mut record = [0u8; PasswordHash::RECORD_LEN];
        record[0] = VERSION_BARE_KEY;
        record[1..17].copy_from_slice(&SALT);
        pbkdf2_hmac::<Sha256>(b"correct horse", &SALT, ITERATIONS, &mut record[17..]);
        let old = PasswordHash::from_record(&record).unwrap();
        assert!(old.verify(b"correct horse"));
        assert!(!old.verify(b"correct horse\0"), "the padding no longer lets a NUL in");
        assert!(!old.verify(b"correct hors"));
        assert_eq!(old.to_record(), record, "kept as it was");
    }

    #[test]
    fn verify_takes_the_password_and_nothing_else() {
        let hash = PasswordHash::new(b"correct horse", SALT).unwrap();
        assert!(hash.verify(b"correct horse"));
        for wrong in [&b"correct hors"[..], b"correct horse ", b"Correct horse", b"", &[0; 200]] {
            assert!(!hash.verify(wrong), "{wrong:?}");
        }
        let other_salt = PasswordHash::new(b"correct horse", [7; SALT_LEN]).unwrap();
        assert_ne!(other_salt.hash, hash.hash, "the salt changes the hash");
        assert!(other_salt.verify(b"correct horse"));
    }

    #[test]
    fn the_record_round_trips_and_holds_no_password() {
        let hash = PasswordHash::new(b"correct horse", SALT).unwrap();
        let record = hash.to_record();
        assert_eq!(record.len(), PasswordHash::RECORD_LEN);
        assert_eq!(record[0], VERSION);
        assert_eq!(&record[1..17], &SALT);
        assert!(!record.windows(13).any(|w| w == b"correct horse"));
        let back = PasswordHash::from_record(&record).unwrap();
        assert!(back.verify(b"correct horse") && !back.verify(b"correct horsf"));
        assert_eq!(format!("{back:?}"), "PasswordHash(..)");
        for len in 0..record.len() {
            assert!(PasswordHash::from_record(&record[..len]).is_none(), "cut to {len}");
        }
        assert!(PasswordHash::from_record(&[record.as_slice(), &[0]].concat()).is_none());
        let mut other = record;
        other[0] = 3;
        assert!(PasswordHash::from_record(&other).is_none(), "another version");
    }
}
