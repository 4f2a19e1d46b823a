//! HTTP Basic authentication (RFC 7617): the `Authorization` header's
//! credentials, user name `admin`.

use super::{MAX_PASSWORD_LEN, USER};

/// Longest decoded `user:password` taken: `admin:` and the longest password.
pub const MAX_CREDENTIALS_LEN: usize = USER.len() + 1 + MAX_PASSWORD_LEN;

/// What a request's `Authorization` header says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Credentials<'a> {
    /// No `Authorization` header.
    Missing,
    /// Not `Basic` credentials we can read, or another user.
    Invalid,
    /// `admin` and this password.
    Admin(&'a [u8]),
}

/// The credentials of `header` (the `Authorization` value, if any), decoded into `buf`.
pub fn credentials<'a>(header: Option<&[u8]>, buf: &'a mut [u8; MAX_CREDENTIALS_LEN]) -> Credentials<'a> {
    let Some(header) = header else { return Credentials::Missing };
    let header = header.trim_ascii();
    let Some((scheme, token)) = header.split_at_checked(5) else { return Credentials::Invalid };
    if !scheme.eq_ignore_ascii_case(b"basic") || !token.first().is_some_and(u8::is_ascii_whitespace) {
        return Credentials::Invalid;
    }
    let Some(len) = base64(token.trim_ascii(), buf) else { return Credentials::Invalid };
    let decoded = buf.get(..len).unwrap_or_default();
    match decoded.split_at_checked(USER.len() + 1) {
        Some((user, password)) if user.strip_suffix(b":") == Some(USER.as_bytes()) => Credentials::Admin(password),
        _ => Credentials::Invalid,
    }
}

/// The value of one base64 digit (RFC 4648, section 4).
fn digit(byte: u8) -> Option<u32> {
    Some(u32::from(match byte {
        b'A'..=b'Z' => byte - b'A',
        b'a'..=b'z' => byte - b'a' + 26,
        b'0'..=b'9' => byte - b'0' + 52,
        b'+' => 62,
        b'/' => 63,
        _ => return None,
    }))
}

/// Decodes base64 (padded or not) into `out`; `None` for anything else or too long.
fn base64(text: &[u8], out: &mut [u8]) -> Option<usize> {
    let (text, padding) = match (text.strip_suffix(b"=="), text.strip_suffix(b"=")) {
        (Some(text), _) => (text, 2),
        (None, Some(text)) => (text, 1),
        (None, None) => (text, 0),
    };
    // Padding only ever completes the last group to 4 digits.
    if padding > 0 && (text.len() + padding) % 4 != 0 {
        return None;
    }
    let mut len = 0;
    for group in text.chunks(4) {
        let (bits, bytes) = match *group {
            [a, b] => ((digit(a)? << 18) | (digit(b)? << 12), 1),
            [a, b, c] => ((digit(a)? << 18) | (digit(b)? << 12) | (digit(c)? << 6), 2),
            [a, b, c, d] => ((digit(a)? << 18) | (digit(b)? << 12) | (digit(c)? << 6) | digit(d)?, 3),
            _ => return None,
        };
        // Canonical encodings only (RFC 4648, 3.5): the bits a short last
        // group leaves over must be zero, so one password has one encoding.
        let spare_bits = 8 * (3 - bytes);
        if bits & ((1 << spare_bits) - 1) != 0 {
            return None;
        }
        let [_, decoded @ ..] = bits.to_be_bytes();
        for byte in decoded.get(..bytes)? {
            *out.get_mut(len)? = *byte;
            len += 1;
        }
    }
    Some(len)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(header: &str) -> Option<Vec<u8>> {
        let mut buf = [0; MAX_CREDENTIALS_LEN];
        match credentials(Some(header.as_bytes()), &mut buf) {
            Credentials::Admin(password) => Some(password.to_vec()),
            _ => None,
        }
    }

    #[test]
    fn basic_credentials_decode() {
        // RFC 7617's example is Aladdin:open sesame; ours is admin.
        assert_eq!(read("Basic YWRtaW46b3BlbiBzZXNhbWU="), Some(b"open sesame".to_vec()));
        assert_eq!(read("basic   YWRtaW46b3BlbiBzZXNhbWU  "), Some(b"open sesame".to_vec()));
        assert_eq!(read("Basic YWRtaW46b3BlbiBzZXNhbWU"), Some(b"open sesame".to_vec()), "padding may be left out");
        // A last group with spare bits set is not the canonical encoding (the
        // http fuzz target found the API took one): refused.
        assert_eq!(read("Basic YWRtaW46czNjcmV0LXBhc3M="), Some(b"s3cret-pass".to_vec()));
        assert_eq!(read("Basic YWRtaW46czNjcmV0LXBhc3O="), None);
        assert_eq!(read("Basic YWRtaW46b3BlbiBzZXNhbWV="), None);
        assert_eq!(read("Basic YWRtaW46"), Some(Vec::new()), "admin with an empty password");
        assert_eq!(read("Basic YWRtaW46cGFzczp3b3Jk"), Some(b"pass:word".to_vec()), "a colon in the password");
    }

    #[test]
    fn anything_else_is_invalid() {
        let mut buf = [0; MAX_CREDENTIALS_LEN];
        assert_eq!(credentials(None, &mut buf), Credentials::Missing);
        for bad in [
            "",
            "Basic",
            "Basic ",
            "BasicYWRtaW46b3BlbiBzZXNhbWU=",
            "Bearer YWRtaW46b3BlbiBzZXNhbWU=",
            "Basic QWxhZGRpbjpvcGVuIHNlc2FtZQ==", // Aladdin
            "Basic YWRtaW4=",                     // admin, no colon
            "Basic YWRtaW46b3BlbiBzZXNhbWU===",
            "Basic YWRtaW46b3BlbiBzZXNhbWU=x",
            "Basic YWRtaW46==",
            "Basic YWRta W46",
            "Basic Y",
            "Basic YWRtaW46b3BlbiBzZXNhbWU*",
        ] {
            assert_eq!(credentials(Some(bad.as_bytes()), &mut buf), Credentials::Invalid, "{bad:?}");
        }
        // The longest password fits; one byte more does not.
        let encode = |len: usize| {
            let plain = [b"admin:".as_slice(), &vec![b'p'; len]].concat();
            let mut text = String::new();
            let table = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
            for chunk in plain.chunks(3) {
                let n = chunk.iter().enumerate().fold(0u32, |n, (i, &b)| n | u32::from(b) << (16 - 8 * i));
                for i in 0..=chunk.len() {
                    text.push(char::from(table[(n >> (18 - 6 * i) & 63) as usize]));
                }
            }
            format!("Basic {text}")
        };
        assert_eq!(read(&encode(MAX_PASSWORD_LEN)).map(|p| p.len()), Some(MAX_PASSWORD_LEN));
        assert_eq!(read(&encode(MAX_PASSWORD_LEN + 1)), None);
    }
}
