//! JSON in and out, by hand (RFC 8259): a pull reader over a request body
//! and an output buffer that escapes strings.
//!
//! Why not serde-json-core: the API needs one error per field (an unknown
//! key, a value of the wrong type, a value its rule refuses), keeps reading
//! after the first, and takes a number or a string for any setting as the
//! text [`crate::settings::Settings::set`] parses. A derive stops at the
//! first error and fixes one type per field; this reader is a few hundred
//! lines and no generic code per document.
//!
//! Contract (smoltcp's): the reader never panics and never reads past its
//! slice, whatever the bytes; every error is [`Malformed`] with the offset
//! where the body stops being JSON. A [`Str`] has been checked when it is
//! returned (escapes, control characters, UTF-8), so decoding it cannot fail.
//! The writer never panics either: past its end it records an overflow.

use core::fmt;

use crate::text::{self, Unsigned};

/// Where a body stops being JSON (a byte offset).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Malformed {
    pub at: usize,
}

/// Deepest nesting of objects and arrays taken, counting the outermost
/// (the API's documents have 2; a deeper value is skipped up to this).
pub const MAX_DEPTH: usize = 8;

/// A string as it stands in the body between its quotes, escapes and all.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Str<'a> {
    raw: &'a [u8],
}

impl<'a> Str<'a> {
    /// The string's bytes, escapes decoded (UTF-8).
    pub fn bytes(&self) -> Decoded<'a> {
        Decoded { rest: self.raw, pending: [0; 4], pending_len: 0, pending_pos: 0 }
    }

    /// Whether the string is exactly `text`.
    pub fn is(&self, text: &str) -> bool {
        self.bytes().eq(text.bytes())
    }

    /// Whether two strings say the same, however escaped.
    pub fn same(&self, other: &Str<'_>) -> bool {
        self.bytes().eq(other.bytes())
    }

    /// The string decoded into `buf`; `None` when it does not fit.
    pub fn decode<'b>(&self, buf: &'b mut [u8]) -> Option<&'b str> {
        let mut len = 0;
        for byte in self.bytes() {
            *buf.get_mut(len)? = byte;
            len += 1;
        }
        let (text, _) = buf.split_at_checked(len)?;
        core::str::from_utf8(text).ok()
    }
}

/// The decoded bytes of a [`Str`].
#[derive(Clone, Debug)]
pub struct Decoded<'a> {
    rest: &'a [u8],
    pending: [u8; 4],
    pending_len: u8,
    pending_pos: u8,
}

impl Iterator for Decoded<'_> {
    type Item = u8;

    fn next(&mut self) -> Option<u8> {
        if self.pending_pos < self.pending_len {
            let byte = self.pending.get(usize::from(self.pending_pos)).copied();
            self.pending_pos += 1;
            return byte;
        }
        match self.rest {
            [b'\\', b'u', a, b, c, d, tail @ ..] => {
                let unit = hex4([*a, *b, *c, *d]).unwrap_or(0xfffd);
                self.rest = tail;
                let code = match (unit, self.rest) {
                    (0xd800..=0xdbff, [b'\\', b'u', a, b, c, d, tail @ ..]) => match hex4([*a, *b, *c, *d]) {
                        Some(low @ 0xdc00..=0xdfff) => {
                            self.rest = tail;
                            0x10000 + ((unit - 0xd800) << 10) + (low - 0xdc00)
                        }
                        _ => 0xfffd,
                    },
                    _ => unit,
                };
                // A lone surrogate becomes U+FFFD.
                let ch = char::from_u32(code).unwrap_or(char::REPLACEMENT_CHARACTER);
                let len = ch.encode_utf8(&mut self.pending).len();
                self.pending_len = len as u8;
                self.pending_pos = 1;
                self.pending.first().copied()
            }
            [b'\\', escaped, tail @ ..] => {
                self.rest = tail;
                Some(match escaped {
                    b'b' => 0x08,
                    b'f' => 0x0c,
                    b'n' => b'\n',
                    b'r' => b'\r',
                    b't' => b'\t',
                    // `"`, `\` and `/` stand for themselves.
                    other => *other,
                })
            }
            [byte, tail @ ..] => {
                self.rest = tail;
                Some(*byte)
            }
            [] => None,
        }
    }
}

