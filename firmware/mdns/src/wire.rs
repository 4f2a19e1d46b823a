//! DNS messages as Multicast DNS carries them: the header, questions and
//! names of a query (RFC 1035 section 4.1, RFC 6762 section 18), read by
//! length, and a writer for the response.
//!
//! ```text
//! | id (2) | flags (2) | questions (2) | answers (2) | authority (2) | additional (2) | sections ... |
//! ```
//!
//! Contract (smoltcp's): [`Message::new_checked`] takes any bytes, and once
//! it succeeds no accessor panics; [`Message::questions`] reads each
//! question by its length, follows compression pointers only backwards
//! (before the run of labels they end) and at most [`MAX_POINTER_HOPS`]
//! times, and stops at the first error. The
//! [`Writer`] never writes past its buffer: it counts what it could not
//! write, so one pass measures a response and the next writes it.

use core::fmt;

/// The header's fields.
mod field {
    use core::ops::Range;
    pub const ID: Range<usize> = 0..2;
    pub const FLAGS: Range<usize> = 2..4;
    pub const QUESTIONS: Range<usize> = 4..6;
    pub const ANSWERS: Range<usize> = 6..8;
    pub const ADDITIONAL: Range<usize> = 10..12;
}

/// Bytes of the header.
pub const HEADER_LEN: usize = 12;
/// Longest name on the wire, length bytes included (RFC 1035 section 3.1).
pub const MAX_NAME_LEN: usize = 255;
/// Longest label (RFC 1035 section 3.1).
pub const MAX_LABEL_LEN: usize = 63;
/// Compression pointers followed in one name. Each pointer must point
/// before the first label of the run it ends, so a name can never loop;
/// this bounds the work a hostile chain of pointers costs.
pub const MAX_POINTER_HOPS: usize = 16;

/// Header flags (RFC 1035 section 4.1.1).
pub mod flags {
    /// A response (clear: a query).
    pub const RESPONSE: u16 = 1 << 15;
    /// The operation code, 4 bits: 0 is a standard query.
    pub const OPCODE: u16 = 0xf << 11;
    /// An authoritative answer: every mDNS response sets it (RFC 6762 section 18.4).
    pub const AUTHORITATIVE: u16 = 1 << 10;
    /// The response code, 4 bits.
    pub const RCODE: u16 = 0xf;
}

/// Record types (RFC 1035 section 3.2.2, RFC 3596, RFC 2782, RFC 4034).
pub mod rtype {
    pub const A: u16 = 1;
    pub const PTR: u16 = 12;
    pub const TXT: u16 = 16;
    pub const AAAA: u16 = 28;
    pub const SRV: u16 = 33;
    pub const NSEC: u16 = 47;
    /// A question for every type (`*`).
    pub const ANY: u16 = 255;
}

/// Classes (RFC 1035 section 3.2.4).
pub mod class {
    pub const IN: u16 = 1;
    pub const ANY: u16 = 255;
    /// The top bit of a question's class: the querier takes a unicast
    /// response (RFC 6762 section 5.4); of a record's: cache flush (section 10.2).
    pub const TOP_BIT: u16 = 1 << 15;
}

/// Why a message could not be read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// Shorter than its header, or a question runs past the end.
    Truncated,
    /// A label length with the reserved top bits 01 or 10.
    BadLabel,
    /// A name longer than [`MAX_NAME_LEN`].
    NameTooLong,
    /// A compression pointer that does not point backwards, or one too many.
    BadPointer,
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Truncated => "message truncated",
            Self::BadLabel => "reserved label type",
            Self::NameTooLong => "name longer than 255 bytes",
            Self::BadPointer => "compression pointer not backwards or too many",
        })
    }
}

impl core::error::Error for Error {}

fn u16_at(bytes: &[u8], at: usize) -> Option<u16> {
    let end = at.checked_add(2)?;
    match bytes.get(at..end)? {
        [a, b] => Some(u16::from_be_bytes([*a, *b])),
        _ => None,
    }
}

fn header_u16(bytes: &[u8], range: core::ops::Range<usize>) -> u16 {
    u16_at(bytes, range.start).unwrap_or(0)
}

