//! Writing one response: its status line, the few header fields the API
//! sends, and its body, all by [`WRITE_TIMEOUT`] after the first byte.
//! A response ends its connection (`Connection: close`) unless it is kept
//! alive (HTTPS).

use embassy_time::{Instant, with_deadline};
use embedded_io_async::{ErrorKind, Write};

use super::json::Out;
use super::{Error, WRITE_TIMEOUT};

/// A response status: its code and reason phrase.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Status {
    pub code: u16,
    reason: &'static str,
}

impl Status {
    pub const OK: Self = Self::new(200, "OK");
    pub const ACCEPTED: Self = Self::new(202, "Accepted");
    pub const PERMANENT_REDIRECT: Self = Self::new(308, "Permanent Redirect");
    pub const BAD_REQUEST: Self = Self::new(400, "Bad Request");
    pub const UNAUTHORIZED: Self = Self::new(401, "Unauthorized");
    pub const FORBIDDEN: Self = Self::new(403, "Forbidden");
    pub const NOT_FOUND: Self = Self::new(404, "Not Found");
    pub const METHOD_NOT_ALLOWED: Self = Self::new(405, "Method Not Allowed");
    pub const NOT_ACCEPTABLE: Self = Self::new(406, "Not Acceptable");
    pub const UNSUPPORTED_MEDIA_TYPE: Self = Self::new(415, "Unsupported Media Type");
    pub const MISDIRECTED_REQUEST: Self = Self::new(421, "Misdirected Request");
    pub const REQUEST_TIMEOUT: Self = Self::new(408, "Request Timeout");
    pub const CONTENT_TOO_LARGE: Self = Self::new(413, "Content Too Large");
    pub const HEADER_FIELDS_TOO_LARGE: Self = Self::new(431, "Request Header Fields Too Large");
    pub const INTERNAL_SERVER_ERROR: Self = Self::new(500, "Internal Server Error");
    pub const NOT_IMPLEMENTED: Self = Self::new(501, "Not Implemented");

    const fn new(code: u16, reason: &'static str) -> Self {
        Self { code, reason }
    }
}

/// A response: its status, what its body is, one more header field
/// (`Allow`, `WWW-Authenticate`, `Content-Encoding`) when it needs one, a
/// redirect's `Location`, and whether the connection stays open after it.
#[derive(Clone, Copy, Debug)]
pub struct Response<'a> {
    pub status: Status,
    pub content_type: &'static str,
    pub header: Option<(&'static str, &'static str)>,
    pub location: Option<&'a [u8]>,
    pub body: &'a [u8],
    pub keep_alive: bool,
}

/// The fields every response carries that a browser honours: no framing
/// (no clickjacking of the page's buttons), no guessing at content types,
/// no `Referer` to other sites, and the page's content security policy.
const SECURITY_FIELDS: [(&str, &str); 4] = [
    ("X-Frame-Options", "DENY"),
    ("X-Content-Type-Options", "nosniff"),
    ("Referrer-Policy", "no-referrer"),
    ("Content-Security-Policy", super::page::CONTENT_SECURITY_POLICY),
];

/// Room for the longest head: the status line and the fields, the longest
/// reason phrase and extra field included, the security fields, and a
/// `Location` (`https://`, a host of at most the head's length, a port, a path).
pub const RESPONSE_HEAD_LEN: usize = 256 + 64 + super::page::CONTENT_SECURITY_POLICY.len() + 32 + super::MAX_HEAD_LEN;

/// Writes `response` to `writer`, whole by [`WRITE_TIMEOUT`] from now; its
/// head is formatted in `head` (at least [`RESPONSE_HEAD_LEN`] bytes: the
/// request's buffer, done with by then).
pub async fn write<W: Write>(writer: &mut W, response: &Response<'_>, head: &mut [u8]) -> Result<(), Error> {
    let mut out = Out::new(head);
    out.text("HTTP/1.1 ");
    out.number(response.status.code);
    out.text(" ");
    out.text(response.status.reason);
    out.text("\r\nContent-Type: ");
    out.text(response.content_type);
    out.text("\r\nContent-Length: ");
    out.number(response.body.len());
    out.text("\r\nCache-Control: no-store\r\n");
    if !response.keep_alive {
        out.text("Connection: close\r\n");
    }
    if let Some(location) = response.location {
        out.text("Location: ");
        out.text(core::str::from_utf8(location).unwrap_or_default());
        out.text("\r\n");
    }
    for (name, value) in SECURITY_FIELDS.into_iter().chain(response.header) {
        out.text(name);
        out.text(": ");
        out.text(value);
        out.text("\r\n");
    }
    out.text("\r\n");
    let deadline = Instant::now() + WRITE_TIMEOUT;
    let sent = async {
        write_all(writer, out.as_bytes()).await?;
        write_all(writer, response.body).await?;
        writer.flush().await.map_err(|e| Error::Io(embedded_io_async::Error::kind(&e)))
    };
    with_deadline(deadline, sent).await.unwrap_or(Err(Error::Timeout))
}

/// Every byte of `bytes` (embedded-io-async's own `write_all` panics on a
/// write of 0 bytes: here it is an error).
async fn write_all<W: Write>(writer: &mut W, mut bytes: &[u8]) -> Result<(), Error> {
    while !bytes.is_empty() {
        match writer.write(bytes).await {
            Ok(0) => return Err(Error::Io(ErrorKind::WriteZero)),
            Ok(n) => bytes = bytes.get(n..).unwrap_or_default(),
            Err(e) => return Err(Error::Io(embedded_io_async::Error::kind(&e))),
        }
    }
    Ok(())
}
