//! The client side of Read Holding Registers (FC 03): the request a client
//! sends, and the strict check of the reply it gets back (Modbus Application
//! Protocol V1.1b3, 6.3; Modbus Messaging on TCP/IP Implementation Guide
//! V1.0b, 3.1.3). The robot link polls its controller with it.
//!
//! Contract: [`ReadHoldingRegisters::parse_reply`] never panics on any
//! input; it takes one whole frame (as [`crate::mbap::next_frame_len`]
//! delimits it from the stream, by the length field only) and accepts it
//! only if every field is the one the request asks for:
//!
//! - the transaction id is the request's, the protocol id is 0;
//! - the length field counts exactly the bytes given (no more, no fewer);
//! - the unit id is the request's;
//! - the function code is 03, or 83 with one exception code;
//! - the byte count is 2 x the quantity asked for, and that many bytes follow.

use core::fmt;

use crate::Exception;
use crate::mbap::{self, Frame, HEADER_LEN, Header, MODBUS_PROTOCOL_ID};
use crate::pdu::{EXCEPTION_FLAG, FunctionCode, MAX_READ_REGISTERS, Request};

/// Bytes of a Read Holding Registers request ADU: the header and a 5-byte PDU.
pub const REQUEST_ADU_LEN: usize = HEADER_LEN + 5;

/// Why a reply is not the answer to the request; each is a failed poll.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ReplyError {
    /// The frame is not whole (the bytes end before the length field says)
    /// or its length field is outside the valid range: framing lost.
    Framing(mbap::Error),
    /// The bytes given go on past the frame the length field delimits.
    TrailingBytes,
    /// Not the transaction this request carried (a late or foreign reply).
    TransactionId(u16),
    /// A protocol id other than 0.
    ProtocolId(u16),
    /// Another unit answered.
    UnitId(u8),
    /// A function code other than 03 or 83.
    Function(u8),
    /// The server answered with an exception (any code, listed or not).
    Exception(Exception),
    /// An exception reply whose PDU is not exactly the code and one byte.
    BadException,
    /// The byte count is not 2 x the quantity, or not the bytes that follow.
    ByteCount(u8),
}

impl fmt::Display for ReplyError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Framing(e) => write!(f, "reply framing: {e}"),
            Self::TrailingBytes => f.write_str("bytes past the reply frame"),
            Self::TransactionId(id) => write!(f, "reply to another transaction ({id})"),
            Self::ProtocolId(id) => write!(f, "reply protocol id {id}"),
            Self::UnitId(unit) => write!(f, "reply from unit {unit}"),
            Self::Function(code) => write!(f, "reply function code {code:#04x}"),
            Self::Exception(e) => write!(f, "reply: {e}"),
            Self::BadException => f.write_str("malformed exception reply"),
            Self::ByteCount(count) => write!(f, "reply byte count {count}"),
        }
    }
}

impl core::error::Error for ReplyError {}

impl From<mbap::Error> for ReplyError {
    fn from(e: mbap::Error) -> Self {
        Self::Framing(e)
    }
}

/// One Read Holding Registers transaction, as a client sends it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ReadHoldingRegisters {
    pub transaction_id: u16,
    pub unit_id: u8,
    pub start: u16,
    /// 1..=125 ([`MAX_READ_REGISTERS`]).
    pub quantity: u16,
}

impl ReadHoldingRegisters {
    /// Bytes [`ReadHoldingRegisters::emit`] writes.
    pub const fn buffer_len(&self) -> usize {
        REQUEST_ADU_LEN
    }

