use ed25519_dalek::{Signer, SigningKey};
use proptest::prelude::*;

use super::*;

/// A header for `mps2-an386` 1.2.3 with a 0x0102_0304-byte payload and
/// the signature 0x40, 0x41, ... 0x7f, byte by byte.
#[rustfmt::skip]
const HEADER: [u8; HEADER_LEN] = [
    // magic "MBIOFW\r\n"
    b'M', b'B', b'I', b'O', b'F', b'W', b'\r', b'\n',
    // format version 2, header length 128 (LE)
    0x02, 0x00, 0x80, 0x00,
    // board "mps2-an386", NUL-padded to 32 bytes
    b'm', b'p', b's', b'2', b'-', b'a', b'n', b'3', b'8', b'6', 0, 0, 0, 0, 0, 0,
    0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
    // version 1.2.3 (u16 LE each), reserved 0
    0x01, 0x00, 0x02, 0x00, 0x03, 0x00, 0x00, 0x00,
    // payload length 0x01020304 (LE)
    0x04, 0x03, 0x02, 0x01,
    // reserved, 8 bytes of 0
    0, 0, 0, 0, 0, 0, 0, 0,
    // signature: 64 bytes
    0x40, 0x41, 0x42, 0x43, 0x44, 0x45, 0x46, 0x47, 0x48, 0x49, 0x4a, 0x4b, 0x4c, 0x4d, 0x4e, 0x4f,
    0x50, 0x51, 0x52, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5a, 0x5b, 0x5c, 0x5d, 0x5e, 0x5f,
    0x60, 0x61, 0x62, 0x63, 0x64, 0x65, 0x66, 0x67, 0x68, 0x69, 0x6a, 0x6b, 0x6c, 0x6d, 0x6e, 0x6f,
    0x70, 0x71, 0x72, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7a, 0x7b, 0x7c, 0x7d, 0x7e, 0x7f,
];

fn header() -> Header {
    let mut signature = [0; SIGNATURE_LEN];
    for (i, b) in signature.iter_mut().enumerate() {
        *b = 0x40 + i as u8;
    }
    Header {
        board: Board::new("mps2-an386").unwrap(),
        version: Version { major: 1, minor: 2, patch: 3 },
        payload_len: 0x0102_0304,
        signature,
    }
}

/// The key of RFC 8032's test 1 (any fixed key would do).
fn signing_key() -> SigningKey {
    SigningKey::from_bytes(&[
        0x9d, 0x61, 0xb1, 0x9d, 0xef, 0xfd, 0x5a, 0x60, 0xba, 0x84, 0x4a, 0xf4, 0x92, 0xec, 0x2c, 0xc4, 0x44, 0x49,
        0xc5, 0x69, 0x7b, 0x32, 0x69, 0x19, 0x70, 0x3b, 0xac, 0x03, 0x1c, 0xae, 0x7f, 0x60,
    ])
}

/// A signed image (header and payload) of `payload` for `board`.
fn signed(board: &str, payload: &[u8]) -> Vec<u8> {
    let mut header = Header {
        board: Board::new(board).unwrap(),
        version: Version { major: 0, minor: 2, patch: 0 },
        payload_len: payload.len() as u32,
        signature: [0; SIGNATURE_LEN],
    };
    let mut digest = header.digest();
    digest.update(payload);
    header.signature = signing_key().sign(&digest.finalize()).to_bytes();
    let mut image = header.emit().to_vec();
    image.extend_from_slice(payload);
    image
}

/// Checks the image's signature the way the device does: parse, digest, verify.
fn check(image: &[u8], key: &[u8; PUBLIC_KEY_LEN]) -> Result<Header, &'static str> {
    let header = Header::parse(image).map_err(|_| "format")?;
    let payload = image.get(HEADER_LEN..).ok_or("payload")?;
    if payload.len() != header.payload_len as usize {
        return Err("length");
    }
    let mut digest = header.digest();
    digest.update(payload);
    header.verify(key, &digest.finalize()).map_err(|_| "signature")?;
    Ok(header)
}

#[test]
fn the_annotated_header_parses() {
    assert_eq!(Header::parse(&HEADER), Ok(header()));
}

#[test]
fn emit_writes_the_annotated_bytes() {
    assert_eq!(header().emit(), HEADER);
}

#[test]
fn the_payload_after_the_header_is_not_looked_at() {
    let mut bytes = HEADER.to_vec();
    bytes.extend_from_slice(&[0xa5; 40]);
    assert_eq!(Header::parse(&bytes), Ok(header()));
}

#[test]
fn every_prefix_is_truncated() {
    for len in 0..HEADER_LEN {
        assert_eq!(Header::parse(&HEADER[..len]), Err(FormatError::Truncated), "{len} bytes");
    }
}

