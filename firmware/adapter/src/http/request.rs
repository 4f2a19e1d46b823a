//! One HTTP/1.1 request, read and parsed here (no HTTP crate: the API
//! needs a method, a path, three headers and a short body, and a general
//! server cost the NUCLEO image 8 KiB of flash it does not have).
//!
//! What is taken, and what is refused:
//! - The head (request line and header fields, up to and including the
//!   empty line) is at most [`MAX_HEAD_LEN`] bytes: [`Limit::HeadTooLarge`].
//!   Lines end at `\n`, with or without a `\r` before it.
//! - The request line is `METHOD SP TARGET SP HTTP/1.x`; the path is the
//!   target up to its query (`?`) or fragment (`#`).
//! - A header field is `name: value`; the name is compared without case,
//!   the value trimmed of spaces and tabs. A line without a `:`, a name
//!   with white space in it or a folded line (starting with white space)
//!   makes the request bad (400), as RFC 9112 asks.
//! - The body is exactly `Content-Length` bytes (none without one). A
//!   `Content-Length` over [`MAX_BODY_LEN`] is refused at once, before a
//!   byte of the body is read: [`Limit::BodyTooLarge`]. One that is not
//!   digits, two that differ, or a `Transfer-Encoding` (no chunked bodies
//!   here) make the request bad.
//! - Everything must have arrived by the deadline the caller gives.

use core::str;

use embassy_time::{Instant, with_deadline};
use embedded_io_async::Read;

use super::{Error, MAX_BODY_LEN, MAX_HEAD_LEN, REQUEST_BUFFER_LEN};

/// A limit a request broke.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Limit {
    /// The head is over [`MAX_HEAD_LEN`] bytes: 431.
    HeadTooLarge,
    /// A `Content-Length` over [`MAX_BODY_LEN`]: 413.
    BodyTooLarge,
}

/// A request, borrowed from the buffer it was read into.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Request<'b> {
    pub method: &'b str,
    /// The target without its query or fragment, still percent-encoded.
    pub path: &'b str,
    /// The `Authorization` field's value.
    pub authorization: Option<&'b [u8]>,
    /// The `Accept-Encoding` field's value (the last one, if sent twice).
    pub accept_encoding: Option<&'b [u8]>,
    /// The `Host` field's value.
    pub host: Option<&'b [u8]>,
    /// The `Content-Type` field's value.
    pub content_type: Option<&'b [u8]>,
    /// The `Origin` field's value.
    pub origin: Option<&'b [u8]>,
    /// The request line says `HTTP/1.0` (which may leave `Host` out).
    pub http10: bool,
    /// A `Connection` field names `close`: the client wants the connection
    /// closed after this response.
    pub close: bool,
    pub body: &'b [u8],
}

/// The fields a request may carry once only: a second one is a 400, not
/// "the last one wins" (a wrong password then a right one, two hosts, two
/// lengths: which one a proxy on the way read is anyone's guess).
const SINGLE_FIELDS: [&[u8]; 5] = [b"authorization", b"host", b"content-length", b"content-type", b"origin"];

/// What a head says about the body that follows it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Head<'b> {
    request: Request<'b>,
    /// Saturated: only "over the limit" matters past [`MAX_BODY_LEN`].
    content_length: u64,
}

/// A request whose head has been read: the body is still to come, read
/// whole ([`Self::body`]) or streamed ([`Self::stream`]).
#[derive(Debug)]
pub struct Incoming<'b> {
    /// The request, with no body yet.
    pub request: Request<'b>,
    /// The body's length, as `Content-Length` gave it (saturated).
    pub content_length: u64,
    /// The buffer after the head: the body's room.
    rest: &'b mut [u8],
    /// Bytes of the body already read with the head (fewer than [`MAX_BODY_LEN`]).
    have: usize,
}