/// Four hexadecimal digits.
fn hex4(digits: [u8; 4]) -> Option<u32> {
    digits.iter().try_fold(0u32, |value, &digit| Some(value << 4 | char::from(digit).to_digit(16)?))
}

/// One value, as [`Reader::value`] returns it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Value<'a> {
    String(Str<'a>),
    /// The number's text, as the body has it (checked against JSON's grammar).
    Number(&'a str),
    Bool(bool),
    Null,
    /// An object, skipped whole.
    Object,
    /// An array, skipped whole.
    Array,
}

/// A pull reader over one JSON document.
#[derive(Debug)]
pub struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
    /// Objects entered with [`Reader::begin_object`] and not yet left.
    depth: usize,
    /// No key has been read yet in the innermost object.
    first: bool,
}

impl<'a> Reader<'a> {
    pub fn new(bytes: &'a [u8]) -> Self {
        Self { bytes, pos: 0, depth: 0, first: true }
    }

    fn malformed(&self) -> Malformed {
        Malformed { at: self.pos }
    }

    /// The bytes from the current position.
    fn rest(&self) -> &'a [u8] {
        self.bytes.get(self.pos..).unwrap_or_default()
    }

    /// The next byte after whitespace, not consumed.
    pub fn peek(&mut self) -> Option<u8> {
        while let [b' ' | b'\t' | b'\n' | b'\r', ..] = self.rest() {
            self.pos += 1;
        }
        self.rest().first().copied()
    }

    fn expect(&mut self, byte: u8) -> Result<(), Malformed> {
        if self.peek() == Some(byte) {
            self.pos += 1;
            Ok(())
        } else {
            Err(self.malformed())
        }
    }

    /// Enters an object: `{`.
    pub fn begin_object(&mut self) -> Result<(), Malformed> {
        if self.depth >= MAX_DEPTH {
            return Err(self.malformed());
        }
        self.expect(b'{')?;
        self.depth += 1;
        self.first = true;
        Ok(())
    }

    /// The next key of the object entered last and its `:`, or `None` at its
    /// `}` (which leaves the object). The key's value must be read next.
    pub fn next_key(&mut self) -> Result<Option<Str<'a>>, Malformed> {
        if self.depth == 0 {
            return Err(self.malformed());
        }
        if self.peek() == Some(b'}') {
            self.pos += 1;
            self.depth -= 1;
            // The object just left was a value of a key in the one around it.
            self.first = false;
            return Ok(None);
        }
        if !self.first {
            self.expect(b',')?;
        }
        self.first = false;
        let key = self.string()?;
        self.expect(b':')?;
        Ok(Some(key))
    }

    /// The next value; an object or an array is checked and skipped.
    pub fn value(&mut self) -> Result<Value<'a>, Malformed> {
        self.any(self.depth)
    }

    /// Only whitespace is left.
    pub fn end(&mut self) -> Result<(), Malformed> {
        match self.peek() {
            None if self.depth == 0 => Ok(()),
            _ => Err(self.malformed()),
        }
    }

    /// Any value at nesting `depth`.
    fn any(&mut self, depth: usize) -> Result<Value<'a>, Malformed> {
        match self.peek() {
            Some(b'{') => {
                self.container(depth, b'}', |reader, depth| {
                    reader.string()?;
                    reader.expect(b':')?;
                    reader.any(depth).map(drop)
                })?;
                Ok(Value::Object)
            }
            Some(b'[') => {
                self.container(depth, b']', |reader, depth| reader.any(depth).map(drop))?;
                Ok(Value::Array)
            }
            Some(b'"') => self.string().map(Value::String),
            Some(b't') => self.literal(b"true", Value::Bool(true)),
            Some(b'f') => self.literal(b"false", Value::Bool(false)),
            Some(b'n') => self.literal(b"null", Value::Null),
            Some(b'-' | b'0'..=b'9') => self.number().map(Value::Number),
            _ => Err(self.malformed()),
        }
    }

    /// An object or array (its opening byte is next) whose items `item` reads.
    fn container(
        &mut self,
        depth: usize,
        close: u8,
        mut item: impl FnMut(&mut Self, usize) -> Result<(), Malformed>,
    ) -> Result<(), Malformed> {
        if depth >= MAX_DEPTH {
            return Err(self.malformed());
        }
        self.pos += 1;
        if self.peek() == Some(close) {
            self.pos += 1;
            return Ok(());
        }
        loop {
            item(self, depth + 1)?;
            match self.peek() {
                Some(b',') => self.pos += 1,
                Some(byte) if byte == close => {
                    self.pos += 1;
                    return Ok(());
                }
                _ => return Err(self.malformed()),
            }
        }
    }

    fn literal(&mut self, word: &[u8], value: Value<'a>) -> Result<Value<'a>, Malformed> {
        if self.rest().starts_with(word) {
            self.pos += word.len();
            Ok(value)
        } else {
            Err(self.malformed())
        }
    }

    /// A string: `"`, then characters or escapes, then `"`.
    fn string(&mut self) -> Result<Str<'a>, Malformed> {
        self.expect(b'"')?;
        let start = self.pos;
        loop {
            match self.rest() {
                [b'"', ..] => break,
                [b'\\', b'"' | b'\\' | b'/' | b'b' | b'f' | b'n' | b'r' | b't', ..] => self.pos += 2,
                [b'\\', b'u', a, b, c, d, ..] if hex4([*a, *b, *c, *d]).is_some() => self.pos += 6,
                [byte, ..] if *byte >= 0x20 && *byte != b'\\' => self.pos += 1,
                _ => return Err(self.malformed()),
            }
        }
        let raw = self.bytes.get(start..self.pos).unwrap_or_default();
        if core::str::from_utf8(raw).is_err() {
            return Err(Malformed { at: start });
        }
        self.pos += 1;
        Ok(Str { raw })
    }

    /// A number: `-? (0 | [1-9][0-9]*) (. [0-9]+)? ([eE] [+-]? [0-9]+)?`.
    fn number(&mut self) -> Result<&'a str, Malformed> {
        let start = self.pos;
        if let [b'-', ..] = self.rest() {
            self.pos += 1;
        }
        match self.rest() {
            [b'0', ..] => self.pos += 1,
            [b'1'..=b'9', ..] => self.digits(),
            _ => return Err(self.malformed()),
        }
        if let [b'.', ..] = self.rest() {
            self.pos += 1;
            self.required_digits()?;
        }
        if let [b'e' | b'E', ..] = self.rest() {
            self.pos += 1;
            if let [b'+' | b'-', ..] = self.rest() {
                self.pos += 1;
            }
            self.required_digits()?;
        }
        let text = self.bytes.get(start..self.pos).unwrap_or_default();
        // Digits, signs, `.` and `e`: ASCII.
        core::str::from_utf8(text).map_err(|_| Malformed { at: start })
    }

    fn digits(&mut self) {
        while let [b'0'..=b'9', ..] = self.rest() {
            self.pos += 1;
        }
    }

    fn required_digits(&mut self) -> Result<(), Malformed> {
        match self.rest() {
            [b'0'..=b'9', ..] => {
                self.digits();
                Ok(())
            }
            _ => Err(self.malformed()),
        }
    }
}

