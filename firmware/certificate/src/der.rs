//! DER's tag-length-value, read from a slice: one element at a time, each
//! checked against what is left before any byte of it is used.
//!
//! Only what X.509 needs: single-byte tags (every tag of RFC 5280's
//! certificate is one), definite lengths in short or long form of up to
//! four bytes. A length that is not minimal is refused, as DER requires
//! (X.690 10.1), so one certificate has one reading.

use crate::Error;

/// Universal and context tags X.509 uses.
pub mod tag {
    pub const BOOLEAN: u8 = 0x01;
    pub const INTEGER: u8 = 0x02;
    pub const BIT_STRING: u8 = 0x03;
    pub const OCTET_STRING: u8 = 0x04;
    pub const OID: u8 = 0x06;
    pub const UTF8_STRING: u8 = 0x0c;
    pub const PRINTABLE_STRING: u8 = 0x13;
    pub const IA5_STRING: u8 = 0x16;
    pub const UTC_TIME: u8 = 0x17;
    pub const GENERALIZED_TIME: u8 = 0x18;
    pub const SEQUENCE: u8 = 0x30;
    pub const SET: u8 = 0x31;
    /// `[n]` constructed, explicit (0xa0 + n).
    pub const fn explicit(n: u8) -> u8 {
        0xa0 | n
    }
}

/// One element: its tag, its contents, and all its bytes (header too).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tlv<'a> {
    pub tag: u8,
    pub value: &'a [u8],
    pub whole: &'a [u8],
}

/// A reader over a run of elements (a SEQUENCE's contents, say).
#[derive(Clone, Copy, Debug)]
pub struct Reader<'a> {
    rest: &'a [u8],
}

impl<'a> Reader<'a> {
    pub const fn new(bytes: &'a [u8]) -> Self {
        Self { rest: bytes }
    }

    pub const fn is_empty(&self) -> bool {
        self.rest.is_empty()
    }

    /// The next element, whatever its tag.
    pub fn read(&mut self) -> Result<Tlv<'a>, Error> {
        let (&tag, after_tag) = self.rest.split_first().ok_or(Error::Truncated)?;
        if tag & 0x1f == 0x1f {
            // A multi-byte tag: none in a certificate this device reads.
            return Err(Error::Malformed);
        }
        let (&first, after_first) = after_tag.split_first().ok_or(Error::Truncated)?;
        let (len, after_len) = match first {
            0..=0x7f => (usize::from(first), after_first),
            0x81..=0x84 => {
                let count = usize::from(first & 0x7f);
                let (digits, after) = after_first.split_at_checked(count).ok_or(Error::Truncated)?;
                let len = digits.iter().fold(0usize, |len, &digit| (len << 8) | usize::from(digit));
                // Minimal: the long form only past 127, and no leading zero byte.
                if len < 0x80 || digits.first() == Some(&0) {
                    return Err(Error::Malformed);
                }
                (len, after)
            }
            // Indefinite (0x80) is BER's, not DER's; longer lengths cannot fit.
            _ => return Err(Error::Malformed),
        };
        let (value, rest) = after_len.split_at_checked(len).ok_or(Error::Truncated)?;
        let whole_len = self.rest.len() - rest.len();
        let whole = self.rest.get(..whole_len).ok_or(Error::Truncated)?;
        self.rest = rest;
        Ok(Tlv { tag, value, whole })
    }

    /// The next element, which must have `tag`.
    pub fn expect(&mut self, tag: u8) -> Result<Tlv<'a>, Error> {
        let tlv = self.read()?;
        if tlv.tag == tag { Ok(tlv) } else { Err(Error::Malformed) }
    }

    /// The next element if it has `tag`; otherwise nothing is read.
    pub fn optional(&mut self, tag: u8) -> Result<Option<Tlv<'a>>, Error> {
        match self.rest.first() {
            Some(&next) if next == tag => self.read().map(Some),
            _ => Ok(None),
        }
    }

    /// Nothing may be left.
    pub fn finish(&self) -> Result<(), Error> {
        if self.rest.is_empty() { Ok(()) } else { Err(Error::Malformed) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec;

    #[test]
    fn lengths_in_short_and_long_form() {
        let mut short = Reader::new(&[0x04, 0x02, 0xaa, 0xbb, 0x05, 0x00]);
        assert_eq!(short.read().unwrap(), Tlv { tag: 4, value: &[0xaa, 0xbb], whole: &[4, 2, 0xaa, 0xbb] });
        assert_eq!(short.read().unwrap().value, &[] as &[u8]);
        assert!(short.is_empty());
        let mut long = vec![0x04, 0x81, 0x80];
        long.extend([7; 0x80]);
        assert_eq!(Reader::new(&long).read().unwrap().value.len(), 0x80);
        let mut two = vec![0x04, 0x82, 0x01, 0x00];
        two.extend([7; 0x100]);
        assert_eq!(Reader::new(&two).read().unwrap().value.len(), 0x100);
    }

    #[test]
    fn what_der_forbids_or_the_slice_lacks_is_refused() {
        for (bytes, error) in [
            (&[][..], Error::Truncated),
            (&[0x04], Error::Truncated),
            (&[0x04, 0x02, 0xaa], Error::Truncated),
            (&[0x04, 0x80, 0x00, 0x00], Error::Malformed),
            (&[0x04, 0x81, 0x05, 1, 2, 3, 4, 5], Error::Malformed),
            (&[0x04, 0x82, 0x00, 0x80], Error::Malformed),
            (&[0x04, 0x85, 1, 1, 1, 1, 1], Error::Malformed),
            (&[0x04, 0x84, 0xff, 0xff, 0xff, 0xff], Error::Truncated),
            (&[0x1f, 0x01, 0x00], Error::Malformed),
        ] {
            assert_eq!(Reader::new(bytes).read(), Err(error), "{bytes:02x?}");
        }
    }
}