/// Reads a request's head from `reader` into `buffer` by `deadline`.
///
/// `Ok(None)`: the client closed the connection without sending a byte,
/// or sent none by `idle` (a kept-alive connection's next request; `None`:
/// the first request, which must come by `deadline` or is answered 408).
pub async fn read_head<'b, R: Read>(
    reader: &mut R,
    buffer: &'b mut [u8; REQUEST_BUFFER_LEN],
    idle: Option<Instant>,
    deadline: Instant,
) -> Result<Option<Incoming<'b>>, Error> {
    let mut filled = 0;
    let mut scan = Scan::default();
    let head_len = loop {
        if let Some(end) = scan.run(buffer.get(..filled).unwrap_or_default()) {
            break end;
        }
        let free = buffer.get_mut(filled..MAX_HEAD_LEN).unwrap_or_default();
        if free.is_empty() {
            return Err(Error::Limit(Limit::HeadTooLarge));
        }
        let read = match idle.filter(|_| filled == 0) {
            Some(idle) => match fill(reader, free, idle).await {
                Err(Error::Timeout) => return Ok(None),
                read => read?,
            },
            None => fill(reader, free, deadline).await?,
        };
        match read {
            0 if filled == 0 => return Ok(None),
            0 => return Err(Error::BadRequest),
            n => filled += n,
        }
    };
    let (head_bytes, rest) = buffer.split_at_mut(head_len);
    let Head { request, content_length } = parse(head_bytes)?;
    Ok(Some(Incoming { request, content_length, rest, have: filled - head_len }))
}

impl<'b> Incoming<'b> {
    /// Whether no byte past this request's body was read with its head (a
    /// client that sends its next request before this one's answer: the
    /// connection then closes after the answer, rather than keep bytes
    /// that are not this request's).
    pub fn is_exact(&self) -> bool {
        self.have as u64 <= self.content_length
    }

    /// The request with its whole body: at most [`MAX_BODY_LEN`] bytes
    /// ([`Limit::BodyTooLarge`] otherwise, before a byte more is read).
    pub async fn body<R: Read>(self, reader: &mut R, deadline: Instant) -> Result<Request<'b>, Error> {
        let len = usize::try_from(self.content_length).unwrap_or(usize::MAX);
        if len > MAX_BODY_LEN {
            return Err(Error::Limit(Limit::BodyTooLarge));
        }
        let body = self.rest.get_mut(..len).ok_or(Error::Limit(Limit::BodyTooLarge))?;
        let mut have = self.have;
        while have < body.len() {
            match fill(reader, body.get_mut(have..).unwrap_or_default(), deadline).await? {
                0 => return Err(Error::BadRequest),
                n => have += n,
            }
        }
        Ok(Request { body, ..self.request })
    }

    /// The body as it comes, in chunks of [`CHUNK_LEN`] bytes (the last one
    /// shorter), whatever its length: for a body too large to hold.
    pub fn stream<'i, R: Read>(&'i mut self, reader: &'i mut R, deadline: Instant) -> Stream<'i, R> {
        Stream { reader, room: &mut *self.rest, ready: self.have, left: self.content_length, deadline }
    }
}

/// The chunks a streamed body comes in (the last one shorter): the body's
/// room in the request buffer, which the head never makes smaller.
pub const CHUNK_LEN: usize = MAX_BODY_LEN;

const _: () = assert!(REQUEST_BUFFER_LEN - MAX_HEAD_LEN >= CHUNK_LEN);

/// A body read chunk by chunk ([`Incoming::stream`]).
#[derive(Debug)]
pub struct Stream<'i, R> {
    reader: &'i mut R,
    room: &'i mut [u8],
    /// Bytes at the start of `room` already read (with the head).
    ready: usize,
    /// Bytes of the body not yet given out.
    left: u64,
    deadline: Instant,
}

impl<R: Read> Stream<'_, R> {
    /// Bytes of the body not yet given out.
    pub fn left(&self) -> u64 {
        self.left
    }

    /// The next chunk: `Ok(None)` once the whole body has been given out;
    /// [`Error::BadRequest`] when the connection closes before it.
    pub async fn chunk(&mut self) -> Result<Option<&[u8]>, Error> {
        let len = usize::try_from(self.left).unwrap_or(usize::MAX).min(CHUNK_LEN);
        if len == 0 {
            return Ok(None);
        }
        let chunk = self.room.get_mut(..len).unwrap_or_default();
        let mut have = self.ready.min(len);
        while have < chunk.len() {
            match fill(self.reader, chunk.get_mut(have..).unwrap_or_default(), self.deadline).await? {
                0 => return Err(Error::BadRequest),
                n => have += n,
            }
        }
        self.ready = 0;
        self.left -= chunk.len() as u64;
        Ok(Some(chunk))
    }
}

