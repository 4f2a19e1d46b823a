// The Modbus/TCP Security role of a client certificate: the UTF8String in
// the extension 1.3.6.1.4.1.50316.802.1, read from the certificate's DER with
// no allocation and no panic. Engine-independent: both spikes include it.

/// DER of the OID 1.3.6.1.4.1.50316.802.1 (contents octets).
pub const ROLE_OID: &[u8] = &[0x2b, 0x06, 0x01, 0x04, 0x01, 0x83, 0x89, 0x0c, 0x86, 0x22, 0x01];

/// One TLV: (tag, contents, rest).
fn tlv(input: &[u8]) -> Option<(u8, &[u8], &[u8])> {
    let (&tag, rest) = input.split_first()?;
    let (&first, rest) = rest.split_first()?;
    let (len, rest) = if first < 0x80 {
        (usize::from(first), rest)
    } else {
        let n = usize::from(first & 0x7f);
        if n == 0 || n > 3 {
            return None;
        }
        let (bytes, rest) = rest.split_at_checked(n)?;
        (bytes.iter().fold(0usize, |acc, &b| (acc << 8) | usize::from(b)), rest)
    };
    let (contents, rest) = rest.split_at_checked(len)?;
    Some((tag, contents, rest))
}

/// The role of a certificate: Ok(None) when it has no role extension,
/// Err(()) when the DER or the extension is malformed.
pub fn role(cert_der: &[u8]) -> Result<Option<&str>, ()> {
    let (0x30, cert, _) = tlv(cert_der).ok_or(())? else { return Err(()) };
    let (0x30, mut tbs, _) = tlv(cert).ok_or(())? else { return Err(()) };
    // Skip to the [3] EXPLICIT extensions, the last field of the TBS.
    while !tbs.is_empty() {
        let (tag, contents, rest) = tlv(tbs).ok_or(())?;
        tbs = rest;
        if tag != 0xa3 {
            continue;
        }
        let (0x30, mut exts, _) = tlv(contents).ok_or(())? else { return Err(()) };
        while !exts.is_empty() {
            let (0x30, ext, rest) = tlv(exts).ok_or(())? else { return Err(()) };
            exts = rest;
            let (0x06, oid, mut ext) = tlv(ext).ok_or(())? else { return Err(()) };
            if oid != ROLE_OID {
                continue;
            }
            let (mut tag, mut value, more) = tlv(ext).ok_or(())?;
            if tag == 0x01 {
                // critical BOOLEAN
                ext = more;
                (tag, value, _) = tlv(ext).ok_or(())?;
            }
            if tag != 0x04 {
                return Err(());
            }
            let (0x0c, utf8, _) = tlv(value).ok_or(())? else { return Err(()) };
            return core::str::from_utf8(utf8).map(Some).map_err(|_| ());
        }
    }
    Ok(None)
}
