//! The MBAP header and the framing of a byte stream into ADUs
//! (Modbus Messaging on TCP/IP Implementation Guide V1.0b, 3.1.3).
//!
//! ```text
//! | transaction id (2) | protocol id = 0 (2) | length = unit + PDU (2) | unit id (1) | PDU |
//! ```
//!
//! A frame ends where its length field says, whatever its function code: that
//! is the only framing rule, so an unknown or malformed PDU never puts the
//! stream out of step.

use core::fmt;

use super::{be_u16, put_be_u16};

mod field {
    use core::ops::Range;
    pub const TRANSACTION_ID: usize = 0;
    pub const PROTOCOL_ID: usize = 2;
    pub const LENGTH: usize = 4;
    pub const UNIT_ID: usize = 6;
    pub const PDU_START: usize = 7;
    /// The bytes before the ones the length field counts.
    pub const BEFORE_LENGTH: Range<usize> = 0..6;
}

/// Bytes of the MBAP header, unit id included.
pub const HEADER_LEN: usize = 7;
/// The largest ADU either side may send: 7 header bytes and a 253-byte PDU.
pub const MAX_ADU_LEN: usize = 260;
/// The largest PDU (function code and data).
pub const MAX_PDU_LEN: usize = MAX_ADU_LEN - HEADER_LEN;
/// The smallest length field: a unit id and a function code.
pub const MIN_LENGTH: u16 = 2;
/// The largest length field: a unit id and a [`MAX_PDU_LEN`]-byte PDU.
pub const MAX_LENGTH: u16 = (MAX_ADU_LEN - field::BEFORE_LENGTH.end) as u16;
/// The only protocol id that means Modbus.
pub const MODBUS_PROTOCOL_ID: u16 = 0;

/// Why a stream cannot be framed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// The buffer ends before the frame does: read more.
    Truncated,
    /// The length field is outside `MIN_LENGTH..=MAX_LENGTH`: the stream is
    /// lost and the connection must be closed.
    BadLength(u16),
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Truncated => write!(f, "truncated MBAP frame"),
            Self::BadLength(len) => {
                write!(f, "MBAP length {len} outside {MIN_LENGTH}..={MAX_LENGTH}")
            }
        }
    }
}

impl core::error::Error for Error {}

/// A read/write view of one MBAP frame at the start of a buffer.
///
/// The buffer may hold more bytes after the frame (pipelined requests); the
/// frame's own extent is [`Frame::frame_len`].
#[derive(Debug, Clone)]
pub struct Frame<T: AsRef<[u8]>> {
    buffer: T,
}

impl<T: AsRef<[u8]>> Frame<T> {
    /// Wraps a buffer without checking it; accessors may then return garbage
    /// (never panic) until [`Frame::check_len`] passes.
    pub const fn new_unchecked(buffer: T) -> Self {
        Self { buffer }
    }

    /// Wraps a buffer that holds at least one whole, well-framed frame.
    pub fn new_checked(buffer: T) -> Result<Self, Error> {
        let frame = Self::new_unchecked(buffer);
        frame.check_len()?;
        Ok(frame)
    }

    /// Checks that the length field is valid and the whole frame is in the buffer.
    ///
    /// A bad length is reported as soon as the length field has arrived, so a
    /// lost stream is detected without waiting for bytes that will not come.
    pub fn check_len(&self) -> Result<(), Error> {
        let data = self.buffer.as_ref();
        let length = be_u16(data, field::LENGTH).ok_or(Error::Truncated)?;
        if !(MIN_LENGTH..=MAX_LENGTH).contains(&length) {
            return Err(Error::BadLength(length));
        }
        if data.len() < field::BEFORE_LENGTH.end + usize::from(length) {
            return Err(Error::Truncated);
        }
        Ok(())
    }

    /// Returns the underlying buffer.
    pub fn into_inner(self) -> T {
        self.buffer
    }

    /// The transaction id, echoed in the reply.
    pub fn transaction_id(&self) -> u16 {
        be_u16(self.buffer.as_ref(), field::TRANSACTION_ID).unwrap_or(0)
    }

    /// The protocol id: 0 for Modbus.
    pub fn protocol_id(&self) -> u16 {
        be_u16(self.buffer.as_ref(), field::PROTOCOL_ID).unwrap_or(0)
    }

    /// The length field: bytes that follow it (unit id and PDU).
    pub fn length(&self) -> u16 {
        be_u16(self.buffer.as_ref(), field::LENGTH).unwrap_or(0)
    }

    /// The unit id, echoed in the reply.
    pub fn unit_id(&self) -> u8 {
        self.buffer.as_ref().get(field::UNIT_ID).copied().unwrap_or(0)
    }

    /// Bytes of the whole frame, header included.
    pub fn frame_len(&self) -> usize {
        field::BEFORE_LENGTH.end + usize::from(self.length())
    }

