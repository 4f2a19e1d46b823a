//! What a device needs from an X.509 certificate (RFC 5280) in DER, read
//! with no heap and no panic on any input: its names, its validity, its
//! extensions, and the role Modbus/TCP Security carries in one of them.
//!
//! This crate checks no signature and trusts nothing it reads: the TLS
//! engine verifies a client's chain against the configured CA first, and
//! only then is the certificate read here. Every length is checked against
//! what is left before it is used ([`der`]); a certificate that is not one
//! whole DER `Certificate` is refused as a whole.
//!
//! ```
//! # let der = include_bytes!("../tests/fixtures/operator.der");
//! let certificate = certificate::Certificate::parse(der)?;
//! assert_eq!(certificate.role()?, Some("operator"));
//! assert_eq!(certificate::common_name(certificate.subject), Some("operator-1"));
//! # Ok::<(), certificate::Error>(())
//! ```
#![cfg_attr(not(test), no_std)]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing))]

pub mod der;
mod time;

use core::fmt;

use der::{Reader, Tlv, tag};
pub use time::Time;

/// The role extension of Modbus/TCP Security, OID 1.3.6.1.4.1.50316.802.1,
/// as DER writes the OID's contents.
pub const ROLE_OID: &[u8] = &[0x2b, 0x06, 0x01, 0x04, 0x01, 0x83, 0x89, 0x0c, 0x86, 0x22, 0x01];
/// id-at-commonName, 2.5.4.3.
pub const COMMON_NAME_OID: &[u8] = &[0x55, 0x04, 0x03];
/// id-ce-subjectAltName, 2.5.29.17.
pub const SUBJECT_ALT_NAME_OID: &[u8] = &[0x55, 0x1d, 0x11];
/// id-ce-basicConstraints, 2.5.29.19.
pub const BASIC_CONSTRAINTS_OID: &[u8] = &[0x55, 0x1d, 0x13];
/// id-ecPublicKey, 1.2.840.10045.2.1.
const EC_PUBLIC_KEY_OID: &[u8] = &[0x2a, 0x86, 0x48, 0xce, 0x3d, 0x02, 0x01];
/// prime256v1 (P-256), 1.2.840.10045.3.1.7.
const P256_OID: &[u8] = &[0x2a, 0x86, 0x48, 0xce, 0x3d, 0x03, 0x01, 0x07];

/// Why bytes are not a certificate this crate reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// An element runs past the end of its bytes.
    Truncated,
    /// Not the structure RFC 5280 gives, or not DER.
    Malformed,
    /// An extension given twice (RFC 5280 4.2 forbids it): which one would
    /// count is not for this device to guess.
    DuplicateExtension,
    /// The role extension holds something other than a UTF8String of UTF-8.
    BadRole,
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Truncated => "truncated certificate",
            Self::Malformed => "not an X.509 certificate in DER",
            Self::DuplicateExtension => "an extension appears twice",
            Self::BadRole => "the role extension is not a UTF8String",
        })
    }
}

impl core::error::Error for Error {}

/// A certificate's parts, each a slice of the bytes it was read from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Certificate<'a> {
    /// All of it, as given.
    pub der: &'a [u8],
    /// The signed part, `tbsCertificate`, whole.
    pub tbs: &'a [u8],
    /// The serial number's contents (big-endian, as written).
    pub serial: &'a [u8],
    /// The issuer's and the subject's `Name`, whole (see [`common_name`]).
    pub issuer: &'a [u8],
    pub subject: &'a [u8],
    pub not_before: Time,
    pub not_after: Time,
    /// `subjectPublicKeyInfo`, whole.
    pub public_key_info: &'a [u8],
    /// The `Extensions` sequence's contents (empty without any).
    extensions: &'a [u8],
}