/// A response body being written into a fixed buffer. Past the end (or the
/// reserve kept by [`Out::reserve`]) it drops bytes and records an overflow.
#[derive(Debug)]
pub struct Out<'b> {
    buf: &'b mut [u8],
    len: usize,
    /// Bytes at the end kept back for closing brackets.
    reserved: usize,
    overflow: bool,
}

impl<'b> Out<'b> {
    pub fn new(buf: &'b mut [u8]) -> Self {
        Self { buf, len: 0, reserved: 0, overflow: false }
    }

    /// What has been written.
    pub fn as_bytes(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or_default()
    }

    /// Whether something did not fit.
    pub fn overflowed(&self) -> bool {
        self.overflow
    }

    /// Starts over.
    pub fn clear(&mut self) {
        self.len = 0;
        self.reserved = 0;
        self.overflow = false;
    }

    /// Where the body ends now, to go back to with [`Out::truncate`].
    pub fn mark(&self) -> usize {
        self.len
    }

    /// Drops what was written after `mark` (and a recorded overflow).
    pub fn truncate(&mut self, mark: usize) {
        self.len = self.len.min(mark);
        self.overflow = false;
    }

    /// Keeps `n` bytes at the end back from what follows, until released
    /// with `reserve(0)`.
    pub fn reserve(&mut self, n: usize) {
        self.reserved = n;
    }