    /// The PDU: function code and data, never empty.
    ///
    /// Fails as [`Frame::check_len`] does when the buffer does not hold a
    /// whole, well-framed frame.
    pub fn pdu(&self) -> Result<&[u8], Error> {
        self.check_len()?;
        // After check_len the buffer holds frame_len() >= PDU_START + 1 bytes,
        // so neither split fails; if one did, the frame would be cut short.
        let Some((frame, _next)) = self.buffer.as_ref().split_at_checked(self.frame_len()) else {
            return Err(Error::Truncated);
        };
        let Some((_header, pdu)) = frame.split_at_checked(field::PDU_START) else {
            return Err(Error::Truncated);
        };
        Ok(pdu)
    }
}

impl<T: AsRef<[u8]> + AsMut<[u8]>> Frame<T> {
    /// Sets the transaction id.
    pub fn set_transaction_id(&mut self, value: u16) {
        put_be_u16(self.buffer.as_mut(), field::TRANSACTION_ID, value);
    }

    /// Sets the protocol id.
    pub fn set_protocol_id(&mut self, value: u16) {
        put_be_u16(self.buffer.as_mut(), field::PROTOCOL_ID, value);
    }

    /// Sets the length field.
    pub fn set_length(&mut self, value: u16) {
        put_be_u16(self.buffer.as_mut(), field::LENGTH, value);
    }

    /// Sets the unit id.
    pub fn set_unit_id(&mut self, value: u8) {
        if let Some(b) = self.buffer.as_mut().get_mut(field::UNIT_ID) {
            *b = value;
        }
    }

    /// The bytes after the header, where a PDU is emitted (up to [`MAX_PDU_LEN`]).
    ///
    /// Empty when the buffer has no room past the header: then no PDU fits,
    /// and an `emit` into it returns `None`.
    pub fn payload_mut(&mut self) -> &mut [u8] {
        let data = self.buffer.as_mut();
        let end = data.len().min(MAX_ADU_LEN);
        data.get_mut(field::PDU_START..end).unwrap_or(&mut [])
    }
}

/// The fields of an MBAP header, without the length (which the PDU decides).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Header {
    /// Pairs a reply with its request.
    pub transaction_id: u16,
    /// 0 for Modbus.
    pub protocol_id: u16,
    /// The addressed unit (slave) behind the server.
    pub unit_id: u8,
}

impl Header {
    /// Reads the header of a checked frame.
    pub fn parse<T: AsRef<[u8]>>(frame: &Frame<T>) -> Self {
        Self { transaction_id: frame.transaction_id(), protocol_id: frame.protocol_id(), unit_id: frame.unit_id() }
    }

    /// Writes the header for a PDU of `pdu_len` bytes that is already in place.
    /// Returns the frame's length, or `None` if the PDU is empty or too long.
    pub fn emit<T: AsRef<[u8]> + AsMut<[u8]>>(&self, frame: &mut Frame<T>, pdu_len: usize) -> Option<usize> {
        if pdu_len == 0 || pdu_len > MAX_PDU_LEN || frame.buffer.as_ref().len() < HEADER_LEN + pdu_len {
            return None;
        }
        // pdu_len <= MAX_PDU_LEN = 253, so the sum fits the field.
        let length = u16::try_from(pdu_len + 1).ok()?;
        frame.set_transaction_id(self.transaction_id);
        frame.set_protocol_id(self.protocol_id);
        frame.set_length(length);
        frame.set_unit_id(self.unit_id);
        Some(HEADER_LEN + pdu_len)
    }
}

