//! The bootloader's signature check, served to the image it starts
//! (docs/update.md, "The bootloader's signature check").
//!
//! ed25519's verification is about 14 KiB of code, more than the NUCLEO's
//! image had room for within its 128 KiB budget of the time (docs/update.md),
//! and it need not be in every image. The bootloader, which has the
//! room, carries it once and puts a table of its entry points at a fixed
//! place, [`TABLE_OFFSET`] bytes from its start (right after its vector
//! table). The image computes the digest itself and calls the check there
//! with its own public key: the key stays the running firmware's, and a
//! new image can bring a new one.
//!
//! The table begins with [`MAGIC`], which also names its layout. An image
//! under a bootloader without the table (an older one, or none) finds no
//! [`Service`] and refuses every upload with
//! [`SignatureError::Unavailable`](crate::SignatureError::Unavailable); it
//! never calls an address it has not checked.
//!
//! The check runs on the image's stack and must touch none of the
//! bootloader's statics (its RAM is the image's by then): ed25519-dalek's
//! verification has none, and the bootloaders' static RAM is measured on
//! each build (docs/sizes.md).

use core::ops::Range;

use crate::{DIGEST_LEN, PUBLIC_KEY_LEN, SIGNATURE_LEN, SignatureError};

/// Where a bootloader puts its [`Services`]: this many bytes from its
/// start, right after its vector table (1 KiB holds the longest of the
/// boards' tables; the linker script places the
/// `.boot_services` section there and checks it).
pub const TABLE_OFFSET: usize = 0x400;

/// The table's first bytes; another layout of the table, or another
/// length of the digest it checks, gets another magic (`\x01` checked a
/// 64-byte digest, `\x02` the 32-byte digest of format 2).
pub const MAGIC: [u8; 8] = *b"MBIOSVC\x02";

/// The check's entry point, as the bootloader exports it: pointers to the
/// public key, the digest (the signed message) and the signature; it
/// returns [`VERIFIED`], [`BAD_KEY`] or [`MISMATCH`].
pub type VerifyFn = unsafe extern "C" fn(
    public_key: *const [u8; PUBLIC_KEY_LEN],
    digest: *const [u8; DIGEST_LEN],
    signature: *const [u8; SIGNATURE_LEN],
) -> u32;

/// The signature verifies. Not 0 or 1, so that a stray function returning
/// a flag is not taken for a yes.
pub const VERIFIED: u32 = 0x5afe_0001;
/// The public key is not a point of the curve.
pub const BAD_KEY: u32 = 0x5afe_0002;
/// The signature is not the key's over the digest.
pub const MISMATCH: u32 = 0x5afe_0003;

/// The table a bootloader exports (`#[repr(C)]`: its layout is the ABI).
#[repr(C)]
#[derive(Debug)]
pub struct Services {
    magic: [u8; 8],
    verify: VerifyFn,
}

#[cfg(feature = "verify")]
impl Services {
    /// The table of a bootloader that carries the check: place it in the
    /// `.boot_services` section, at [`TABLE_OFFSET`].
    pub const fn new() -> Self {
        Self { magic: MAGIC, verify: serve_verify }
    }
}

#[cfg(feature = "verify")]
impl Default for Services {
    fn default() -> Self {
        Self::new()
    }
}

/// The bootloader's side of [`VerifyFn`]: [`crate::verify`].
#[cfg(feature = "verify")]
unsafe extern "C" fn serve_verify(
    public_key: *const [u8; PUBLIC_KEY_LEN],
    digest: *const [u8; DIGEST_LEN],
    signature: *const [u8; SIGNATURE_LEN],
) -> u32 {
    // SAFETY: the ABI: each pointer is to a live array of its length
    // ([`Service::verify`] passes references).
    let (public_key, digest, signature) = unsafe { (&*public_key, &*digest, &*signature) };
    match crate::verify(public_key, digest, signature) {
        Ok(()) => VERIFIED,
        Err(SignatureError::PublicKey) => BAD_KEY,
        Err(_) => MISMATCH,
    }
}

/// A bootloader's check, found by [`Service::find`].
#[derive(Clone, Copy, Debug)]
pub struct Service {
    verify: VerifyFn,
}

impl Service {
    /// The check of the table at `table`, if one is there: its magic is
    /// [`MAGIC`] and its entry point lies in `code` (the bootloader's
    /// flash) and is Thumb code.
    ///
    /// # Safety
    ///
    /// `table..table + size_of::<Services>()` must be readable, and a table
    /// found there with the right magic must be a [`Services`] as this crate
    /// builds it ([`Services::new`]), in code nothing changes while the
    /// image runs (the bootloader's flash).
    pub unsafe fn find(table: usize, code: Range<usize>) -> Option<Self> {
        let at = table as *const Services;
        // SAFETY: the caller's promise: the bytes are readable. Read as bytes
        // and as an address: a function pointer is not made until checked.
        let (magic, entry) = unsafe {
            (
                core::ptr::addr_of!((*at).magic).read_volatile(),
                core::ptr::addr_of!((*at).verify).cast::<usize>().read_volatile(),
            )
        };
        let thumb = cfg!(target_arch = "arm");
        let aligned = if thumb { entry & 1 == 1 } else { entry != 0 };
        if magic != MAGIC || !code.contains(&entry) || !aligned {
            return None;
        }
        // SAFETY: the caller's promise: behind the magic is this crate's
        // table, whose entry is a VerifyFn (checked above to be in `code`).
        let verify = unsafe { core::mem::transmute::<usize, VerifyFn>(entry) };
        Some(Self { verify })
    }