impl<'a> Certificate<'a> {
    /// Reads `der`, which must be exactly one certificate. Extensions are
    /// checked here too (each well formed, none twice), so the accessors
    /// below cannot meet a malformed one.
    pub fn parse(der: &'a [u8]) -> Result<Self, Error> {
        let mut outer = Reader::new(der);
        let certificate = outer.expect(tag::SEQUENCE)?;
        outer.finish()?;
        let mut parts = Reader::new(certificate.value);
        let tbs = parts.expect(tag::SEQUENCE)?;
        parts.expect(tag::SEQUENCE)?; // signatureAlgorithm
        parts.expect(tag::BIT_STRING)?; // signatureValue
        parts.finish()?;

        let mut fields = Reader::new(tbs.value);
        if let Some(version) = fields.optional(tag::explicit(0))? {
            let mut version = Reader::new(version.value);
            version.expect(tag::INTEGER)?;
            version.finish()?;
        }
        let serial = fields.expect(tag::INTEGER)?;
        fields.expect(tag::SEQUENCE)?; // signature
        let issuer = fields.expect(tag::SEQUENCE)?;
        let validity = fields.expect(tag::SEQUENCE)?;
        let subject = fields.expect(tag::SEQUENCE)?;
        let public_key_info = fields.expect(tag::SEQUENCE)?;
        // issuerUniqueID [1] and subjectUniqueID [2], implicit: skipped.
        fields.optional(0x81)?;
        fields.optional(0x82)?;
        let extensions = match fields.optional(tag::explicit(3))? {
            Some(wrapper) => {
                let mut wrapper = Reader::new(wrapper.value);
                let list = wrapper.expect(tag::SEQUENCE)?;
                wrapper.finish()?;
                list.value
            }
            None => &[],
        };
        fields.finish()?;

        let mut times = Reader::new(validity.value);
        let not_before = Time::parse(times.read()?)?;
        let not_after = Time::parse(times.read()?)?;
        times.finish()?;

        let certificate = Self {
            der,
            tbs: tbs.whole,
            serial: serial.value,
            issuer: issuer.whole,
            subject: subject.whole,
            not_before,
            not_after,
            public_key_info: public_key_info.whole,
            extensions,
        };
        certificate.check_extensions()?;
        Ok(certificate)
    }

    /// Every extension well formed, and no OID twice.
    fn check_extensions(&self) -> Result<(), Error> {
        let mut outer = self.extensions();
        while let Some(extension) = outer.next() {
            let extension = extension?;
            for other in outer {
                if other?.oid == extension.oid {
                    return Err(Error::DuplicateExtension);
                }
            }
        }
        Ok(())
    }

    /// The extensions, in order.
    pub fn extensions(&self) -> Extensions<'a> {
        Extensions { reader: Reader::new(self.extensions) }
    }

    /// The extension `oid`'s value (the OCTET STRING's contents), if present.
    pub fn extension(&self, oid: &[u8]) -> Option<&'a [u8]> {
        self.extensions().flatten().find(|extension| extension.oid == oid).map(|extension| extension.value)
    }

    /// The Modbus/TCP Security role: `None` without the extension; an error
    /// when the extension holds anything but one UTF8String of UTF-8.
    pub fn role(&self) -> Result<Option<&'a str>, Error> {
        let Some(value) = self.extension(ROLE_OID) else { return Ok(None) };
        let mut reader = Reader::new(value);
        let role = reader.read().map_err(|_| Error::BadRole)?;
        if role.tag != tag::UTF8_STRING || !reader.is_empty() {
            return Err(Error::BadRole);
        }
        core::str::from_utf8(role.value).map(Some).map_err(|_| Error::BadRole)
    }

    /// The subject alternative name extension's names, each an element
    /// with its context tag (none without the extension, or after a
    /// malformed one).
    fn alt_names(&self) -> impl Iterator<Item = Tlv<'a>> + 'a {
        let names = self.extension(SUBJECT_ALT_NAME_OID).and_then(|value| {
            let mut reader = Reader::new(value);
            let list = reader.expect(tag::SEQUENCE).ok()?;
            reader.finish().ok()?;
            Some(list.value)
        });
        let mut reader = Reader::new(names.unwrap_or(&[]));
        core::iter::from_fn(move || reader.read().ok())
    }

    /// The DNS names of the subject alternative name extension, in order
    /// (other kinds of name are skipped).
    pub fn dns_names(&self) -> impl Iterator<Item = &'a str> + 'a {
        // dNSName [2], an IA5String: ASCII.
        self.alt_names().filter(|name| name.tag == 0x82).filter_map(|name| core::str::from_utf8(name.value).ok())
    }

    /// Whether the basic constraints extension says it is a CA (RFC 5280
    /// 4.2.1.9: `cA` TRUE); without the extension, it is not.
    pub fn is_ca(&self) -> bool {
        let Some(value) = self.extension(BASIC_CONSTRAINTS_OID) else { return false };
        let mut reader = Reader::new(value);
        let Ok(constraints) = reader.expect(tag::SEQUENCE) else { return false };
        let mut fields = Reader::new(constraints.value);
        matches!(fields.optional(tag::BOOLEAN), Ok(Some(Tlv { value: [0xff], .. })))
    }

    /// Whether its public key is an elliptic-curve key on P-256.
    pub fn has_p256_key(&self) -> bool {
        let mut outer = Reader::new(self.public_key_info);
        let Ok(info) = outer.expect(tag::SEQUENCE) else { return false };
        let mut fields = Reader::new(info.value);
        let Ok(algorithm) = fields.expect(tag::SEQUENCE) else { return false };
        let mut ids = Reader::new(algorithm.value);
        let (Ok(kind), Ok(curve)) = (ids.expect(tag::OID), ids.expect(tag::OID)) else { return false };
        kind.value == EC_PUBLIC_KEY_OID && curve.value == P256_OID
    }

    /// The IPv4 addresses of the subject alternative name extension, in
    /// order (IPv6 and other kinds of name are skipped).
    pub fn ipv4_addresses(&self) -> impl Iterator<Item = [u8; 4]> + 'a {
        // iPAddress [7], an OCTET STRING: 4 bytes for IPv4.
        self.alt_names().filter(|name| name.tag == 0x87).filter_map(|name| <[u8; 4]>::try_from(name.value).ok())
    }
}