    /// Writes the request ADU into `buf`; returns its length, or `None` if
    /// `buf` is shorter than [`REQUEST_ADU_LEN`] or the quantity is outside
    /// 1..=125 (no server would answer it).
    pub fn emit(&self, buf: &mut [u8]) -> Option<usize> {
        if !(1..=MAX_READ_REGISTERS).contains(&self.quantity) {
            return None;
        }
        let adu = buf.get_mut(..REQUEST_ADU_LEN)?;
        let mut frame = Frame::new_unchecked(adu);
        let pdu_len =
            Request::ReadHoldingRegisters { start: self.start, quantity: self.quantity }.emit(frame.payload_mut())?;
        let header =
            Header { transaction_id: self.transaction_id, protocol_id: MODBUS_PROTOCOL_ID, unit_id: self.unit_id };
        header.emit(&mut frame, pdu_len)
    }

    /// Bytes of the reply to this request: the header, function code, byte
    /// count and 2 bytes per register.
    pub const fn reply_len(&self) -> usize {
        HEADER_LEN + 2 + 2 * self.quantity as usize
    }

    /// Checks `adu`, exactly one whole reply frame, against this request
    /// (the module's list) and returns the registers it carries.
    pub fn parse_reply<'a>(&self, adu: &'a [u8]) -> Result<Registers<'a>, ReplyError> {
        let frame = Frame::new_checked(adu)?;
        if frame.frame_len() != adu.len() {
            return Err(ReplyError::TrailingBytes);
        }
        if frame.transaction_id() != self.transaction_id {
            return Err(ReplyError::TransactionId(frame.transaction_id()));
        }
        if frame.protocol_id() != MODBUS_PROTOCOL_ID {
            return Err(ReplyError::ProtocolId(frame.protocol_id()));
        }
        if frame.unit_id() != self.unit_id {
            return Err(ReplyError::UnitId(frame.unit_id()));
        }
        // The frame is all of `adu` (checked above): its PDU is what follows the header.
        let pdu = adu.get(HEADER_LEN..).unwrap_or_default();
        let function = u8::from(FunctionCode::ReadHoldingRegisters);
        match pdu {
            [code, data @ ..] if *code == function => {
                let [count, values @ ..] = data else { return Err(ReplyError::ByteCount(0)) };
                if usize::from(*count) != 2 * usize::from(self.quantity) || values.len() != usize::from(*count) {
                    return Err(ReplyError::ByteCount(*count));
                }
                Ok(Registers { bytes: values })
            }
            [code, exception] if *code == function | EXCEPTION_FLAG => {
                Err(ReplyError::Exception(Exception::from(*exception)))
            }
            [code, ..] if *code == function | EXCEPTION_FLAG => Err(ReplyError::BadException),
            [code, ..] => Err(ReplyError::Function(*code)),
            // pdu() is never empty; if it were, no function code answered.
            [] => Err(ReplyError::Function(0)),
        }
    }
}

/// The registers of a checked reply: big-endian pairs, as many as asked for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Registers<'a> {
    bytes: &'a [u8],
}