    /// Checks `signature` over `digest` against `public_key` in the
    /// bootloader, as [`crate::verify`] does.
    pub fn verify(
        &self,
        public_key: &[u8; PUBLIC_KEY_LEN],
        digest: &[u8; DIGEST_LEN],
        signature: &[u8; SIGNATURE_LEN],
    ) -> Result<(), SignatureError> {
        // SAFETY: `find` checked the table; the pointers are references to
        // arrays of the lengths the ABI says, alive for the call.
        match unsafe { (self.verify)(public_key, digest, signature) } {
            VERIFIED => Ok(()),
            BAD_KEY => Err(SignatureError::PublicKey),
            _ => Err(SignatureError::Mismatch),
        }
    }
}

/// Checks `signature` over `digest` against `public_key` with the check
/// of the bootloader whose code is `code` (its table [`TABLE_OFFSET`]
/// bytes in); [`SignatureError::Unavailable`] when it serves none. What a
/// board's [`Check`](crate::Check) calls.
///
/// # Safety
///
/// As [`Service::find`]'s, for the table at `code.start + TABLE_OFFSET`.
pub unsafe fn check_in(
    code: Range<usize>,
    public_key: &[u8; PUBLIC_KEY_LEN],
    digest: &[u8; DIGEST_LEN],
    signature: &[u8; SIGNATURE_LEN],
) -> Result<(), SignatureError> {
    let table = code.start.saturating_add(TABLE_OFFSET);
    // SAFETY: the caller's promise.
    match unsafe { Service::find(table, code) } {
        Some(service) => service.verify(public_key, digest, signature),
        None => Err(SignatureError::Unavailable),
    }
}

#[cfg(test)]
mod tests {
    use ed25519_dalek::{Signer, SigningKey};

    use super::*;

    static TABLE: Services = Services::new();

    fn signed() -> ([u8; PUBLIC_KEY_LEN], [u8; DIGEST_LEN], [u8; SIGNATURE_LEN]) {
        let key = SigningKey::from_bytes(&[7; 32]);
        let digest = [0x5a; DIGEST_LEN];
        (key.verifying_key().to_bytes(), digest, key.sign(&digest).to_bytes())
    }

    fn everywhere() -> Range<usize> {
        0..usize::MAX
    }

    #[test]
    fn the_check_found_in_a_table_verifies_as_the_crate_does() {
        // SAFETY: TABLE is a Services, alive for the test.
        let service = unsafe { Service::find(&raw const TABLE as usize, everywhere()) }.unwrap();
        let (key, digest, signature) = signed();
        assert_eq!(service.verify(&key, &digest, &signature), Ok(()));
        let mut forged = signature;
        forged[0] ^= 1;
        assert_eq!(service.verify(&key, &digest, &forged), Err(SignatureError::Mismatch));
        assert_eq!(crate::verify(&key, &digest, &forged), Err(SignatureError::Mismatch));
        let mut other = digest;
        other[DIGEST_LEN - 1] ^= 0x80;
        assert_eq!(service.verify(&key, &other, &signature), Err(SignatureError::Mismatch));
    }

    #[test]
    fn a_key_off_the_curve_is_told_apart() {
        // SAFETY: as above.
        let service = unsafe { Service::find(&raw const TABLE as usize, everywhere()) }.unwrap();
        let (_, digest, signature) = signed();
        // y = 2 has no x on the curve.
        let mut key = [0; 32];
        key[0] = 2;
        assert_eq!(crate::verify(&key, &digest, &signature), Err(SignatureError::PublicKey));
        assert_eq!(service.verify(&key, &digest, &signature), Err(SignatureError::PublicKey));
    }

    #[test]
    fn no_table_without_the_magic() {
        #[repr(C, align(8))]
        struct Fake([u8; 8], usize);
        let entry = TABLE.verify as usize;
        let mut fake = Fake(MAGIC, entry);
        fake.0[7] ^= 0xff;
        // SAFETY: `fake` is readable for a Services' size.
        assert!(unsafe { Service::find(&raw const fake as usize, everywhere()) }.is_none());
        let erased = Fake([0xff; 8], usize::MAX);
        // SAFETY: as above.
        assert!(unsafe { Service::find(&raw const erased as usize, everywhere()) }.is_none());
        let zeroed = Fake([0; 8], 0);
        // SAFETY: as above.
        assert!(unsafe { Service::find(&raw const zeroed as usize, everywhere()) }.is_none());
    }

    #[test]
    fn no_table_whose_entry_is_outside_the_bootloader() {
        let entry = TABLE.verify as usize;
        // SAFETY: TABLE is a Services.
        let found = |code: Range<usize>| unsafe { Service::find(&raw const TABLE as usize, code) };
        assert!(found(0..entry).is_none(), "entry just past the code");
        assert!(found(entry + 1..usize::MAX).is_none(), "entry before the code");
        assert!(found(entry..entry + 1).is_some());
    }
}