/// One read by `deadline`.
async fn fill<R: Read>(reader: &mut R, into: &mut [u8], deadline: Instant) -> Result<usize, Error> {
    match with_deadline(deadline, reader.read(into)).await {
        Err(_) => Err(Error::Timeout),
        Ok(Err(e)) => Err(Error::Io(embedded_io_async::Error::kind(&e))),
        Ok(Ok(n)) => Ok(n.min(into.len())),
    }
}

/// Where the search for the head's end stands: bytes already looked at,
/// and where the current line starts.
#[derive(Clone, Copy, Debug, Default)]
struct Scan {
    looked: usize,
    line: usize,
}

impl Scan {
    /// The head's length, once `bytes` hold its empty last line.
    fn run(&mut self, bytes: &[u8]) -> Option<usize> {
        while let Some(&byte) = bytes.get(self.looked) {
            self.looked += 1;
            if byte != b'\n' {
                continue;
            }
            let line = bytes.get(self.line..self.looked - 1).unwrap_or_default();
            // The first line is the request line, even when empty.
            if self.line > 0 && trim_cr(line).is_empty() {
                return Some(self.looked);
            }
            self.line = self.looked;
        }
        None
    }
}

fn trim_cr(line: &[u8]) -> &[u8] {
    line.strip_suffix(b"\r").unwrap_or(line)
}

/// Parses a whole head (ending with its empty line).
fn parse(head: &[u8]) -> Result<Head<'_>, Error> {
    let mut lines = head.split(|&b| b == b'\n').map(trim_cr);
    let (method, path, http10) = request_line(lines.next().unwrap_or_default()).ok_or(Error::BadRequest)?;
    let mut request = Request {
        method,
        path,
        authorization: None,
        accept_encoding: None,
        host: None,
        content_type: None,
        origin: None,
        http10,
        close: false,
        body: &[],
    };
    let mut content_length = None;
    let mut seen = [false; SINGLE_FIELDS.len()];
    for line in lines.take_while(|line| !line.is_empty()) {
        let (name, value) = field(line).ok_or(Error::BadRequest)?;
        if let Some(index) = SINGLE_FIELDS.iter().position(|single| name.eq_ignore_ascii_case(single)) {
            match seen.get_mut(index) {
                Some(seen) if !*seen => *seen = true,
                _ => return Err(Error::BadRequest),
            }
        }
        if name.eq_ignore_ascii_case(b"content-length") {
            content_length = Some(decimal(value).ok_or(Error::BadRequest)?);
        } else if name.eq_ignore_ascii_case(b"transfer-encoding") {
            return Err(Error::BadRequest);
        } else if name.eq_ignore_ascii_case(b"authorization") {
            request.authorization = Some(value);
        } else if name.eq_ignore_ascii_case(b"accept-encoding") {
            request.accept_encoding = Some(value);
        } else if name.eq_ignore_ascii_case(b"host") {
            request.host = Some(value);
        } else if name.eq_ignore_ascii_case(b"content-type") {
            request.content_type = Some(value);
        } else if name.eq_ignore_ascii_case(b"origin") {
            request.origin = Some(value);
        } else if name.eq_ignore_ascii_case(b"connection") {
            request.close |= value.split(|&b| b == b',').any(|token| token.trim_ascii().eq_ignore_ascii_case(b"close"));
        }
    }
    Ok(Head { request, content_length: content_length.unwrap_or(0) })
}

