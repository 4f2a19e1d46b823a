//! The device's own key and certificate: a P-256 key from the generator,
//! and a self-signed certificate naming the device (its name, `NAME.local`,
//! its address), which a plant may replace with one its CA signed.
//!
//! The device has no clock, so its certificate's validity cannot follow
//! the date: it runs from 2025-01-01 to 9999-12-31, RFC 5280's "no
//! well-defined expiration" (4.1.2.5).

use core::ffi::c_char;
use core::mem::MaybeUninit;
use core::ptr;

use mbedtls_rs_sys as sys;

use crate::{Error, check, rng};

/// A P-256 private key: its scalar, big-endian.
pub const KEY_LEN: usize = 32;

/// The longest self-signed certificate this writes (a 32-character name
/// and an address make about 450 bytes).
pub const MAX_SELF_SIGNED_LEN: usize = 1024;

/// P-256's group order n, big-endian: a private key is in 1..n.
const ORDER: [u8; KEY_LEN] = [
    0xff, 0xff, 0xff, 0xff, 0x00, 0x00, 0x00, 0x00, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xbc, 0xe6, 0xfa,
    0xad, 0xa7, 0x17, 0x9e, 0x84, 0xf3, 0xb9, 0xca, 0xc2, 0xfc, 0x63, 0x25, 0x51,
];

/// A new private key from the generator: 32 random bytes, drawn again
/// until they fall in 1..n (FIPS 186-5 A.4.2's rejection sampling; a draw
/// falls outside with a probability of about 2^-32).
pub fn generate_key() -> Result<[u8; KEY_LEN], Error> {
    for _ in 0..8 {
        let mut scalar = [0u8; KEY_LEN];
        if !rng::fill(&mut scalar) {
            return Err(Error::NoEntropy);
        }
        if scalar != [0; KEY_LEN] && scalar < ORDER {
            return Ok(scalar);
        }
    }
    Err(Error::NoEntropy)
}

/// The length of [`key_der`]'s encoding.
pub const KEY_DER_LEN: usize = 51;

/// The key as SEC1 DER (RFC 5915 `ECPrivateKey`, the curve named, the
/// public key left out: whoever reads it derives it).
pub fn key_der(scalar: &[u8; KEY_LEN]) -> [u8; KEY_DER_LEN] {
    const HEAD: [u8; 7] = [0x30, 0x31, 0x02, 0x01, 0x01, 0x04, 0x20];
    // [0] { OID 1.2.840.10045.3.1.7, prime256v1 }
    const CURVE: [u8; 12] = [0xa0, 0x0a, 0x06, 0x08, 0x2a, 0x86, 0x48, 0xce, 0x3d, 0x03, 0x01, 0x07];
    let mut der = [0u8; KEY_DER_LEN];
    let (head, rest) = der.split_at_mut(HEAD.len());
    let (key, curve) = rest.split_at_mut(KEY_LEN);
    head.copy_from_slice(&HEAD);
    key.copy_from_slice(scalar);
    curve.copy_from_slice(&CURVE);
    der
}

/// What the self-signed certificate names.
#[derive(Clone, Copy, Debug)]
pub struct Names<'a> {
    /// The device name: the subject's CN, and DNS names `NAME` and `NAME.local`.
    pub name: &'a str,
    /// Its IPv4 address, an IP name, when it has one.
    pub address: Option<[u8; 4]>,
}

/// The longest device name (the settings' rule).
const MAX_NAME_LEN: usize = 32;