/// A DNS message over `T`'s bytes.
#[derive(Clone, Copy, Debug)]
pub struct Message<T: AsRef<[u8]>> {
    buffer: T,
}

impl<T: AsRef<[u8]>> Message<T> {
    /// The message, if it holds at least a header.
    pub fn new_checked(buffer: T) -> Result<Self, Error> {
        if buffer.as_ref().len() < HEADER_LEN {
            return Err(Error::Truncated);
        }
        Ok(Self { buffer })
    }

    pub fn id(&self) -> u16 {
        header_u16(self.buffer.as_ref(), field::ID)
    }

    pub fn flags(&self) -> u16 {
        header_u16(self.buffer.as_ref(), field::FLAGS)
    }

    /// A standard query (not a response, opcode 0).
    pub fn is_query(&self) -> bool {
        self.flags() & (flags::RESPONSE | flags::OPCODE) == 0
    }

    pub fn question_count(&self) -> u16 {
        header_u16(self.buffer.as_ref(), field::QUESTIONS)
    }

    pub fn answer_count(&self) -> u16 {
        header_u16(self.buffer.as_ref(), field::ANSWERS)
    }

    pub fn additional_count(&self) -> u16 {
        header_u16(self.buffer.as_ref(), field::ADDITIONAL)
    }

    /// The questions, in order; an error ends them.
    pub fn questions(&self) -> Questions<'_> {
        Questions { message: self.buffer.as_ref(), at: HEADER_LEN, left: self.question_count() }
    }
}

/// One question (RFC 1035 section 4.1.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Question<'a> {
    pub name: Name<'a>,
    pub qtype: u16,
    /// The class without its top bit.
    pub class: u16,
    /// The top bit of the class: a unicast response is welcome (QU).
    pub unicast_response: bool,
}

/// The questions of a message (see [`Message::questions`]).
#[derive(Clone, Debug)]
pub struct Questions<'a> {
    message: &'a [u8],
    at: usize,
    left: u16,
}

impl<'a> Iterator for Questions<'a> {
    type Item = Result<Question<'a>, Error>;

    fn next(&mut self) -> Option<Self::Item> {
        self.left = self.left.checked_sub(1)?;
        let read = (|| {
            let (name, end) = Name::read(self.message, self.at)?;
            let qtype = u16_at(self.message, end).ok_or(Error::Truncated)?;
            let class = u16_at(self.message, end + 2).ok_or(Error::Truncated)?;
            self.at = end + 4;
            Ok(Question { name, qtype, class: class & !class::TOP_BIT, unicast_response: class & class::TOP_BIT != 0 })
        })();
        if read.is_err() {
            // Nothing after a bad question can be found.
            self.left = 0;
        }
        Some(read)
    }
}

/// One step through a name: a label, the end, or a pointer.
enum Step<'a> {
    Label(&'a [u8], usize),
    End(usize),
    Pointer(usize, usize),
}

fn step(message: &[u8], at: usize) -> Result<Step<'_>, Error> {
    let len = *message.get(at).ok_or(Error::Truncated)?;
    match len >> 6 {
        0 if len == 0 => Ok(Step::End(at + 1)),
        0 => {
            let start = at + 1;
            let end = start + usize::from(len);
            let label = message.get(start..end).ok_or(Error::Truncated)?;
            Ok(Step::Label(label, end))
        }
        0b11 => {
            let low = *message.get(at + 1).ok_or(Error::Truncated)?;
            let target = usize::from(u16::from_be_bytes([len & 0x3f, low]));
            Ok(Step::Pointer(target, at + 2))
        }
        _ => Err(Error::BadLabel),
    }
}

/// A name in a message, checked whole when it was read: its labels follow
/// from `start`, through compression pointers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Name<'a> {
    message: &'a [u8],
    start: usize,
}

