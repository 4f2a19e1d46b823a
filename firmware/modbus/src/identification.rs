//! Read Device Identification: function 2B (Encapsulated Interface
//! Transport, 6.19) with MEI type 0E (Modbus Application Protocol V1.1b3, 6.21).
//!
//! ```text
//! request:  | 2B | 0E | read device id code | object id |
//! response: | 2B | 0E | read device id code | conformity level | more follows (00/FF)
//!           | next object id | number of objects | objects ... |
//! object:   | id | length | value (length bytes) |
//! ```
//!
//! The codec knows the layout and the object ids; which objects a device
//! has and what they hold is the server's ([`Writer`] emits its response).

use crate::FunctionCode;
use crate::mbap::MAX_PDU_LEN;

/// The MEI type of Read Device Identification (6.19, 6.21).
pub const MEI_TYPE: u8 = 0x0E;
/// A response's bytes before its objects: function code, MEI type, read
/// device id code, conformity level, more follows, next object id, number
/// of objects.
pub const HEADER_LEN: usize = 7;
/// An object's bytes before its value: id and length.
pub const OBJECT_HEADER_LEN: usize = 2;
/// "More follows": the objects continue in a next response, from the
/// next object id (6.21). Without it the byte is 0x00.
pub const MORE_FOLLOWS: u8 = 0xFF;

code_table! {
    /// A read device id code (V1.1b3, 6.21): which objects a request asks
    /// for. The other codes are `Unknown`, and answered with exception 03;
    /// so is 03 by a server with no extended objects.
    pub enum ReadDeviceIdCode: u8 {
        display: "read device id code",
        /// The basic objects (0x00-0x02), as a stream.
        Basic = 0x01, "basic device identification", section "6.21";
        /// The basic and regular objects (0x00-0x7F), as a stream.
        Regular = 0x02, "regular device identification", section "6.21";
        /// All the objects, the extended (private, 0x80-0xFF) ones too, as a stream.
        Extended = 0x03, "extended device identification", section "6.21";
        /// The object of the request's object id alone.
        Specific = 0x04, "one specific identification object", section "6.21";
    }
}

/// The object ids the specification defines (6.21): the basic category
/// (mandatory), then the regular one (optional).
pub mod object {
    pub const VENDOR_NAME: u8 = 0x00;
    pub const PRODUCT_CODE: u8 = 0x01;
    pub const MAJOR_MINOR_REVISION: u8 = 0x02;
    pub const VENDOR_URL: u8 = 0x03;
    pub const PRODUCT_NAME: u8 = 0x04;
    pub const MODEL_NAME: u8 = 0x05;
    pub const USER_APPLICATION_NAME: u8 = 0x06;
    /// The last object id of the basic category.
    pub const LAST_BASIC: u8 = MAJOR_MINOR_REVISION;
    /// The last object id the regular category defines (0x07-0x7F are reserved).
    pub const LAST_REGULAR: u8 = USER_APPLICATION_NAME;
    /// The first id of the extended category (private objects, 0x80-0xFF).
    pub const FIRST_EXTENDED: u8 = 0x80;
}

/// The objects of a response, as it carries them: `count` times
/// `| id | length | value |`, filling the bytes exactly.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Objects<'a> {
    bytes: &'a [u8],
    count: u8,
}

impl<'a> Objects<'a> {
    /// `count` objects that fill `bytes` exactly, or `None`.
    pub fn parse(count: u8, bytes: &'a [u8]) -> Option<Self> {
        let mut iter = Iter { rest: bytes };
        for _ in 0..count {
            iter.next_object()?;
        }
        iter.rest.is_empty().then_some(Self { bytes, count })
    }

    /// How many objects there are.
    pub fn count(&self) -> u8 {
        self.count
    }

    /// The objects as the response carries them.
    pub fn as_bytes(&self) -> &'a [u8] {
        self.bytes
    }

    /// Each object's id and value, in order.
    pub fn iter(&self) -> Iter<'a> {
        Iter { rest: self.bytes }
    }
}

/// The objects of [`Objects`] in order: `(id, value)`.
#[derive(Clone, Debug)]
pub struct Iter<'a> {
    rest: &'a [u8],
}

impl<'a> Iter<'a> {
    fn next_object(&mut self) -> Option<(u8, &'a [u8])> {
        let (&id, rest) = self.rest.split_first()?;
        let (&len, rest) = rest.split_first()?;
        let (value, rest) = rest.split_at_checked(usize::from(len))?;
        self.rest = rest;
        Some((id, value))
    }
}

impl<'a> Iterator for Iter<'a> {
    type Item = (u8, &'a [u8]);

    fn next(&mut self) -> Option<Self::Item> {
        self.next_object()
    }
}

/// A Read Device Identification response written straight into a reply's
/// PDU, one object at a time: the server's side of
/// [`crate::Response::ReadDeviceIdentification`].
#[derive(Debug)]
pub struct Writer<'a> {
    out: &'a mut [u8],
    len: usize,
    count: u8,
}

