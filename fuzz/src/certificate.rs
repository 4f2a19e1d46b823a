//! The certificate reader (firmware/certificate): arbitrary bytes as the
//! DER of a client's certificate, as port 802 reads it once the TLS
//! engine verified the chain (the reader trusts nothing it reads).
//!
//! Checked: no panic; a certificate read whole keeps its parts inside the
//! bytes it was read from; its role, when it has one, is a UTF-8 string of
//! the extension's; every accessor answers.

/// One input.
pub fn certificate(data: &[u8]) {
    let Ok(parsed) = certificate::Certificate::parse(data) else { return };
    assert_eq!(parsed.der, data, "read whole");
    for part in [parsed.tbs, parsed.issuer, parsed.subject, parsed.public_key_info, parsed.serial] {
        let inside = data.as_ptr_range();
        let range = part.as_ptr_range();
        assert!(inside.start <= range.start && range.end <= inside.end, "a part outside the input");
    }
    if let Ok(Some(role)) = parsed.role() {
        assert!(parsed.extension(certificate::ROLE_OID).is_some(), "a role without its extension");
        assert!(role.len() < data.len());
    }
    let _ = certificate::common_name(parsed.subject);
    let _ = certificate::common_name(parsed.issuer);
    let _ = parsed.dns_names().count();
    let _ = parsed.ipv4_addresses().count();
    let _ = (parsed.is_ca(), parsed.has_p256_key());
    assert!(parsed.not_before.month >= 1 && parsed.not_after.month <= 12);
    // Every extension reads (parse checked them all).
    assert!(parsed.extensions().all(|extension| extension.is_ok()));
}

/// The seeds: real certificates (an operator's, a viewer's, one without a
/// role, one whose role is not a UTF8String, a CA), made by openssl.
pub fn seeds() -> Vec<Vec<u8>> {
    let fixtures = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware/certificate/tests/fixtures");
    let mut seeds: Vec<Vec<u8>> = ["operator.der", "viewer.der", "norole.der", "printable.der", "ca.der"]
        .iter()
        .map(|name| std::fs::read(fixtures.join(name)).unwrap_or_else(|e| panic!("{name}: {e}")))
        .collect();
    seeds.sort();
    seeds
}