    /// Appends bytes as they are.
    pub fn raw(&mut self, bytes: &[u8]) {
        let room = self.buf.len().saturating_sub(self.reserved).saturating_sub(self.len);
        if bytes.len() > room {
            self.overflow = true;
            return;
        }
        if let Some(slot) = self.buf.get_mut(self.len..self.len + bytes.len()) {
            slot.copy_from_slice(bytes);
            self.len += bytes.len();
        } else {
            self.overflow = true;
        }
    }

    /// Appends text as it is (JSON punctuation, numbers, known keys).
    pub fn text(&mut self, text: &str) {
        self.raw(text.as_bytes());
    }

    /// Appends a number.
    #[inline]
    pub fn number(&mut self, value: impl Unsigned) {
        self.number_u64(value.widen());
    }

    /// [`Self::number`], once for every width.
    fn number_u64(&mut self, value: u64) {
        self.text(text::decimal(value, &mut [0; text::MAX_DIGITS]));
    }

    /// Appends a signed number, in tenths when `tenths` (`-12.5` for -125,
    /// `0.0` for 0).
    pub fn signed(&mut self, value: i32, tenths: bool) {
        if value < 0 {
            self.text("-");
        }
        let magnitude = value.unsigned_abs();
        if tenths {
            self.number(magnitude / 10);
            self.text(".");
            self.number(magnitude % 10);
        } else {
            self.number(magnitude);
        }
    }

    /// Appends a JSON string of `bytes` (UTF-8), quoted and escaped.
    pub fn string_of(&mut self, bytes: impl Iterator<Item = u8>) {
        self.raw(b"\"");
        for byte in bytes {
            self.escaped(byte);
        }
        self.raw(b"\"");
    }

    /// Appends a JSON string of `text`.
    pub fn string(&mut self, text: &str) {
        self.string_of(text.bytes());
    }

    /// Appends a JSON string of what `show` writes.
    pub fn string_with(&mut self, show: impl FnOnce(&mut dyn fmt::Write) -> fmt::Result) {
        self.raw(b"\"");
        if show(&mut Escape(self)).is_err() {
            self.overflow = true;
        }
        self.raw(b"\"");
    }

    /// `true` or `false`.
    pub fn boolean(&mut self, value: bool) {
        self.text(if value { "true" } else { "false" });
    }

    /// One byte of a string's content, escaped as JSON needs.
    fn escaped(&mut self, byte: u8) {
        match byte {
            b'"' => self.raw(b"\\\""),
            b'\\' => self.raw(b"\\\\"),
            b'\n' => self.raw(b"\\n"),
            b'\r' => self.raw(b"\\r"),
            b'\t' => self.raw(b"\\t"),
            0..0x20 => {
                let hex = |nibble: u8| if nibble < 10 { b'0' + nibble } else { b'a' + nibble - 10 };
                self.raw(&[b'\\', b'u', b'0', b'0', hex(byte >> 4), hex(byte & 0xf)]);
            }
            _ => self.raw(&[byte]),
        }
    }
}

impl fmt::Write for Out<'_> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        self.raw(s.as_bytes());
        if self.overflow { Err(fmt::Error) } else { Ok(()) }
    }
}

/// Writes into an [`Out`] as the content of a JSON string.
struct Escape<'o, 'b>(&'o mut Out<'b>);

