use proptest::prelude::*;
use std::string::ToString;
use std::vec::Vec;

use super::*;

const OPERATOR: &[u8] = include_bytes!("../tests/fixtures/operator.der");
const VIEWER: &[u8] = include_bytes!("../tests/fixtures/viewer.der");
const NO_ROLE: &[u8] = include_bytes!("../tests/fixtures/norole.der");
const PRINTABLE_ROLE: &[u8] = include_bytes!("../tests/fixtures/printable.der");

#[test]
fn an_operator_certificate_reads_whole() {
    let certificate = Certificate::parse(OPERATOR).unwrap();
    assert_eq!(certificate.role(), Ok(Some("operator")));
    assert_eq!(common_name(certificate.subject), Some("operator-1"));
    assert_eq!(common_name(certificate.issuer), Some("Plant CA"));
    assert_eq!(certificate.serial, &[7]);
    assert_eq!(certificate.dns_names().collect::<Vec<_>>(), ["operator.example"]);
    assert!(certificate.not_before < certificate.not_after);
    assert_eq!(certificate.not_before.to_string().len(), "2026-11-27T12:41:52Z".len());
    let oids: Vec<_> = certificate.extensions().map(|e| e.unwrap().oid).collect();
    assert_eq!(oids.len(), 4);
    assert_eq!(oids[0], ROLE_OID, "the role first, as openssl wrote it");
    assert!(certificate.extensions().all(|e| !e.unwrap().critical));
    assert_eq!(Certificate::parse(VIEWER).unwrap().role(), Ok(Some("viewer")));
}

#[test]
fn cas_and_p256_keys_are_told_apart() {
    let operator = Certificate::parse(OPERATOR).unwrap();
    assert!(!operator.is_ca(), "an end entity");
    assert!(operator.has_p256_key());
    let ca = Certificate::parse(include_bytes!("../tests/fixtures/ca.der")).unwrap();
    assert!(ca.is_ca());
    assert!(ca.has_p256_key());
}

#[test]
fn a_certificate_without_the_extension_has_no_role() {
    let certificate = Certificate::parse(NO_ROLE).unwrap();
    assert_eq!(certificate.role(), Ok(None));
    assert_eq!(common_name(certificate.subject), Some("norole"));
    assert_eq!(certificate.dns_names().count(), 0);
}

#[test]
fn a_role_that_is_not_a_utf8_string_is_refused() {
    assert_eq!(Certificate::parse(PRINTABLE_ROLE).unwrap().role(), Err(Error::BadRole));
}

/// `OPERATOR` with its subject alternative name's OID (2.5.29.17) made the
/// subject key identifier's (2.5.29.14), which it has already: one byte, so
/// every length stays right.
fn with_an_extension_twice() -> Vec<u8> {
    let mut der = OPERATOR.to_vec();
    let san = der.windows(5).position(|w| w == [0x06, 0x03, 0x55, 0x1d, 0x11]).unwrap();
    der[san + 4] = 0x0e;
    der
}

#[test]
fn an_extension_given_twice_refuses_the_certificate() {
    assert_eq!(Certificate::parse(&with_an_extension_twice()), Err(Error::DuplicateExtension));
}

#[test]
fn every_prefix_and_every_longer_input_is_refused() {
    for len in 0..OPERATOR.len() {
        assert!(Certificate::parse(&OPERATOR[..len]).is_err(), "prefix of {len}");
    }
    let mut longer = OPERATOR.to_vec();
    longer.push(0);
    assert_eq!(Certificate::parse(&longer), Err(Error::Malformed));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 4096, ..ProptestConfig::default() })]

    /// Any byte changed anywhere: a result, never a panic; and whatever
    /// reads whole still gives a role only as a UTF8String.
    #[test]
    fn any_changed_byte_gives_a_result(index in 0..OPERATOR.len(), byte in any::<u8>()) {
        let mut der = OPERATOR.to_vec();
        der[index] = byte;
        if let Ok(certificate) = Certificate::parse(&der) {
            let _ = certificate.role();
            let _ = common_name(certificate.subject);
            let _ = certificate.dns_names().count();
        }
    }

    #[test]
    fn any_bytes_give_a_result(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        if let Ok(certificate) = Certificate::parse(&bytes) {
            let _ = certificate.role();
        }
        let _ = common_name(&bytes);
    }
}