impl<'a> Writer<'a> {
    /// A response with no objects yet, in `out` (at most [`MAX_PDU_LEN`]
    /// bytes of it are used); `None` if `out` cannot hold its header.
    pub fn new(out: &'a mut [u8]) -> Option<Self> {
        let end = out.len().min(MAX_PDU_LEN);
        let out = out.get_mut(..end)?;
        (out.len() >= HEADER_LEN).then_some(Self { out, len: HEADER_LEN, count: 0 })
    }

    /// Appends object `id` holding `value`; `None`, and nothing written, if
    /// it does not fit the PDU (or its value is longer than 255 bytes).
    pub fn push(&mut self, id: u8, value: &[u8]) -> Option<()> {
        let len = u8::try_from(value.len()).ok()?;
        let count = self.count.checked_add(1)?;
        let end = self.len.checked_add(OBJECT_HEADER_LEN + value.len())?;
        let (head, rest) = self.out.get_mut(self.len..end)?.split_at_mut_checked(OBJECT_HEADER_LEN)?;
        head.copy_from_slice(&[id, len]);
        rest.copy_from_slice(value);
        (self.len, self.count) = (end, count);
        Some(())
    }

    /// Writes the header before the objects and returns the PDU's length.
    /// `next_object_id`: where the objects continue in a next response
    /// ("more follows"), or `None` when this one holds the last.
    pub fn finish(self, code: ReadDeviceIdCode, conformity: u8, next_object_id: Option<u8>) -> usize {
        let (more, next) = match next_object_id {
            Some(id) => (MORE_FOLLOWS, id),
            None => (0x00, 0x00),
        };
        let function = FunctionCode::EncapsulatedInterfaceTransport.code();
        let header = [function, MEI_TYPE, code.code(), conformity, more, next, self.count];
        if let Some(out) = self.out.get_mut(..HEADER_LEN) {
            out.copy_from_slice(&header);
        }
        self.len
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_round_trip_and_only_01_to_04_are_known() {
        for code in 0..=u8::MAX {
            let read = ReadDeviceIdCode::from(code);
            assert_eq!(u8::from(read), code);
            assert_eq!(read == ReadDeviceIdCode::Unknown(code), ![1, 2, 3, 4].contains(&code), "{code:#04x}");
        }
        assert_eq!(
            ReadDeviceIdCode::Specific.to_string(),
            "read device id code 04: one specific identification object"
        );
    }

    #[test]
    fn objects_must_fill_their_bytes_exactly() {
        let bytes = [0x00, 0x02, b'a', b'b', 0x06, 0x00];
        let objects = Objects::parse(2, &bytes).unwrap();
        assert_eq!(objects.iter().collect::<Vec<_>>(), [(0x00, &b"ab"[..]), (0x06, &b""[..])]);
        assert_eq!((objects.count(), objects.as_bytes()), (2, &bytes[..]));
        assert_eq!(Objects::parse(1, &bytes), None, "bytes left over");
        assert_eq!(Objects::parse(3, &bytes), None, "an object missing");
        for n in 0..bytes.len() {
            assert_eq!(Objects::parse(2, &bytes[..n]), None, "cut at {n}");
        }
        assert_eq!(Objects::parse(0, &[]).map(|o| o.count()), Some(0));
    }

    #[test]
    fn a_writer_fills_the_header_and_objects_and_nothing_else() {
        let mut buf = [0xa5u8; 32];
        let mut writer = Writer::new(&mut buf).unwrap();
        writer.push(object::VENDOR_NAME, b"ab").unwrap();
        writer.push(object::MODEL_NAME, b"xyz").unwrap();
        let len = writer.finish(ReadDeviceIdCode::Regular, 0x82, None);
        #[rustfmt::skip]
        assert_eq!(&buf[..len], [
            0x2b, 0x0e, 0x02, // function, MEI type, read code
            0x82,             // conformity: regular, stream and individual access
            0x00, 0x00,       // no more follows, next object id 0
            0x02,             // two objects
            0x00, 0x02, b'a', b'b',
            0x05, 0x03, b'x', b'y', b'z',
        ]);
        assert_eq!(buf[len], 0xa5);
    }

    #[test]
    fn a_writer_refuses_what_does_not_fit_and_says_where_to_go_on() {
        let mut buf = [0xa5u8; 300];
        let mut writer = Writer::new(&mut buf).unwrap();
        let value = [b'v'; 100];
        writer.push(0, &value).unwrap();
        writer.push(1, &value).unwrap();
        // 7 + 2 × 102 = 211 of 253 bytes: a third of 102 does not fit, 40 does.
        assert_eq!(writer.push(2, &value), None);
        writer.push(2, &value[..40]).unwrap();
        assert_eq!(writer.push(3, &[]), None, "253 bytes used: not even an empty object");
        assert_eq!(writer.push(3, &[0; 256]), None);
        let len = writer.finish(ReadDeviceIdCode::Basic, 0x82, Some(3));
        assert_eq!(len, MAX_PDU_LEN);
        assert_eq!(buf[..HEADER_LEN], [0x2b, 0x0e, 0x01, 0x82, 0xff, 0x03, 0x03]);
        assert_eq!(buf[len], 0xa5, "nothing past the largest PDU");
        assert!(Writer::new(&mut [0u8; HEADER_LEN - 1]).is_none());
    }
}