impl Registers<'_> {
    /// How many registers.
    pub const fn len(&self) -> usize {
        self.bytes.len() / 2
    }

    /// Whether there are none (never, for a checked reply).
    pub const fn is_empty(&self) -> bool {
        self.bytes.len() < 2
    }

    /// The registers in order.
    pub fn iter(&self) -> impl Iterator<Item = u16> + '_ {
        self.bytes.as_chunks::<2>().0.iter().map(|pair| u16::from_be_bytes(*pair))
    }

    /// Copies the registers into `out`; returns how many (the lesser length).
    pub fn copy_to(&self, out: &mut [u16]) -> usize {
        out.iter_mut().zip(self.iter()).map(|(slot, value)| *slot = value).count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const REQUEST: ReadHoldingRegisters =
        ReadHoldingRegisters { transaction_id: 0x1234, unit_id: 1, start: 256, quantity: 3 };

    // The reply to REQUEST, as pymodbus 3.x's server sends it for registers 256-258 = 2, 11, 3:
    static REPLY: [u8; 15] = [
        0x12, 0x34, // transaction id 0x1234
        0x00, 0x00, // protocol id 0
        0x00, 0x09, // length: unit + 8 PDU bytes
        0x01, // unit id 1
        0x03, // function 03
        0x06, // byte count 6 = 2 x 3
        0x00, 0x02, 0x00, 0x0b, 0x00, 0x03, // 2, 11, 3
    ];

    #[test]
    fn emits_the_request() {
        let mut buf = [0xa5u8; 16];
        assert_eq!(REQUEST.emit(&mut buf), Some(REQUEST_ADU_LEN));
        assert_eq!(&buf[..REQUEST_ADU_LEN], &[0x12, 0x34, 0x00, 0x00, 0x00, 0x06, 0x01, 0x03, 0x01, 0x00, 0x00, 0x03]);
        assert_eq!(buf[REQUEST_ADU_LEN], 0xa5, "nothing past the request");
        assert_eq!(REQUEST.emit(&mut buf[..REQUEST_ADU_LEN - 1]), None);
        // The server's own parser reads it back as the same request.
        let frame = Frame::new_checked(&buf[..REQUEST_ADU_LEN]).unwrap();
        assert_eq!(Request::parse(frame.pdu().unwrap()), Ok(Request::ReadHoldingRegisters { start: 256, quantity: 3 }));
    }

    #[test]
    fn quantity_limits() {
        let mut buf = [0u8; 16];
        for (quantity, ok) in [(0, false), (1, true), (125, true), (126, false)] {
            let request = ReadHoldingRegisters { quantity, ..REQUEST };
            assert_eq!(request.emit(&mut buf).is_some(), ok, "quantity {quantity}");
        }
    }

    #[test]
    fn parses_the_reply() {
        let registers = REQUEST.parse_reply(&REPLY).unwrap();
        assert_eq!(registers.len(), 3);
        assert_eq!(registers.iter().collect::<Vec<_>>(), [2, 11, 3]);
        let mut out = [0u16; 4];
        assert_eq!(registers.copy_to(&mut out), 3);
        assert_eq!(out, [2, 11, 3, 0]);
        assert_eq!(REQUEST.reply_len(), REPLY.len());
    }

    #[test]
    fn every_prefix_is_an_error() {
        for n in 0..REPLY.len() {
            assert!(REQUEST.parse_reply(&REPLY[..n]).is_err(), "prefix {n}");
        }
    }

    fn corrupt(at: usize, value: u8) -> Result<Vec<u16>, ReplyError> {
        let mut reply = REPLY;
        reply[at] = value;
        REQUEST.parse_reply(&reply).map(|r| r.iter().collect())
    }

    #[test]
    fn every_field_is_checked() {
        assert_eq!(corrupt(1, 0x35), Err(ReplyError::TransactionId(0x1235)));
        assert_eq!(corrupt(3, 1), Err(ReplyError::ProtocolId(1)));
        assert_eq!(corrupt(5, 0x0a), Err(ReplyError::Framing(mbap::Error::Truncated)), "length one too long");
        assert_eq!(corrupt(5, 0x08), Err(ReplyError::TrailingBytes), "length one too short");
        assert_eq!(corrupt(5, 0x01), Err(ReplyError::Framing(mbap::Error::BadLength(1))));
        assert_eq!(corrupt(6, 2), Err(ReplyError::UnitId(2)));
        assert_eq!(corrupt(7, 0x04), Err(ReplyError::Function(0x04)));
        assert_eq!(corrupt(8, 0x04), Err(ReplyError::ByteCount(4)));
        assert_eq!(corrupt(8, 0x07), Err(ReplyError::ByteCount(7)));
        // The values themselves are the server's business.
        assert_eq!(corrupt(14, 0x04), Ok(vec![2, 11, 4]));
    }

    #[test]
    fn a_reply_of_another_quantity_is_refused() {
        let more = ReadHoldingRegisters { quantity: 4, ..REQUEST };
        assert_eq!(more.parse_reply(&REPLY), Err(ReplyError::ByteCount(6)));
        let fewer = ReadHoldingRegisters { quantity: 2, ..REQUEST };
        assert_eq!(fewer.parse_reply(&REPLY), Err(ReplyError::ByteCount(6)));
    }

    #[test]
    fn exceptions() {
        // pymodbus's reply to a read outside its datastore: exception 02.
        let exception = [0x12, 0x34, 0, 0, 0, 3, 1, 0x83, 0x02];
        assert_eq!(REQUEST.parse_reply(&exception), Err(ReplyError::Exception(Exception::IllegalDataAddress)));
        let unknown = [0x12, 0x34, 0, 0, 0, 3, 1, 0x83, 0x0a];
        assert_eq!(REQUEST.parse_reply(&unknown), Err(ReplyError::Exception(Exception::Unknown(0x0a))));
        let long = [0x12, 0x34, 0, 0, 0, 4, 1, 0x83, 0x02, 0];
        assert_eq!(REQUEST.parse_reply(&long), Err(ReplyError::BadException));
        let short = [0x12, 0x34, 0, 0, 0, 2, 1, 0x83];
        assert_eq!(REQUEST.parse_reply(&short), Err(ReplyError::BadException));
        let other = [0x12, 0x34, 0, 0, 0, 3, 1, 0x84, 0x02];
        assert_eq!(REQUEST.parse_reply(&other), Err(ReplyError::Function(0x84)));
        let no_count = [0x12, 0x34, 0, 0, 0, 2, 1, 0x03];
        assert_eq!(REQUEST.parse_reply(&no_count), Err(ReplyError::ByteCount(0)));
    }

    #[test]
    fn trailing_bytes_are_refused() {
        let mut two = REPLY.to_vec();
        two.push(0);
        assert_eq!(REQUEST.parse_reply(&two), Err(ReplyError::TrailingBytes));
    }

    #[test]
    fn the_largest_reply() {
        let request = ReadHoldingRegisters { quantity: MAX_READ_REGISTERS, ..REQUEST };
        let mut reply = vec![0x12, 0x34, 0, 0, 0, 253, 1, 0x03, 250];
        reply.extend((0..125u16).flat_map(u16::to_be_bytes));
        assert_eq!(request.reply_len(), reply.len());
        assert!(reply.len() <= mbap::MAX_ADU_LEN);
        let values: Vec<u16> = request.parse_reply(&reply).unwrap().iter().collect();
        assert_eq!(values, (0..125).collect::<Vec<_>>());
    }

    mod prop {
        use proptest::prelude::*;

        use super::*;

        proptest! {
            #[test]
            fn never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..300), quantity in 0u16..130) {
                let request = ReadHoldingRegisters { quantity, ..REQUEST };
                let _ = request.parse_reply(&bytes);
            }

            #[test]
            fn any_one_byte_corruption_is_caught_or_a_value(at in 0usize..15, value in any::<u8>()) {
                let mut reply = REPLY;
                let changed = reply[at] != value;
                reply[at] = value;
                let parsed = REQUEST.parse_reply(&reply);
                if changed && at < 9 {
                    prop_assert!(parsed.is_err(), "a header, function or count byte changed: {:?}", parsed);
                } else {
                    prop_assert!(parsed.is_ok());
                }
            }

            #[test]
            fn a_reply_made_for_the_request_parses(
                transaction_id in any::<u16>(), unit_id in any::<u8>(), start in any::<u16>(),
                values in proptest::collection::vec(any::<u16>(), 1..=125),
            ) {
                let quantity = values.len() as u16;
                let request = ReadHoldingRegisters { transaction_id, unit_id, start, quantity };
                let mut reply = Vec::new();
                reply.extend(transaction_id.to_be_bytes());
                reply.extend([0, 0]);
                reply.extend((3 + 2 * quantity).to_be_bytes());
                reply.extend([unit_id, 0x03, (2 * quantity) as u8]);
                reply.extend(values.iter().flat_map(|v| v.to_be_bytes()));
                let parsed: Vec<u16> = request.parse_reply(&reply).unwrap().iter().collect();
                prop_assert_eq!(parsed, values);
            }
        }
    }
}