/// `METHOD SP TARGET SP HTTP/1.x`: the method, the path, and whether it is 1.0.
fn request_line(line: &[u8]) -> Option<(&str, &str, bool)> {
    let mut parts = line.split(|&b| b == b' ');
    let (method, target, version) = (parts.next()?, parts.next()?, parts.next()?);
    let tokens = |bytes: &[u8]| !bytes.is_empty() && bytes.iter().all(|&b| b.is_ascii_graphic());
    let known = matches!(version, b"HTTP/1.1" | b"HTTP/1.0");
    if parts.next().is_some() || !tokens(method) || !tokens(target) || !known {
        return None;
    }
    let path = target.split(|&b| b == b'?' || b == b'#').next().unwrap_or_default();
    Some((str::from_utf8(method).ok()?, str::from_utf8(path).ok()?, version == b"HTTP/1.0"))
}

/// `name: value`, the value trimmed of spaces and tabs.
fn field(line: &[u8]) -> Option<(&[u8], &[u8])> {
    let colon = line.iter().position(|&b| b == b':')?;
    let (name, value) = line.split_at(colon);
    if name.is_empty() || name.iter().any(|b| b.is_ascii_whitespace()) {
        return None;
    }
    let value = value.get(1..).unwrap_or_default();
    let blank = |b: &u8| *b == b' ' || *b == b'\t';
    let start = value.iter().position(|b| !blank(b)).unwrap_or(value.len());
    let end = value.iter().rposition(|b| !blank(b)).map_or(start, |last| last + 1);
    Some((name, value.get(start..end).unwrap_or_default()))
}