#[test]
fn every_magic_byte_is_checked() {
    for at in field::MAGIC {
        let mut bytes = HEADER;
        bytes[at] ^= 0x20;
        assert_eq!(Header::parse(&bytes), Err(FormatError::Magic), "byte {at}");
    }
}

#[test]
fn another_format_version_is_refused() {
    // 1: format 1's files, whose digest was SHA-512.
    for version in [0u16, 1, 3, 0x0200, u16::MAX] {
        let mut bytes = HEADER;
        bytes[field::FORMAT_VERSION].copy_from_slice(&version.to_le_bytes());
        assert_eq!(Header::parse(&bytes), Err(FormatError::FormatVersion(version)));
    }
}

#[test]
fn another_header_length_is_refused() {
    for len in [0u16, 64, 127, 129, 256] {
        let mut bytes = HEADER;
        bytes[field::HEADER_LEN].copy_from_slice(&len.to_le_bytes());
        assert_eq!(Header::parse(&bytes), Err(FormatError::HeaderLen(len)));
    }
}

#[test]
fn a_bad_board_id_is_refused() {
    let cases: [&[u8]; 5] = [
        b"",              // empty
        b"MPS2",          // upper case
        b"mps2 an386",    // a space
        b"mps2\0an386",   // bytes after the NUL
        b"mps2-\xc3\xa9", // not ASCII
    ];
    for id in cases {
        let mut bytes = HEADER;
        bytes[field::BOARD].fill(0);
        bytes[field::BOARD][..id.len()].copy_from_slice(id);
        assert_eq!(Header::parse(&bytes), Err(FormatError::Board), "{id:?}");
    }
}

#[test]
fn a_board_id_of_32_bytes_has_no_nul() {
    let mut bytes = HEADER;
    bytes[field::BOARD].copy_from_slice(b"abcdefghijklmnopqrstuvwxyz012345");
    assert_eq!(Header::parse(&bytes).unwrap().board.as_str(), "abcdefghijklmnopqrstuvwxyz012345");
}

#[test]
fn reserved_fields_must_be_zero() {
    for at in field::RESERVED_1.chain(field::RESERVED_2) {
        let mut bytes = HEADER;
        bytes[at] = 1;
        assert_eq!(Header::parse(&bytes), Err(FormatError::Reserved), "byte {at}");
    }
}

#[test]
fn an_empty_payload_is_refused() {
    let mut bytes = HEADER;
    bytes[field::PAYLOAD_LEN].fill(0);
    assert_eq!(Header::parse(&bytes), Err(FormatError::Empty));
}

#[test]
fn board_ids_follow_the_rule() {
    assert_eq!(Board::new("nucleo-f429zi").unwrap().as_str(), "nucleo-f429zi");
    assert!(Board::new(&"a".repeat(MAX_BOARD_LEN)).is_some());
    for bad in ["", "A", "a_b", "a.b", "ä", &"a".repeat(MAX_BOARD_LEN + 1)] {
        assert!(Board::new(bad).is_none(), "{bad:?}");
    }
}

#[test]
fn versions_parse_as_three_decimal_parts() {
    assert_eq!(Version::parse("1.2.3"), Some(Version { major: 1, minor: 2, patch: 3 }));
    assert_eq!(Version::parse("0.0.65535"), Some(Version { major: 0, minor: 0, patch: 65535 }));
    for bad in ["", "1", "1.2", "1.2.3.4", "1..3", "1.2.65536", "+1.2.3", "1.2.3-rc1", " 1.2.3"] {
        assert_eq!(Version::parse(bad), None, "{bad:?}");
    }
    assert_eq!(Version { major: 10, minor: 0, patch: 7 }.to_string(), "10.0.7");
}

#[test]
fn a_signed_image_verifies() {
    let key = signing_key().verifying_key().to_bytes();
    let image = signed("mps2-an386", b"the application");
    let header = check(&image, &key).unwrap();
    assert_eq!(header.board.as_str(), "mps2-an386");
    assert_eq!(header.payload_len, 15);
}

/// RFC 8032's test 1 (section 7.1): the key's public half, and its
/// signature of the empty message verifies here, so the signatures are
/// ed25519's and not something that merely round-trips.
#[test]
fn rfc_8032_test_1_verifies() {
    let public = signing_key().verifying_key().to_bytes();
    assert_eq!(public[..4], [0xd7, 0x5a, 0x98, 0x01]);
    assert_eq!(public[28..], [0xf7, 0x07, 0x51, 0x1a]);
    #[rustfmt::skip]
    let signature = [
        0xe5, 0x56, 0x43, 0x00, 0xc3, 0x60, 0xac, 0x72, 0x90, 0x86, 0xe2, 0xcc, 0x80, 0x6e, 0x82, 0x8a,
        0x84, 0x87, 0x7f, 0x1e, 0xb8, 0xe5, 0xd9, 0x74, 0xd8, 0x73, 0xe0, 0x65, 0x22, 0x49, 0x01, 0x55,
        0x5f, 0xb8, 0x82, 0x15, 0x90, 0xa3, 0x3b, 0xac, 0xc6, 0x1e, 0x39, 0x70, 0x1c, 0xf9, 0xb4, 0x6b,
        0xd2, 0x5b, 0xf5, 0xf0, 0x59, 0x5b, 0xbe, 0x24, 0x65, 0x51, 0x41, 0x43, 0x8e, 0x7a, 0x10, 0x0b,
    ];
    assert_eq!(signing_key().sign(b"").to_bytes(), signature);
    let key = VerifyingKey::from_bytes(&public).unwrap();
    assert!(key.verify_strict(b"", &Signature::from_bytes(&signature)).is_ok());
}