impl<'a> Name<'a> {
    /// Reads and checks the name at `at`: returns it and where the bytes
    /// after it (in place, not through a pointer) begin.
    pub fn read(message: &'a [u8], at: usize) -> Result<(Self, usize), Error> {
        let mut pos = at;
        // Where the run of labels being read began.
        let mut run = at;
        // Where the name ends in place: after its end byte or its first pointer.
        let mut end = None;
        let mut hops = 0;
        // Bytes on the wire the name would take uncompressed (its end byte included).
        let mut len = 1;
        loop {
            match step(message, pos)? {
                Step::Label(label, next) => {
                    len += 1 + label.len();
                    if len > MAX_NAME_LEN {
                        return Err(Error::NameTooLong);
                    }
                    pos = next;
                }
                Step::End(next) => {
                    return Ok((Self { message, start: at }, end.unwrap_or(next)));
                }
                Step::Pointer(target, next) => {
                    hops += 1;
                    if target >= run || hops > MAX_POINTER_HOPS {
                        return Err(Error::BadPointer);
                    }
                    end = end.or(Some(next));
                    pos = target;
                    run = target;
                }
            }
        }
    }

    /// The labels, first to last (the empty root label not included).
    pub fn labels(&self) -> Labels<'a> {
        Labels { message: self.message, at: self.start, run: self.start, hops: 0 }
    }

    /// Whether the labels are `expected`'s, ASCII case ignored (RFC 6762 section 16).
    pub fn is(&self, expected: &[&[u8]]) -> bool {
        let mut labels = self.labels();
        for want in expected {
            match labels.next() {
                Some(label) if label.eq_ignore_ascii_case(want) => {}
                _ => return false,
            }
        }
        labels.next().is_none()
    }
}

/// The labels of a [`Name`].
#[derive(Clone, Debug)]
pub struct Labels<'a> {
    message: &'a [u8],
    at: usize,
    run: usize,
    hops: usize,
}

impl<'a> Iterator for Labels<'a> {
    type Item = &'a [u8];

    fn next(&mut self) -> Option<&'a [u8]> {
        // The name was checked when it was read; this stays defensive anyway.
        loop {
            match step(self.message, self.at).ok()? {
                Step::Label(label, next) => {
                    self.at = next;
                    return Some(label);
                }
                Step::End(_) => return None,
                Step::Pointer(target, _) => {
                    self.hops += 1;
                    if target >= self.run || self.hops > MAX_POINTER_HOPS {
                        return None;
                    }
                    self.at = target;
                    self.run = target;
                }
            }
        }
    }
}

/// A compression pointer to `offset` (RFC 1035 section 4.1.4), if the
/// offset fits its 14 bits.
pub fn pointer(offset: usize) -> Option<[u8; 2]> {
    let offset = u16::try_from(offset).ok().filter(|offset| *offset < 0x4000)?;
    Some((0xc000 | offset).to_be_bytes())
}

/// Writes a message into a buffer, and counts: what does not fit is not
/// written, but [`Writer::len`] still grows, so a pass over an empty buffer
/// measures the message.
#[derive(Debug)]
pub struct Writer<'a> {
    buffer: &'a mut [u8],
    len: usize,
}

impl<'a> Writer<'a> {
    pub fn new(buffer: &'a mut [u8]) -> Self {
        Self { buffer, len: 0 }
    }

    /// Bytes written, or that would have been.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether nothing was written.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Whether everything fitted.
    pub fn fits(&self) -> bool {
        self.len <= self.buffer.len()
    }

    pub fn put(&mut self, bytes: &[u8]) {
        let end = self.len.saturating_add(bytes.len());
        if let Some(slot) = self.buffer.get_mut(self.len..end) {
            slot.copy_from_slice(bytes);
        }
        self.len = end;
    }

    pub fn put_u8(&mut self, value: u8) {
        self.put(&[value]);
    }

    pub fn put_u16(&mut self, value: u16) {
        self.put(&value.to_be_bytes());
    }

    pub fn put_u32(&mut self, value: u32) {
        self.put(&value.to_be_bytes());
    }

    /// Writes `value` at `at`, over what is there (a length known afterwards).
    pub fn set_u16(&mut self, at: usize, value: u16) {
        if let Some(slot) = at.checked_add(2).and_then(|end| self.buffer.get_mut(at..end)) {
            slot.copy_from_slice(&value.to_be_bytes());
        }
    }
}