/// One extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Extension<'a> {
    /// The OID's contents.
    pub oid: &'a [u8],
    pub critical: bool,
    /// The OCTET STRING's contents: the extension's own DER.
    pub value: &'a [u8],
}

/// The extensions of a certificate, each read as it comes.
#[derive(Clone, Copy, Debug)]
pub struct Extensions<'a> {
    reader: Reader<'a>,
}

impl<'a> Iterator for Extensions<'a> {
    type Item = Result<Extension<'a>, Error>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.reader.is_empty() {
            return None;
        }
        let extension = read_extension(&mut self.reader);
        if extension.is_err() {
            // Nothing after a malformed element can be found reliably.
            self.reader = Reader::new(&[]);
        }
        Some(extension)
    }
}

fn read_extension<'a>(reader: &mut Reader<'a>) -> Result<Extension<'a>, Error> {
    let sequence = reader.expect(tag::SEQUENCE)?;
    let mut fields = Reader::new(sequence.value);
    let oid = fields.expect(tag::OID)?;
    let critical = match fields.optional(tag::BOOLEAN)? {
        Some(Tlv { value: [0xff], .. }) => true,
        // DER writes FALSE by leaving it out (X.690 11.5); 0x00 is read too.
        Some(Tlv { value: [0x00], .. }) => false,
        Some(_) => return Err(Error::Malformed),
        None => false,
    };
    let value = fields.expect(tag::OCTET_STRING)?;
    fields.finish()?;
    Ok(Extension { oid: oid.value, critical, value: value.value })
}

/// The first common name (CN) in a `Name`, if it is a UTF8String,
/// PrintableString or IA5String of UTF-8.
pub fn common_name(name: &[u8]) -> Option<&str> {
    let mut outer = Reader::new(name);
    let sequence = outer.expect(tag::SEQUENCE).ok()?;
    let mut rdns = Reader::new(sequence.value);
    while !rdns.is_empty() {
        let set = rdns.expect(tag::SET).ok()?;
        let mut attributes = Reader::new(set.value);
        while !attributes.is_empty() {
            let attribute = attributes.expect(tag::SEQUENCE).ok()?;
            let mut fields = Reader::new(attribute.value);
            let oid = fields.expect(tag::OID).ok()?;
            let value = fields.read().ok()?;
            let text_kind = matches!(value.tag, tag::UTF8_STRING | tag::PRINTABLE_STRING | tag::IA5_STRING);
            if oid.value == COMMON_NAME_OID && text_kind {
                return core::str::from_utf8(value.value).ok();
            }
        }
    }
    None
}

#[cfg(test)]
mod tests;