/// Writes a self-signed certificate for `key` naming `names` into `out`
/// and returns it. `serial`: 1 to 20 bytes, big-endian.
pub fn self_signed<'o>(
    key: &[u8; KEY_LEN],
    names: &Names<'_>,
    serial: &[u8],
    out: &'o mut [u8],
) -> Result<&'o [u8], Error> {
    let name = names.name.as_bytes();
    if name.is_empty() || name.len() > MAX_NAME_LEN || !name.iter().all(|b| b.is_ascii_alphanumeric() || *b == b'-') {
        return Err(Error::BadName);
    }
    // "CN=" NAME NUL, for Mbed TLS's name parser.
    let mut subject = [0u8; 3 + MAX_NAME_LEN + 1];
    let (cn, rest) = subject.split_at_mut(3);
    cn.copy_from_slice(b"CN=");
    rest.get_mut(..name.len()).ok_or(Error::BadName)?.copy_from_slice(name);
    // NAME.local, for the DNS name.
    let mut local = [0u8; MAX_NAME_LEN + 6];
    local.get_mut(..name.len()).ok_or(Error::BadName)?.copy_from_slice(name);
    local.get_mut(name.len()..name.len() + 6).ok_or(Error::BadName)?.copy_from_slice(b".local");
    let local = local.get(..name.len() + 6).ok_or(Error::BadName)?;
    let address = names.address.unwrap_or_default();

    let der = key_der(key);
    let mut pk = MaybeUninit::<sys::mbedtls_pk_context>::zeroed();
    let mut writer = MaybeUninit::<sys::mbedtls_x509write_cert>::zeroed();
    let pk = pk.as_mut_ptr();
    let writer = writer.as_mut_ptr();
    // SAFETY: both are initialized before use and freed on every path
    // below; every pointer handed over outlives the calls that use it.
    let written = unsafe {
        sys::mbedtls_pk_init(pk);
        sys::mbedtls_x509write_crt_init(writer);
        let result = (|| {
            check(sys::mbedtls_pk_parse_key(
                pk,
                der.as_ptr(),
                der.len(),
                ptr::null(),
                0,
                Some(rng::random),
                ptr::null_mut(),
            ))
            .map_err(|_| Error::BadKey)?;
            sys::mbedtls_x509write_crt_set_version(writer, sys::MBEDTLS_X509_CRT_VERSION_3 as i32);
            sys::mbedtls_x509write_crt_set_md_alg(writer, sys::mbedtls_md_type_t_MBEDTLS_MD_SHA256);
            sys::mbedtls_x509write_crt_set_subject_key(writer, pk);
            sys::mbedtls_x509write_crt_set_issuer_key(writer, pk);
            let subject = subject.as_ptr().cast::<c_char>();
            check(sys::mbedtls_x509write_crt_set_subject_name(writer, subject))?;
            check(sys::mbedtls_x509write_crt_set_issuer_name(writer, subject))?;
            check(sys::mbedtls_x509write_crt_set_serial_raw(writer, serial.as_ptr().cast_mut(), serial.len()))?;
            check(sys::mbedtls_x509write_crt_set_validity(
                writer,
                c"20250101000000".as_ptr(),
                c"99991231235959".as_ptr(),
            ))?;
            check(sys::mbedtls_x509write_crt_set_basic_constraints(writer, 0, -1))?;
            check(sys::mbedtls_x509write_crt_set_key_usage(writer, sys::MBEDTLS_X509_KU_DIGITAL_SIGNATURE))?;
            // The names: NAME, NAME.local, and the address if any.
            let mut sans: [sys::mbedtls_x509_san_list; 3] = core::array::from_fn(|_| sys::mbedtls_x509_san_list {
                node: sys::mbedtls_x509_subject_alternative_name { type_: 0, san: core::mem::zeroed() },
                next: ptr::null_mut(),
            });
            let dns = |text: &[u8]| sys::mbedtls_x509_subject_alternative_name {
                type_: sys::MBEDTLS_X509_SAN_DNS_NAME as i32,
                san: sys::mbedtls_x509_subject_alternative_name__bindgen_ty_1 {
                    unstructured_name: sys::mbedtls_x509_buf { tag: 0, len: text.len(), p: text.as_ptr().cast_mut() },
                },
            };
            let [first, second, third] = &mut sans;
            first.node = dns(name);
            second.node = dns(local);
            first.next = second;
            if names.address.is_some() {
                third.node = sys::mbedtls_x509_subject_alternative_name {
                    type_: sys::MBEDTLS_X509_SAN_IP_ADDRESS as i32,
                    san: sys::mbedtls_x509_subject_alternative_name__bindgen_ty_1 {
                        unstructured_name: sys::mbedtls_x509_buf {
                            tag: 0,
                            len: address.len(),
                            p: address.as_ptr().cast_mut(),
                        },
                    },
                };
                second.next = third;
            }
            check(sys::mbedtls_x509write_crt_set_subject_alternative_name(writer, first))?;
            // Written at the end of `out`; the count is returned.
            let len =
                sys::mbedtls_x509write_crt_der(writer, out.as_mut_ptr(), out.len(), Some(rng::random), ptr::null_mut());
            check(len)?;
            usize::try_from(len).map_err(|_| Error::Internal)
        })();
        sys::mbedtls_x509write_crt_free(writer);
        sys::mbedtls_pk_free(pk);
        result
    }?;
    let start = out.len().checked_sub(written).ok_or(Error::Internal)?;
    out.get(start..).ok_or(Error::Internal)
}

/// Whether Mbed TLS reads `der` as one certificate (it is parsed into the
/// arena and freed again).
pub fn check_certificate(der: &[u8]) -> Result<(), Error> {
    let mut parsed = MaybeUninit::<sys::mbedtls_x509_crt>::zeroed();
    let parsed = parsed.as_mut_ptr();
    // SAFETY: initialized, used, freed; `der` outlives the call.
    unsafe {
        sys::mbedtls_x509_crt_init(parsed);
        let result = check(sys::mbedtls_x509_crt_parse_der(parsed, der.as_ptr(), der.len()));
        sys::mbedtls_x509_crt_free(parsed);
        result.map_err(|_| Error::BadCertificate)
    }
}