/// Where the next frame in `stream` ends: `Ok(Some(len))` for a whole frame,
/// `Ok(None)` when more bytes are needed, `Err` when the stream is lost.
pub fn next_frame_len(stream: &[u8]) -> Result<Option<usize>, Error> {
    let frame = Frame::new_unchecked(stream);
    match frame.check_len() {
        Ok(()) => Ok(Some(frame.frame_len())),
        Err(Error::Truncated) => Ok(None),
        Err(e) => Err(e),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    // Read Holding Registers, as sent by pymodbus 3.16 `read_holding_registers(256, count=3)`:
    static READ_VERSION: [u8; 12] = [
        0x00, 0x01, // transaction id 1
        0x00, 0x00, // protocol id 0
        0x00, 0x06, // length: unit + 5 PDU bytes
        0x01, // unit id 1
        0x03, // function 03 read holding registers
        0x01, 0x00, // start 256
        0x00, 0x03, // quantity 3
    ];

    #[test]
    fn parses_fields() {
        let frame = Frame::new_checked(&READ_VERSION[..]).unwrap();
        assert_eq!(frame.transaction_id(), 1);
        assert_eq!(frame.protocol_id(), 0);
        assert_eq!(frame.length(), 6);
        assert_eq!(frame.unit_id(), 1);
        assert_eq!(frame.frame_len(), 12);
        assert_eq!(frame.pdu(), Ok(&[0x03, 0x01, 0x00, 0x00, 0x03][..]));
    }

    #[test]
    fn every_prefix_is_truncated() {
        for n in 0..READ_VERSION.len() {
            assert_eq!(next_frame_len(&READ_VERSION[..n]), Ok(None), "prefix {n}");
        }
        assert_eq!(next_frame_len(&READ_VERSION), Ok(Some(12)));
    }

    #[test]
    fn trailing_bytes_belong_to_the_next_frame() {
        let mut two = [0u8; 24];
        two[..12].copy_from_slice(&READ_VERSION);
        two[12..].copy_from_slice(&READ_VERSION);
        assert_eq!(next_frame_len(&two), Ok(Some(12)));
        let frame = Frame::new_checked(&two[..]).unwrap();
        assert_eq!(frame.pdu().map(<[u8]>::len), Ok(5));
    }

    #[test]
    fn length_limits() {
        let header = |len: u16| {
            let [hi, lo] = len.to_be_bytes();
            [0, 0, 0, 0, hi, lo]
        };
        assert_eq!(next_frame_len(&header(0)), Err(Error::BadLength(0)));
        assert_eq!(next_frame_len(&header(1)), Err(Error::BadLength(1)));
        assert_eq!(next_frame_len(&header(2)), Ok(None));
        assert_eq!(next_frame_len(&header(254)), Ok(None));
        assert_eq!(next_frame_len(&header(255)), Err(Error::BadLength(255)));
        assert_eq!(next_frame_len(&header(u16::MAX)), Err(Error::BadLength(u16::MAX)));
        let mut max = [0u8; MAX_ADU_LEN];
        max[..6].copy_from_slice(&header(254));
        assert_eq!(next_frame_len(&max), Ok(Some(MAX_ADU_LEN)));
        assert_eq!(next_frame_len(&max[..MAX_ADU_LEN - 1]), Ok(None));
        let mut min = [0u8; 8];
        min[..6].copy_from_slice(&header(2));
        assert_eq!(next_frame_len(&min), Ok(Some(8)));
        assert_eq!(Frame::new_checked(&min[..]).unwrap().pdu(), Ok(&[0][..]));
    }

    #[test]
    fn unchecked_accessors_do_not_panic() {
        let frame = Frame::new_unchecked(&[0x12u8][..]);
        assert_eq!(frame.transaction_id(), 0);
        assert_eq!(frame.unit_id(), 0);
        assert_eq!(frame.pdu(), Err(Error::Truncated));
    }

    #[test]
    fn pdu_of_a_frame_that_is_not_whole_is_an_error() {
        for n in 0..READ_VERSION.len() {
            assert_eq!(Frame::new_unchecked(&READ_VERSION[..n]).pdu(), Err(Error::Truncated), "prefix {n}");
        }
        // A length field of 1 counts the unit id only: no function code.
        let no_function = [0, 1, 0, 0, 0, 1, 1, 0x03];
        assert_eq!(Frame::new_unchecked(&no_function[..]).pdu(), Err(Error::BadLength(1)));
        let mut too_long = [0u8; 300];
        too_long[4..6].copy_from_slice(&255u16.to_be_bytes());
        assert_eq!(Frame::new_unchecked(&too_long[..]).pdu(), Err(Error::BadLength(255)));
    }

    #[test]
    fn emit_round_trip() {
        let mut buf = [0xa5u8; 16];
        buf[7..12].copy_from_slice(&[0x03, 0x01, 0x00, 0x00, 0x03]);
        let header = Header { transaction_id: 1, protocol_id: 0, unit_id: 1 };
        let mut frame = Frame::new_unchecked(&mut buf[..]);
        assert_eq!(header.emit(&mut frame, 5), Some(12));
        assert_eq!(&buf[..12], &READ_VERSION);
        assert_eq!(buf[12], 0xa5, "nothing written past the frame");
        let frame = Frame::new_checked(&buf[..]).unwrap();
        assert_eq!(Header::parse(&frame), header);
    }

    #[test]
    fn emit_refuses_what_does_not_fit() {
        let header = Header { transaction_id: 0, protocol_id: 0, unit_id: 0 };
        let mut small = [0u8; 8];
        assert_eq!(header.emit(&mut Frame::new_unchecked(&mut small[..]), 2), None);
        let mut big = [0u8; 300];
        assert_eq!(header.emit(&mut Frame::new_unchecked(&mut big[..]), 0), None);
        assert_eq!(header.emit(&mut Frame::new_unchecked(&mut big[..]), MAX_PDU_LEN + 1), None);
        assert_eq!(header.emit(&mut Frame::new_unchecked(&mut big[..]), MAX_PDU_LEN), Some(MAX_ADU_LEN));
    }
}
