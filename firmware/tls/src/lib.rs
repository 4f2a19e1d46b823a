//! The device's TLS server side (docs/tls.md): Mbed TLS 3.6 through its
//! raw bindings, driven over any `embedded-io-async` stream, with every
//! byte it allocates taken from one fixed arena.
//!
//! - [`init`]: once, the arena and the entropy source.
//! - [`Server`]: a configuration made from DER credentials: the device's
//!   certificate and P-256 key, and optionally the CA that clients'
//!   certificates must chain to (Modbus/TCP Security) .
//! - [`identity`]: the device's own P-256 key and self-signed certificate.
//! - [`Session`]: one connection: [`Session::handshake`], then
//!   `embedded-io-async` `Read` and `Write`, [`Session::peer_certificate`].
//!
//! Out of memory is an error like any other: the arena's `calloc` returns
//! null and Mbed TLS fails the handshake (or the configuration) it was
//! making. Nothing here panics.
#![no_std]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing))]

pub mod arena;
pub mod identity;
pub mod rng;
mod server;
mod session;

// The C library functions Mbed TLS needs beyond compiler-builtins'.
#[cfg(target_os = "none")]
use tinyrlibc as _;

use core::fmt;

use mbedtls_rs_sys as sys;

pub use self::rng::Entropy;
pub use self::server::{Credentials, Server};
pub use self::session::{RX_LEN, Session, TX_LEN};

/// Why a TLS operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// Mbed TLS's error code (negative).
    Mbedtls(i32),
    /// The arena had no room.
    OutOfMemory,
    /// A certificate is not DER Mbed TLS reads.
    BadCertificate,
    /// The key is not a P-256 key in SEC1 or PKCS#8 DER.
    BadKey,
    /// The key is not the certificate's.
    KeyMismatch,
    /// The stream failed.
    Io(embedded_io_async::ErrorKind),
    /// A length the session computed fell outside its buffers.
    Internal,
    /// [`init`] was not called, or the entropy source failed.
    NoEntropy,
    /// A device name a certificate cannot carry (the settings' rule).
    BadName,
}

impl Error {
    /// Whether the peer's certificate was refused (missing, or not
    /// chaining to the CA), as opposed to any other failure.
    pub fn is_certificate(&self) -> bool {
        matches!(
            self,
            Self::Mbedtls(
                sys::MBEDTLS_ERR_X509_CERT_VERIFY_FAILED
                    | sys::MBEDTLS_ERR_SSL_NO_CLIENT_CERTIFICATE
                    | sys::MBEDTLS_ERR_SSL_BAD_CERTIFICATE
            )
        )
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Mbedtls(code) => write!(f, "Mbed TLS error -0x{:04x}", code.unsigned_abs()),
            Self::OutOfMemory => f.write_str("the TLS arena is full"),
            Self::BadCertificate => f.write_str("not a certificate in DER"),
            Self::BadKey => f.write_str("not a P-256 private key in DER"),
            Self::KeyMismatch => f.write_str("the key is not the certificate's"),
            Self::Io(kind) => write!(f, "stream error: {kind:?}"),
            Self::Internal => f.write_str("internal length error"),
            Self::NoEntropy => f.write_str("no entropy"),
            Self::BadName => f.write_str("not a device name"),
        }
    }
}

impl core::error::Error for Error {}

impl embedded_io_async::Error for Error {
    fn kind(&self) -> embedded_io_async::ErrorKind {
        match self {
            Self::Io(kind) => *kind,
            Self::OutOfMemory => embedded_io_async::ErrorKind::OutOfMemory,
            _ => embedded_io_async::ErrorKind::Other,
        }
    }
}

/// Mbed TLS's status as a result: 0 and positive counts are fine.
pub(crate) fn check(status: i32) -> Result<(), Error> {
    match status {
        0.. => Ok(()),
        sys::MBEDTLS_ERR_SSL_ALLOC_FAILED => Err(Error::OutOfMemory),
        error => Err(Error::Mbedtls(error)),
    }
}

/// Gives Mbed TLS its arena (one region, or up to [`arena::MAX_REGIONS`])
/// and its entropy source: once, before anything else here. Fails when
/// there are too many regions, the source gives no entropy or PSA cannot
/// start.
pub fn init(arena: impl IntoIterator<Item = &'static mut [u8]>, entropy: Entropy) -> Result<(), Error> {
    if !arena::init(arena) {
        return Err(Error::Internal);
    }
    // SAFETY: plain function pointers with calloc's and free's contracts.
    unsafe { sys::mbedtls_platform_set_calloc_free(Some(arena::calloc), Some(arena::free)) };
    if !rng::init(entropy) {
        return Err(Error::NoEntropy);
    }
    // SAFETY: after the allocator and the random source are in place.
    match unsafe { sys::psa_crypto_init() } {
        0 => Ok(()),
        status => Err(Error::Mbedtls(status)),
    }
}