impl fmt::Write for Escape<'_, '_> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        for byte in s.bytes() {
            self.0.escaped(byte);
        }
        if self.0.overflow { Err(fmt::Error) } else { Ok(()) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every value of a document, flattened: keys and scalars, in order.
    fn walk(body: &str) -> Result<Vec<String>, Malformed> {
        let mut reader = Reader::new(body.as_bytes());
        let mut seen = Vec::new();
        reader.begin_object()?;
        while let Some(key) = reader.next_key()? {
            seen.push(key.bytes().map(char::from).collect());
            if reader.peek() == Some(b'{') {
                reader.begin_object()?;
                while let Some(inner) = reader.next_key()? {
                    seen.push(format!("{}=", String::from_utf8(inner.bytes().collect()).unwrap()));
                    seen.push(format!("{:?}", reader.value()?));
                }
            } else {
                seen.push(format!("{:?}", reader.value()?));
            }
        }
        reader.end()?;
        Ok(seen)
    }

    #[test]
    fn documents_read_as_written() {
        let body = r#" { "a" : { "b": 1, "c": "x\"y" }, "d": [1, {"e": null}], "f": true, "g": {} } "#;
        let seen = walk(body).unwrap();
        assert_eq!(seen[0], "a");
        assert_eq!(seen[1], "b=");
        assert_eq!(seen[2], r#"Number("1")"#);
        assert_eq!(seen[4], r#"String(Str { raw: [120, 92, 34, 121] })"#);
        assert_eq!(seen[5..], ["d", "Array", "f", "Bool(true)", "g"]);
        assert!(walk("{}").unwrap().is_empty());
    }

    #[test]
    fn numbers_follow_the_grammar() {
        for good in ["0", "-0", "7", "247", "1.5", "-1e3", "2E+10", "0.0e-1"] {
            let body = format!(r#"{{"n": {good}}}"#);
            assert_eq!(walk(&body).unwrap()[1], format!("Number({good:?})"), "{good}");
        }
        for bad in ["01", "-", "1.", ".5", "1e", "1e+", "+1", "0x10", "1.e3", "--1", "Infinity", "NaN"] {
            assert!(walk(&format!(r#"{{"n": {bad}}}"#)).is_err(), "{bad}");
        }
    }

    #[test]
    fn malformed_documents_are_refused_where_they_break() {
        let cases: &[(&str, usize)] = &[
            ("", 0),
            ("[]", 0),
            ("{", 1),
            ("{,}", 1),
            (r#"{"a"}"#, 4),
            (r#"{"a":}"#, 5),
            (r#"{"a":1,}"#, 7),
            (r#"{"a":1 "b":2}"#, 7),
            (r#"{"a":1}}"#, 7),
            (r#"{"a":1} x"#, 8),
            (r#"{"a":[1,]}"#, 8),
            (r#"{"a":[1}"#, 7),
            (r#"{"a":tru}"#, 5),
            ("{\"a\":\"\x01\"}", 6),
            (r#"{"a":"\x"}"#, 6),
            (r#"{"a":"\u12g4"}"#, 6),
            (r#"{"a":"open"#, 10),
            (r#"{'a':1}"#, 1),
        ];
        for &(body, at) in cases {
            assert_eq!(walk(body), Err(Malformed { at }), "{body:?}");
        }
        assert_eq!(walk("{\"a\":\"\u{e9}\"}").unwrap()[1], r#"String(Str { raw: [195, 169] })"#);
        let mut invalid_utf8 = b"{\"a\":\"".to_vec();
        invalid_utf8.extend([0xff, b'"', b'}']);
        let mut reader = Reader::new(&invalid_utf8);
        reader.begin_object().unwrap();
        assert_eq!(reader.next_key().unwrap().map(|k| k.is("a")), Some(true));
        assert_eq!(reader.value(), Err(Malformed { at: 6 }));
    }

    #[test]
    fn nesting_stops_at_the_limit() {
        let nested = |n: usize| format!(r#"{{"a":{}1{}}}"#, "[".repeat(n), "]".repeat(n));
        assert!(walk(&nested(MAX_DEPTH - 1)).is_ok());
        assert!(walk(&nested(MAX_DEPTH)).is_err());
        assert!(walk(&nested(10_000)).is_err(), "no recursion past the limit");
    }

    #[test]
    fn strings_decode_their_escapes() {
        let mut reader = Reader::new(br#"{"k": "a\"\\\/\b\f\n\r\t\u00e9\ud83d\ude00\ud800x"}"#);
        reader.begin_object().unwrap();
        reader.next_key().unwrap();
        let Value::String(s) = reader.value().unwrap() else { panic!() };
        let mut buf = [0u8; 64];
        assert_eq!(s.decode(&mut buf), Some("a\"\\/\u{8}\u{c}\n\r\t\u{e9}\u{1f600}\u{fffd}x"));
        assert_eq!(s.decode(&mut [0u8; 4]), None, "does not fit");
        let mut reader = Reader::new(br#"{"\u0061b": 1}"#);
        reader.begin_object().unwrap();
        let key = reader.next_key().unwrap().unwrap();
        assert!(key.is("ab") && !key.is("a") && !key.is("abc"));
        assert!(key.same(&Str { raw: b"ab" }));
    }

    #[test]
    fn every_prefix_and_every_byte_flip_is_safe() {
        let body = br#"{"modbus": {"unit_id": 7, "allow_write": "10.0.0.0/8"}, "x": [1.5e3, {"y": null}]}"#;
        for len in 0..body.len() {
            assert!(walk(std::str::from_utf8(&body[..len]).unwrap_or("")).is_err(), "prefix of {len}");
        }
        for i in 0..body.len() {
            for byte in [0u8, b'"', b'\\', b'{', b'}', b'[', b']', b',', b':', 0xff] {
                let mut copy = body.to_vec();
                copy[i] = byte;
                let mut reader = Reader::new(&copy);
                // Walk it generically: never a panic.
                let _ = (|| -> Result<(), Malformed> {
                    reader.begin_object()?;
                    while reader.next_key()?.is_some() {
                        reader.value()?;
                    }
                    reader.end()
                })();
            }
        }
    }

    #[test]
    fn the_writer_escapes_and_stops_at_its_end() {
        let mut buf = [0xa5u8; 64];
        let mut out = Out::new(&mut buf);
        out.text("{");
        out.string("a\"b\\c\n\u{1}é");
        out.text(":");
        out.number(42u32);
        out.text(",");
        out.boolean(true);
        out.string_with(|w| w.write_str("x\ty"));
        out.text("}");
        assert!(!out.overflowed());
        assert_eq!(out.as_bytes(), r#"{"a\"b\\c\n\u0001é":42,true"x\ty"}"#.as_bytes());
        let mut small = [0u8; 8];
        let mut out = Out::new(&mut small);
        out.text("12345");
        out.reserve(2);
        let mark = out.mark();
        out.text("67");
        assert!(out.overflowed(), "the reserve is kept back");
        out.truncate(mark);
        out.reserve(0);
        out.text("}}");
        assert!(!out.overflowed());
        assert_eq!(out.as_bytes(), b"12345}}");
        out.clear();
        assert_eq!(out.as_bytes(), b"");
    }

    #[test]
    fn signed_numbers_and_tenths_read_back_as_their_values() {
        let cases: [(i32, bool, &str); 10] = [
            (0, false, "0"),
            (7, false, "7"),
            (-7, false, "-7"),
            (i32::from(i16::MIN), false, "-32768"),
            (i32::from(i16::MAX), false, "32767"),
            (0, true, "0.0"),
            (5, true, "0.5"),
            (-5, true, "-0.5"),
            (-125, true, "-12.5"),
            (i32::from(i16::MIN), true, "-3276.8"),
        ];
        for (value, tenths, text) in cases {
            let mut buf = [0u8; 16];
            let mut out = Out::new(&mut buf);
            out.signed(value, tenths);
            assert_eq!(core::str::from_utf8(out.as_bytes()), Ok(text), "{value} {tenths}");
            let read: f64 = serde_json::from_slice(out.as_bytes()).unwrap();
            let expected = if tenths { f64::from(value) / 10.0 } else { f64::from(value) };
            assert!((read - expected).abs() < 1e-9, "{text} reads as {read}");
        }
    }
}
