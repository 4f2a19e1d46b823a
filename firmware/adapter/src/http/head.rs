//! The request head, watched byte by byte as it is read, before picoserve
//! parses it: the limits the API promises are enforced here, once.
//!
//! - The head (request line and header fields, up to and including the
//!   empty line) is at most [`MAX_HEAD_LEN`] bytes: [`Limit::HeadTooLarge`].
//! - A `Content-Length` over [`MAX_BODY_LEN`]: [`Limit::BodyTooLarge`],
//!   known before a byte of the body is read.
//!
//! The second is also what keeps picoserve 0.20.1 safe: its reader adds the
//! `Content-Length` it parsed to a buffer offset unchecked
//! (`self.read_position += content_length` in `request.rs`), which panics
//! on overflow in a build with overflow checks (tests, fuzzing) and wraps
//! in one without. Every value it could take to overflow is far over
//! [`MAX_BODY_LEN`], so it never sees one.
//!
//! To never let a value through that picoserve would read otherwise, the
//! scanner reads the head exactly as picoserve does: lines end at `\n`; the
//! first line is the request line; the head ends at the first later line
//! made only of ASCII whitespace (empty, or `\r`); a header's name is what
//! precedes its first `:`, trimmed of ASCII whitespace and compared without
//! case; its value is the rest, trimmed, parsed as Rust parses a `usize`
//! (an optional `+`, then digits); NUL bytes are removed before a header is
//! parsed (so `Content-Le\0ngth` is `Content-Length`). Every
//! `Content-Length` is checked, not only the first picoserve uses.

use super::{MAX_BODY_LEN, MAX_HEAD_LEN};

/// A limit a request broke.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Limit {
    /// The head is over [`MAX_HEAD_LEN`] bytes: 431.
    HeadTooLarge,
    /// A `Content-Length` over [`MAX_BODY_LEN`]: 413.
    BodyTooLarge,
}

const CONTENT_LENGTH: &[u8] = b"content-length";

/// Where the scan is within a header line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Field {
    /// The request line, or a header that is not `Content-Length`: nothing to watch.
    Other,
    /// Before the `:`: how much of `content-length` the name has matched,
    /// whether it has started and whether trailing whitespace began.
    Name { matched: usize, started: bool, trailing: bool, failed: bool },
    /// A `Content-Length` value.
    Value(Number),
}

/// A `Content-Length` value, as `usize::from_str` takes it after trimming.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Number {
    /// Leading whitespace.
    Before,
    /// After a `+`.
    Sign,
    /// Digits so far (saturating: only "over the limit" matters).
    Digits(u64),
    /// Digits, then whitespace.
    After(u64),
    /// Not a number: picoserve reads it as no body.
    Invalid,
}

impl Number {
    fn push(self, byte: u8) -> Self {
        let digit = byte.is_ascii_digit().then(|| u64::from(byte - b'0'));
        let space = byte.is_ascii_whitespace();
        match (self, digit) {
            (Self::Before, _) if space => Self::Before,
            (Self::Before, None) if byte == b'+' => Self::Sign,
            (Self::Before | Self::Sign, Some(d)) => Self::Digits(d),
            (Self::Digits(n), Some(d)) => Self::Digits(n.saturating_mul(10).saturating_add(d)),
            (Self::Digits(n) | Self::After(n), None) if space => Self::After(n),
            _ => Self::Invalid,
        }
    }

    fn value(self) -> Option<u64> {
        match self {
            Self::Digits(n) | Self::After(n) => Some(n),
            _ => None,
        }
    }
}

/// Watches a request's head go by.
#[derive(Clone, Debug)]
pub struct Head {
    /// Bytes of the head seen so far.
    len: usize,
    /// Lines ended so far (0: in the request line).
    lines: usize,
    /// The current line holds only ASCII whitespace so far.
    blank: bool,
    field: Field,
    /// The empty line came: the rest is the body.
    done: bool,
    /// A limit was broken: every later scan says so again.
    broken: Option<Limit>,
}

impl Default for Head {
    fn default() -> Self {
        Self::new()
    }
}

impl Head {
    pub const fn new() -> Self {
        Self { len: 0, lines: 0, blank: true, field: Field::Other, done: false, broken: None }
    }

    /// Whether the whole head has gone by.
    pub fn done(&self) -> bool {
        self.done
    }

    /// Watches the next `bytes` of the stream.
    pub fn scan(&mut self, bytes: &[u8]) -> Result<(), Limit> {
        if let Some(limit) = self.broken {
            return Err(limit);
        }
        for &byte in bytes {
            if self.done {
                break;
            }
            self.len += 1;
            if self.len > MAX_HEAD_LEN {
                self.broken = Some(Limit::HeadTooLarge);
                return Err(Limit::HeadTooLarge);
            }
            if let Err(limit) = self.byte(byte) {
                self.broken = Some(limit);
                return Err(limit);
            }
        }
        Ok(())
    }

    fn byte(&mut self, byte: u8) -> Result<(), Limit> {
        if byte == b'\n' {
            return self.end_line();
        }
        self.blank &= byte.is_ascii_whitespace();
        if byte == 0 {
            // Removed by picoserve before it parses the header.
            return Ok(());
        }
        self.field = match self.field {
            Field::Other => Field::Other,
            Field::Name { matched, failed, .. } if byte == b':' => {
                if !failed && matched == CONTENT_LENGTH.len() {
                    Field::Value(Number::Before)
                } else {
                    Field::Other
                }
            }
            Field::Name { matched, started, trailing, failed } => {
                let space = byte.is_ascii_whitespace();
                let next = CONTENT_LENGTH.get(matched).copied();
                match (started, trailing) {
                    (false, _) if space => Field::Name { matched, started, trailing, failed },
                    (_, false) if !space && next == Some(byte.to_ascii_lowercase()) => {
                        Field::Name { matched: matched + 1, started: true, trailing, failed }
                    }
                    (true, _) if space => Field::Name { matched, started, trailing: true, failed },
                    _ => Field::Name { matched, started: true, trailing, failed: true },
                }
            }
            Field::Value(number) => Field::Value(number.push(byte)),
        };
        Ok(())
    }

