//! The server's configuration: its certificate and key, the CA its
//! clients' certificates must chain to, the versions, suites and curves.
//! Made once from DER and shared by every session.

use core::ffi::c_void;
use core::mem::{align_of, size_of};
use core::ptr::{self, NonNull};

use mbedtls_rs_sys as sys;

use crate::{Error, arena, check, rng};

/// What a server presents and whom it trusts, in DER.
#[derive(Clone, Copy, Debug)]
pub struct Credentials<'a> {
    /// The server's certificate.
    pub certificate: &'a [u8],
    /// Its private key: SEC1 (`EC PRIVATE KEY`) or PKCS#8, P-256.
    pub key: &'a [u8],
    /// The CA that client certificates must chain to; `None`: no client
    /// certificate is asked for (HTTPS, where the password authenticates).
    pub client_ca: Option<&'a [u8]>,
}

/// The suites offered: AES-128-GCM with SHA-256, in TLS 1.3 and, with
/// ECDHE and an ECDSA certificate, in TLS 1.2. Zero ends the list.
static CIPHERSUITES: [i32; 3] =
    [sys::MBEDTLS_TLS1_3_AES_128_GCM_SHA256 as i32, sys::MBEDTLS_TLS_ECDHE_ECDSA_WITH_AES_128_GCM_SHA256 as i32, 0];

/// Key exchange on P-256 only (the curve the build carries).
static GROUPS: [u16; 2] =
    [sys::MBEDTLS_SSL_IANA_TLS_GROUP_SECP256R1 as u16, sys::MBEDTLS_SSL_IANA_TLS_GROUP_NONE as u16];

/// Signatures: ECDSA on P-256 with SHA-256, the device's and its clients'.
static SIGNATURE_ALGORITHMS: [u16; 2] =
    [sys::MBEDTLS_TLS1_3_SIG_ECDSA_SECP256R1_SHA256 as u16, sys::MBEDTLS_TLS1_3_SIG_NONE as u16];

/// The C structures, in the arena so that they never move.
struct Parts {
    config: sys::mbedtls_ssl_config,
    certificate: sys::mbedtls_x509_crt,
    key: sys::mbedtls_pk_context,
    client_ca: sys::mbedtls_x509_crt,
}

const _: () = assert!(align_of::<Parts>() <= 16, "the arena aligns its blocks to 16 bytes");

/// A server configuration.
#[derive(Debug)]
pub struct Server {
    parts: NonNull<Parts>,
    verifies_clients: bool,
}

impl Server {
    /// Reads the credentials and makes the configuration. Fails when the
    /// arena has no room or the DER is not what it must be; then nothing
    /// is left allocated.
    pub fn new(credentials: &Credentials<'_>) -> Result<Self, Error> {
        // SAFETY: calloc returns null or a zeroed block of this size,
        // aligned as Parts (checked above); zero is where each `_init` starts.
        let parts = unsafe { arena::calloc(1, size_of::<Parts>()) }.cast::<Parts>();
        let parts = NonNull::new(parts).ok_or(Error::OutOfMemory)?;
        let server = Self { parts, verifies_clients: credentials.client_ca.is_some() };
        // SAFETY: the parts are ours and stay where they are; each is
        // initialized before use and freed by Drop, whatever step fails.
        unsafe {
            let p = parts.as_ptr();
            sys::mbedtls_ssl_config_init(&raw mut (*p).config);
            sys::mbedtls_x509_crt_init(&raw mut (*p).certificate);
            sys::mbedtls_pk_init(&raw mut (*p).key);
            sys::mbedtls_x509_crt_init(&raw mut (*p).client_ca);
            server.configure(credentials)?;
        }
        Ok(server)
    }

    /// # Safety
    ///
    /// The parts are initialized and owned by `self`.
    unsafe fn configure(&self, credentials: &Credentials<'_>) -> Result<(), Error> {
        let p = self.parts.as_ptr();
        // SAFETY: as the caller promises; every pointer handed to Mbed TLS
        // points into the parts, which outlive the configuration.
        unsafe {
            let certificate = credentials.certificate;
            check(sys::mbedtls_x509_crt_parse_der(&raw mut (*p).certificate, certificate.as_ptr(), certificate.len()))
                .map_err(|_| Error::BadCertificate)?;
            check(sys::mbedtls_pk_parse_key(
                &raw mut (*p).key,
                credentials.key.as_ptr(),
                credentials.key.len(),
                ptr::null(),
                0,
                Some(rng::random),
                ptr::null_mut(),
            ))
            .map_err(|_| Error::BadKey)?;
            check(sys::mbedtls_pk_check_pair(
                &raw const (*p).certificate.pk,
                &raw const (*p).key,
                Some(rng::random),
                ptr::null_mut(),
            ))
            .map_err(|_| Error::KeyMismatch)?;
            let config = &raw mut (*p).config;
            check(sys::mbedtls_ssl_config_defaults(
                config,
                sys::MBEDTLS_SSL_IS_SERVER as i32,
                sys::MBEDTLS_SSL_TRANSPORT_STREAM as i32,
                sys::MBEDTLS_SSL_PRESET_DEFAULT as i32,
            ))?;
            sys::mbedtls_ssl_conf_rng(config, Some(rng::random), ptr::null_mut::<c_void>());
            check(sys::mbedtls_ssl_conf_own_cert(config, &raw mut (*p).certificate, &raw mut (*p).key))?;
            match credentials.client_ca {
                Some(ca) => {
                    check(sys::mbedtls_x509_crt_parse_der(&raw mut (*p).client_ca, ca.as_ptr(), ca.len()))
                        .map_err(|_| Error::BadCertificate)?;
                    sys::mbedtls_ssl_conf_ca_chain(config, &raw mut (*p).client_ca, ptr::null_mut());
                    sys::mbedtls_ssl_conf_authmode(config, sys::MBEDTLS_SSL_VERIFY_REQUIRED as i32);
                }
                None => sys::mbedtls_ssl_conf_authmode(config, sys::MBEDTLS_SSL_VERIFY_NONE as i32),
            }
            (*config).private_min_tls_version = sys::mbedtls_ssl_protocol_version_MBEDTLS_SSL_VERSION_TLS1_2;
            (*config).private_max_tls_version = sys::mbedtls_ssl_protocol_version_MBEDTLS_SSL_VERSION_TLS1_3;
            sys::mbedtls_ssl_conf_ciphersuites(config, CIPHERSUITES.as_ptr());
            sys::mbedtls_ssl_conf_groups(config, GROUPS.as_ptr());
            sys::mbedtls_ssl_conf_sig_algs(config, SIGNATURE_ALGORITHMS.as_ptr());
        }
        Ok(())
    }

    /// Whether clients must present a certificate chaining to the CA.
    pub fn verifies_clients(&self) -> bool {
        self.verifies_clients
    }

    pub(crate) fn config(&self) -> *const sys::mbedtls_ssl_config {
        // SAFETY: the parts live as long as self.
        unsafe { &raw const (*self.parts.as_ptr()).config }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let p = self.parts.as_ptr();
        // SAFETY: initialized in `new`; freeing an initialized, unused part is fine.
        unsafe {
            sys::mbedtls_ssl_config_free(&raw mut (*p).config);
            sys::mbedtls_x509_crt_free(&raw mut (*p).certificate);
            sys::mbedtls_pk_free(&raw mut (*p).key);
            sys::mbedtls_x509_crt_free(&raw mut (*p).client_ca);
            arena::free(p.cast());
        }
    }
}