/// The digest is SHA-256 of the signed header bytes and then the payload,
/// however the payload is split.
#[test]
fn the_digest_is_sha256_of_header_then_payload() {
    let header = header();
    let payload = [7u8; 300];
    let mut digest = header.digest();
    digest.update(&payload[..100]);
    digest.update(&payload[100..]);
    let mut whole = header.signed_bytes().to_vec();
    whole.extend_from_slice(&payload);
    assert_eq!(digest.finalize(), <[u8; DIGEST_LEN]>::from(Sha256::digest(&whole)));
    // And SHA-256 is SHA-256: FIPS 180-2's "abc".
    let abc = Sha256::digest(b"abc");
    assert_eq!(abc[..4], [0xba, 0x78, 0x16, 0xbf]);
}

#[test]
fn any_changed_byte_breaks_the_signature() {
    let key = signing_key().verifying_key().to_bytes();
    let image = signed("mps2-an386", &[0x5a; 50]);
    // Every byte of the signed header, of the signature and of the payload;
    // changes the format check catches are "format", the rest "signature".
    for at in 0..image.len() {
        let mut bad = image.clone();
        bad[at] ^= 0x01;
        let result = check(&bad, &key);
        assert!(result.is_err(), "byte {at} changed and still accepted");
    }
}

#[test]
fn a_relabelled_board_or_version_is_caught_by_the_signature() {
    let key = signing_key().verifying_key().to_bytes();
    let image = signed("mps2-an386", &[1, 2, 3, 4]);
    let mut header = Header::parse(&image).unwrap();
    header.board = Board::new("nucleo-f429zi").unwrap();
    let mut relabelled = header.emit().to_vec();
    relabelled.extend_from_slice(&image[HEADER_LEN..]);
    assert_eq!(check(&relabelled, &key).unwrap_err(), "signature");

    let mut header = Header::parse(&image).unwrap();
    header.version.major = 9;
    let mut relabelled = header.emit().to_vec();
    relabelled.extend_from_slice(&image[HEADER_LEN..]);
    assert_eq!(check(&relabelled, &key).unwrap_err(), "signature");
}

#[test]
fn another_key_does_not_verify() {
    let other = SigningKey::from_bytes(&[7; 32]).verifying_key().to_bytes();
    let image = signed("mps2-an386", &[1, 2, 3]);
    assert_eq!(check(&image, &other).unwrap_err(), "signature");
}

#[test]
fn a_key_off_the_curve_is_refused() {
    // y = 2 is not the y of a point on edwards25519.
    let mut bad_key = [0u8; 32];
    bad_key[0] = 2;
    let digest = [0; DIGEST_LEN];
    assert_eq!(verify(&bad_key, &digest, &[0; SIGNATURE_LEN]), Err(SignatureError::PublicKey));
}

fn any_header() -> impl Strategy<Value = Header> {
    ("[a-z0-9-]{1,32}", any::<(u16, u16, u16)>(), 1..=u32::MAX, proptest::collection::vec(any::<u8>(), SIGNATURE_LEN))
        .prop_map(|(board, (major, minor, patch), payload_len, signature)| Header {
            board: Board::new(&board).unwrap(),
            version: Version { major, minor, patch },
            payload_len,
            signature: signature.try_into().unwrap(),
        })
}

proptest! {
    #[test]
    fn parse_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
        let _ = Header::parse(&bytes);
    }

    #[test]
    fn parse_never_panics_near_a_valid_header(at in 0..HEADER_LEN, value in any::<u8>(), len in 0..=HEADER_LEN) {
        let mut bytes = HEADER;
        bytes[at] = value;
        let _ = Header::parse(&bytes[..len]);
    }

    #[test]
    fn parse_reads_what_emit_writes(header in any_header()) {
        prop_assert_eq!(Header::parse(&header.emit()), Ok(header));
    }

    #[test]
    fn a_header_parsed_is_emitted_as_it_came(bytes in proptest::collection::vec(any::<u8>(), HEADER_LEN)) {
        if let Ok(header) = Header::parse(&bytes) {
            prop_assert_eq!(&header.emit()[..], &bytes[..]);
        }
    }
}