    fn end_line(&mut self) -> Result<(), Limit> {
        if self.lines > 0 && self.blank {
            self.done = true;
            return Ok(());
        }
        if let Field::Value(number) = self.field
            && number.value().is_some_and(|n| n > MAX_BODY_LEN as u64)
        {
            return Err(Limit::BodyTooLarge);
        }
        self.lines += 1;
        self.blank = true;
        self.field = Field::Name { matched: 0, started: false, trailing: false, failed: false };
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan(head: &[u8]) -> (Result<(), Limit>, bool) {
        let mut scanner = Head::new();
        let result = scanner.scan(head);
        (result, scanner.done())
    }

    #[test]
    fn a_head_ends_at_its_first_blank_line() {
        assert_eq!(scan(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n"), (Ok(()), true));
        assert_eq!(scan(b"GET / HTTP/1.1\nHost: x\n\n"), (Ok(()), true));
        assert_eq!(scan(b"GET / HTTP/1.1\r\nHost: x\r\n \t\r\n"), (Ok(()), true), "whitespace only");
        assert_eq!(scan(b"\r\n\r\n"), (Ok(()), true), "the request line is never the end");
        assert_eq!(scan(b"\r\n"), (Ok(()), false));
        assert_eq!(scan(b"GET / HTTP/1.1\r\nHost: x\r\n\0\r\n"), (Ok(()), false), "NUL is not whitespace");
        assert_eq!(scan(b"GET / HTTP/1.1\r\nHost: x\r\n"), (Ok(()), false));
    }

    #[test]
    fn the_head_has_a_limit() {
        let mut head = b"GET / HTTP/1.1\r\nX: ".to_vec();
        head.resize(MAX_HEAD_LEN - 4, b'a');
        head.extend(b"\r\n\r\n");
        assert_eq!(head.len(), MAX_HEAD_LEN);
        assert_eq!(scan(&head), (Ok(()), true));
        let mut over = head.clone();
        over.insert(20, b'a');
        assert_eq!(scan(&over).0, Err(Limit::HeadTooLarge));
        // Bytes after the head are the body: not counted.
        head.extend([b'x'; 5000]);
        assert_eq!(scan(&head), (Ok(()), true));
        // Byte by byte, the same; and once broken, always broken.
        let mut scanner = Head::new();
        let results: Vec<_> = over.iter().map(|b| scanner.scan(&[*b])).collect();
        assert_eq!(results.iter().filter(|r| r.is_err()).count(), 1, "the last byte breaks it");
        assert_eq!(scanner.scan(b""), Err(Limit::HeadTooLarge));
    }

    #[test]
    fn content_lengths_over_the_body_limit_are_refused_as_picoserve_reads_them() {
        let head = |field: &str| format!("PUT /api/settings HTTP/1.1\r\n{field}\r\n\r\n");
        let over = MAX_BODY_LEN + 1;
        for field in [
            format!("Content-Length: {over}"),
            format!("content-length:{over}"),
            format!("  CONTENT-LENGTH  :  {over}  "),
            format!("Content-Length: +{over}"),
            format!("Content-Length: 0{over}"),
            "Content-Length: 18446744073709551615".to_string(),
            "Content-Length: 99999999999999999999999999".to_string(),
            format!("Content-Le\0ngth: 1\0{over}"),
            format!("Content-Length:\t{over}\r"),
        ] {
            assert_eq!(scan(head(&field).as_bytes()).0, Err(Limit::BodyTooLarge), "{field:?}");
        }
        let max = MAX_BODY_LEN;
        for field in [
            format!("Content-Length: {max}"),
            "Content-Length: 0".to_string(),
            // picoserve reads these as no body at all.
            format!("Content-Length: -{over}"),
            format!("Content-Length: {over}x"),
            format!("Content-Length: {over} 1"),
            format!("Content-Length: ++{over}"),
            format!("Content-Length: 1{over}\x0b"),
            // Not the Content-Length header.
            format!("Content-Lengths: {over}"),
            format!("Content Length: {over}"),
            format!("X-Content-Length: {over}"),
            format!("Content-Type: {over}"),
        ] {
            assert_eq!(scan(head(&field).as_bytes()), (Ok(()), true), "{field:?}");
        }
        // The request line is no header, whatever it holds.
        assert_eq!(scan(format!("Content-Length: {over}\r\n\r\n").as_bytes()), (Ok(()), true));
    }

    #[test]
    fn every_split_gives_the_same_verdict() {
        let heads: [&[u8]; 3] = [
            b"PUT / HTTP/1.1\r\nContent-Length: 99999\r\n\r\n",
            b"PUT / HTTP/1.1\r\nContent-Length: 12\r\n\r\n{}",
            b"GET / HTTP/1.1\r\n\r\n",
        ];
        for head in heads {
            let whole = scan(head);
            for cut in 0..head.len() {
                let mut scanner = Head::new();
                let first = scanner.scan(&head[..cut]);
                let result = first.and_then(|()| scanner.scan(&head[cut..]));
                assert_eq!((result, scanner.done()), whole, "{head:?} cut at {cut}");
            }
        }
    }
}