/// Decimal digits (at least one); saturates, since only "over the limit" matters.
fn decimal(digits: &[u8]) -> Option<u64> {
    if digits.is_empty() {
        return None;
    }
    digits.iter().try_fold(0u64, |value, &digit| {
        digit.is_ascii_digit().then(|| value.saturating_mul(10).saturating_add(u64::from(digit - b'0')))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn head(text: &str) -> Result<Head<'_>, Error> {
        let bytes = text.as_bytes();
        let len = Scan::default().run(bytes).expect("a whole head");
        assert_eq!(len, bytes.len(), "the head ends at its empty line");
        parse(bytes)
    }

    #[test]
    fn a_head_ends_at_its_first_empty_line_after_the_request_line() {
        for (text, end) in [
            ("GET / HTTP/1.1\r\n\r\nbody", Some(18)),
            ("GET / HTTP/1.1\n\nbody", Some(16)),
            ("GET / HTTP/1.1\r\nA: b\r\n\r\n", Some(24)),
            ("\r\n\r\n", Some(4)),
            ("GET / HTTP/1.1\r\nA: b\r\n", None),
            ("GET / HTTP/1.1\r\n\r", None),
        ] {
            assert_eq!(Scan::default().run(text.as_bytes()), end, "{text:?}");
        }
        // Fed a byte at a time: the same end.
        let text = b"PUT /api/settings HTTP/1.1\r\nContent-Length: 2\r\n\r\n{}";
        let mut scan = Scan::default();
        let ends: Vec<_> = (0..=text.len()).filter_map(|n| scan.run(&text[..n])).collect();
        assert_eq!(ends.first(), Some(&(text.len() - 2)));
    }

    #[test]
    fn the_request_line_gives_the_method_and_the_path() {
        let parsed = head("GET /api/status?x=1#y HTTP/1.0\r\n\r\n").unwrap().request;
        assert_eq!((parsed.method, parsed.path), ("GET", "/api/status"));
        for bad in [
            "\r\n\r\n",
            "GET\r\n\r\n",
            "GET /\r\n\r\n",
            "GET / HTTP/2\r\n\r\n",
            "GET  / HTTP/1.1\r\n\r\n",
            "GET / HTTP/1.1 x\r\n\r\n",
            "G\u{e9}T / HTTP/1.1\r\n\r\n",
        ] {
            assert_eq!(head(bad), Err(Error::BadRequest), "{bad:?}");
        }
    }

    #[test]
    fn a_field_that_may_come_once_and_comes_twice_is_a_bad_request() {
        for name in ["Authorization", "Host", "Content-Length", "Content-Type", "Origin"] {
            let once = format!("PUT /x HTTP/1.1\r\n{name}: 1\r\nX-Other: 2\r\n\r\n");
            assert!(head(&once).is_ok(), "{name} once");
            // Twice, the second in other capitals, with the same or another value.
            for second in ["1", "2"] {
                let twice = format!("PUT /x HTTP/1.1\r\n{name}: 1\r\n{}: {second}\r\n\r\n", name.to_uppercase());
                assert_eq!(head(&twice), Err(Error::BadRequest), "{twice:?}");
            }
        }
        let parsed = head(
            "GET / HTTP/1.1\r\nHost: 10.0.0.1:80\r\nOrigin: http://10.0.0.1\r\nContent-Type: application/json\r\n\r\n",
        )
        .unwrap()
        .request;
        assert_eq!(parsed.host, Some(&b"10.0.0.1:80"[..]));
        assert_eq!(parsed.origin, Some(&b"http://10.0.0.1"[..]));
        assert_eq!(parsed.content_type, Some(&b"application/json"[..]));
        // Fields a client may repeat are still taken: the last one.
        let accept = head("GET / HTTP/1.1\r\nAccept-Encoding: br\r\nAccept-Encoding: gzip\r\n\r\n").unwrap();
        assert_eq!(accept.request.accept_encoding, Some(&b"gzip"[..]));
    }

    #[test]
    fn header_fields_are_read_without_case_and_trimmed() {
        let text =
            "PUT /x HTTP/1.1\r\nauthorization:  Basic abc \t\r\nACCEPT-ENCODING: gzip\r\nContent-length: 12\r\n\r\n";
        let parsed = head(text).unwrap();
        assert_eq!(parsed.request.authorization, Some(&b"Basic abc"[..]));
        assert_eq!(parsed.request.accept_encoding, Some(&b"gzip"[..]));
        assert_eq!(parsed.content_length, 12);
        assert_eq!(head("GET / HTTP/1.1\r\nX-Empty:\r\n\r\n").map(|h| h.content_length), Ok(0));
        for bad in [
            "GET / HTTP/1.1\r\nno colon\r\n\r\n",
            "GET / HTTP/1.1\r\n: no name\r\n\r\n",
            "GET / HTTP/1.1\r\nName : space before the colon\r\n\r\n",
            "GET / HTTP/1.1\r\nA: b\r\n folded\r\n\r\n",
            "PUT / HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\n",
        ] {
            assert_eq!(head(bad), Err(Error::BadRequest), "{bad:?}");
        }
    }

    #[test]
    fn content_length_is_digits_and_saturates() {
        let length =
            |value: &str| head(&format!("PUT / HTTP/1.1\r\nContent-Length: {value}\r\n\r\n")).map(|h| h.content_length);
        assert_eq!(length("0"), Ok(0));
        assert_eq!(length("1025"), Ok(1025));
        assert_eq!(length("18446744073709551616"), Ok(u64::MAX));
        assert_eq!(length(&"9".repeat(100)), Ok(u64::MAX));
        for bad in ["", "+1", "-1", "1 2", "0x10", "1.0"] {
            assert_eq!(length(bad), Err(Error::BadRequest), "{bad:?}");
        }
        let twice = "PUT / HTTP/1.1\r\nContent-Length: 2\r\nContent-Length: 2\r\n\r\n";
        assert_eq!(head(twice), Err(Error::BadRequest), "even the same length twice");
        let differ = "PUT / HTTP/1.1\r\nContent-Length: 2\r\nContent-Length: 3\r\n\r\n";
        assert_eq!(head(differ), Err(Error::BadRequest));
    }

    /// Reads `bytes` as one client would send them, `size` bytes a read.
    struct Client<'a> {
        bytes: &'a [u8],
        size: usize,
    }

    impl embedded_io_async::ErrorType for Client<'_> {
        type Error = embedded_io_async::ErrorKind;
    }

    impl Read for Client<'_> {
        async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
            let n = buf.len().min(self.size).min(self.bytes.len());
            let (now, later) = self.bytes.split_at(n);
            buf[..n].copy_from_slice(now);
            self.bytes = later;
            Ok(n)
        }
    }

    /// A request read head, then body, as `serve` reads one.
    async fn read<'b, R: Read>(
        reader: &mut R,
        buffer: &'b mut [u8; REQUEST_BUFFER_LEN],
        deadline: Instant,
    ) -> Result<Option<Request<'b>>, Error> {
        match read_head(reader, buffer, None, deadline).await? {
            Some(incoming) => incoming.body(reader, deadline).await.map(Some),
            None => Ok(None),
        }
    }

    fn far() -> Instant {
        Instant::now() + embassy_time::Duration::from_secs(60)
    }

    #[test]
    fn a_body_is_read_whole_within_its_limit() {
        let _clock = crate::server::testing::Clock::take();
        for size in [1, 7, 64, 4096] {
            let text = b"PUT /x HTTP/1.1\r\nContent-Length: 5\r\n\r\nhello, and more";
            let mut buffer = [0; REQUEST_BUFFER_LEN];
            let mut client = Client { bytes: text, size };
            let got = embassy_futures::block_on(read(&mut client, &mut buffer, far()));
            assert_eq!(got.map(|r| r.map(|r| r.body)), Ok(Some(&b"hello"[..])), "size {size}");
        }
        let over = format!("PUT /x HTTP/1.1\r\nContent-Length: {}\r\n\r\n", MAX_BODY_LEN + 1);
        let mut buffer = [0; REQUEST_BUFFER_LEN];
        let mut client = Client { bytes: over.as_bytes(), size: 4096 };
        let got = embassy_futures::block_on(read(&mut client, &mut buffer, far()));
        assert_eq!(got, Err(Error::Limit(Limit::BodyTooLarge)));
        let mut client = Client { bytes: b"PUT /x HTTP/1.1\r\nContent-Length: 5\r\n\r\nhel", size: 4096 };
        let got = embassy_futures::block_on(read(&mut client, &mut buffer, far()));
        assert_eq!(got, Err(Error::BadRequest), "cut off");
    }

    #[test]
    fn a_streamed_body_comes_in_whole_chunks_whatever_the_reads() {
        let _clock = crate::server::testing::Clock::take();
        let body: Vec<u8> = (0..3 * CHUNK_LEN + 17).map(|i| (i % 251) as u8).collect();
        for (size, extra) in [(1, 0), (3, 5), (100, 0), (1500, 9), (8192, 0)] {
            let mut bytes = format!("POST /f HTTP/1.1\r\nContent-Length: {}\r\n\r\n", body.len()).into_bytes();
            bytes.extend_from_slice(&body);
            bytes.extend(std::iter::repeat_n(0xee, extra));
            let mut client = Client { bytes: &bytes, size };
            let mut buffer = [0; REQUEST_BUFFER_LEN];
            let mut incoming =
                embassy_futures::block_on(read_head(&mut client, &mut buffer, None, far())).unwrap().unwrap();
            assert_eq!(incoming.content_length, body.len() as u64);
            let mut stream = incoming.stream(&mut client, far());
            let mut got = Vec::new();
            let mut lens = Vec::new();
            while let Some(chunk) = embassy_futures::block_on(stream.chunk()).unwrap() {
                lens.push(chunk.len());
                got.extend_from_slice(chunk);
            }
            assert_eq!(got, body, "size {size}");
            assert_eq!(lens, [CHUNK_LEN, CHUNK_LEN, CHUNK_LEN, 17], "size {size}");
            assert_eq!(stream.left(), 0);
        }
        // Cut off anywhere: an error, never a short body taken as whole.
        let mut bytes = format!("POST /f HTTP/1.1\r\nContent-Length: {}\r\n\r\n", body.len()).into_bytes();
        let head_len = bytes.len();
        bytes.extend_from_slice(&body);
        for cut in (head_len..bytes.len()).step_by(97) {
            let mut client = Client { bytes: &bytes[..cut], size: 700 };
            let mut buffer = [0; REQUEST_BUFFER_LEN];
            let mut incoming =
                embassy_futures::block_on(read_head(&mut client, &mut buffer, None, far())).unwrap().unwrap();
            let mut stream = incoming.stream(&mut client, far());
            let end = loop {
                match embassy_futures::block_on(stream.chunk()) {
                    Ok(Some(_)) => {}
                    other => break other.map(|chunk| chunk.is_some()),
                }
            };
            assert_eq!(end, Err(Error::BadRequest), "cut at {cut}");
        }
    }
}
