//! Modbus TCP framing written from the specification alone (Modbus Messaging
//! on TCP/IP Implementation Guide V1.0b, 3.1.3), never from the library's
//! code: the unit tests, the fuzz targets and the system tests check the
//! server's framing against it.
//!
//! ```text
//! | transaction id (2) | protocol id (2) | length = unit id + PDU (2) | unit id (1) | PDU |
//! ```
//!
//! A frame is delimited by its length field only: 6 bytes, then `length`
//! more, with `length` in 2..=254 (a unit id and a PDU of 1..=253 bytes). A
//! length field out of that range loses the stream: nothing after it can be
//! framed, and the server closes the connection once the frames before it
//! are answered. A frame whose protocol id is not 0 is not Modbus: the server
//! skips it without a reply and carries on.

use std::ops::RangeInclusive;

/// Bytes up to and including the length field.
pub const LENGTH_END: usize = 6;
/// The MBAP header: transaction id, protocol id, length, unit id.
pub const HEADER_LEN: usize = 7;
/// The length fields a frame may carry: a unit id and a PDU of 1..=253 bytes.
pub const LENGTH_RANGE: RangeInclusive<u16> = 2..=254;
/// The length fields a reply may carry: a reply's PDU has at least a
/// function code and one byte (an exception code, a byte count or an echo).
pub const REPLY_LENGTH_RANGE: RangeInclusive<u16> = 3..=254;
/// The longest frame: 6 bytes and the longest length.
pub const MAX_ADU_LEN: usize = 260;
/// The protocol id of Modbus.
pub const MODBUS_PROTOCOL_ID: u16 = 0;

/// A frame around `pdu`, its length field `pdu.len() + 1` whatever that is
/// (a test may want one out of range).
pub fn adu(transaction_id: u16, protocol_id: u16, unit_id: u8, pdu: &[u8]) -> Vec<u8> {
    let length = u16::try_from(pdu.len() + 1).expect("a PDU of at most 65 534 bytes");
    let mut frame = Vec::with_capacity(HEADER_LEN + pdu.len());
    frame.extend_from_slice(&transaction_id.to_be_bytes());
    frame.extend_from_slice(&protocol_id.to_be_bytes());
    frame.extend_from_slice(&length.to_be_bytes());
    frame.push(unit_id);
    frame.extend_from_slice(pdu);
    frame
}

/// The length field of the frame `stream` starts with, once its 6 bytes are there.
pub fn length_field(stream: &[u8]) -> Option<u16> {
    match stream.get(4..LENGTH_END)? {
        [hi, lo] => Some(u16::from_be_bytes([*hi, *lo])),
        _ => None,
    }
}

/// The protocol id of a frame, once its 4 bytes are there.
pub fn protocol_id(frame: &[u8]) -> Option<u16> {
    match frame.get(2..4)? {
        [hi, lo] => Some(u16::from_be_bytes([*hi, *lo])),
        _ => None,
    }
}

/// What the start of a stream holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Next {
    /// Not yet a whole frame: fewer than 6 bytes, or fewer than the length
    /// field announces.
    Incomplete,
    /// A whole frame of this many bytes.
    Frame(usize),
    /// A length field out of [`LENGTH_RANGE`]: the stream is lost here, as
    /// soon as the 6 bytes up to it are there.
    BadLength(u16),
}

/// Frames the start of `stream`.
pub fn next(stream: &[u8]) -> Next {
    let Some(length) = length_field(stream) else { return Next::Incomplete };
    if !LENGTH_RANGE.contains(&length) {
        return Next::BadLength(length);
    }
    let len = LENGTH_END + usize::from(length);
    if stream.len() < len { Next::Incomplete } else { Next::Frame(len) }
}

/// A client's byte stream, framed.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Frames<'a> {
    /// Every whole frame, in order, whatever its protocol id.
    pub frames: Vec<&'a [u8]>,
    /// The length field that lost the stream after `frames`, if one did.
    pub bad_length: Option<u16>,
    /// What follows the last whole frame when the stream is not lost: the
    /// start of a frame that never came whole.
    pub rest: &'a [u8],
}

impl<'a> Frames<'a> {
    /// The frames a server answers, one reply each and in order: the Modbus
    /// frames (protocol id 0).
    pub fn requests(&self) -> Vec<&'a [u8]> {
        self.frames.iter().copied().filter(|frame| is_modbus(frame)).collect()
    }

    /// How many frames a server skips unanswered (another protocol id).
    pub fn skipped(&self) -> usize {
        self.frames.iter().filter(|frame| !is_modbus(frame)).count()
    }
}

/// Whether a whole frame is Modbus (protocol id 0).
pub fn is_modbus(frame: &[u8]) -> bool {
    protocol_id(frame) == Some(MODBUS_PROTOCOL_ID)
}

/// Frames a client's byte stream as the specification says.
pub fn split(mut stream: &[u8]) -> Frames<'_> {
    let mut frames = Vec::new();
    loop {
        match next(stream) {
            Next::Frame(len) => {
                let (frame, rest) = stream.split_at(len);
                frames.push(frame);
                stream = rest;
            }
            Next::Incomplete => return Frames { frames, bad_length: None, rest: stream },
            Next::BadLength(length) => return Frames { frames, bad_length: Some(length), rest: &[] },
        }
    }
}

/// Splits what a server sent into its replies. A server sends whole frames
/// only, each with a length field in [`REPLY_LENGTH_RANGE`]: panics otherwise.
pub fn split_replies(mut bytes: &[u8]) -> Vec<Vec<u8>> {
    let mut replies = Vec::new();
    while !bytes.is_empty() {
        let length = length_field(bytes).unwrap_or_else(|| panic!("a reply cut short: {bytes:02x?}"));
        assert!(REPLY_LENGTH_RANGE.contains(&length), "a reply with length field {length}: {bytes:02x?}");
        let (reply, rest) = bytes
            .split_at_checked(LENGTH_END + usize::from(length))
            .unwrap_or_else(|| panic!("the reply stream ends with a partial frame: {bytes:02x?}"));
        replies.push(reply.to_vec());
        bytes = rest;
    }
    replies
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures::PYMODBUS;

    /// A header announcing `length`.
    fn header(length: u16) -> Vec<u8> {
        let [hi, lo] = length.to_be_bytes();
        vec![0x00, 0x01, 0x00, 0x00, hi, lo]
    }

    #[test]
    fn the_fixtures_frame_whole_alone_and_pipelined() {
        for fixture in &PYMODBUS {
            assert_eq!(next(fixture.request), Next::Frame(fixture.request.len()), "{}", fixture.name);
            assert_eq!(split_replies(fixture.reply), [fixture.reply], "{}", fixture.name);
        }
        let all: Vec<u8> = PYMODBUS.iter().flat_map(|f| f.request.iter().copied()).collect();
        let framed = split(&all);
        assert_eq!(framed.frames, PYMODBUS.map(|f| f.request));
        assert_eq!((framed.bad_length, framed.rest, framed.skipped()), (None, &[][..], 0));
    }

    #[test]
    fn every_prefix_is_incomplete() {
        let request = PYMODBUS[0].request;
        for n in 0..request.len() {
            assert_eq!(next(&request[..n]), Next::Incomplete, "prefix {n}");
            assert_eq!(split(&request[..n]), Frames { rest: &request[..n], ..Frames::default() });
        }
    }

    #[test]
    fn a_length_out_of_range_is_seen_with_its_6_bytes() {
        for length in [0, 1, 255, 256, u16::MAX] {
            assert_eq!(next(&header(length)), Next::BadLength(length));
            assert_eq!(next(&header(length)[..5]), Next::Incomplete);
        }
        for length in [2, 254] {
            assert_eq!(next(&header(length)), Next::Incomplete);
        }
        let stream = [PYMODBUS[0].request, &header(1), PYMODBUS[1].request].concat();
        let framed = split(&stream);
        assert_eq!((framed.frames, framed.bad_length), (vec![PYMODBUS[0].request], Some(1)));
    }

    #[test]
    fn the_shortest_and_longest_frames() {
        let shortest = adu(1, 0, 1, &[0x07]);
        let longest = adu(2, 0, 1, &[0x64; 253]);
        assert_eq!((next(&shortest), next(&longest)), (Next::Frame(8), Next::Frame(MAX_ADU_LEN)));
        assert_eq!(next(&adu(3, 0, 1, &[0x64; 254])), Next::BadLength(255));
        assert_eq!(next(&adu(4, 0, 1, &[])), Next::BadLength(1));
    }

    #[test]
    fn frames_of_another_protocol_are_framed_and_not_requests() {
        let foreign = adu(9, 1, 1, &[0x03, 0x01, 0x00, 0x00, 0x03]);
        let stream = [&foreign[..], PYMODBUS[1].request].concat();
        let framed = split(&stream);
        assert_eq!(framed.frames, [&foreign[..], PYMODBUS[1].request]);
        assert_eq!((framed.requests(), framed.skipped()), (vec![PYMODBUS[1].request], 1));
    }

    #[test]
    fn adu_writes_the_header_the_fixtures_show() {
        let request = PYMODBUS[0].request;
        assert_eq!(adu(1, 0, 1, &request[HEADER_LEN..]), request);
    }

    #[test]
    #[should_panic(expected = "partial frame")]
    fn a_reply_stream_cut_short_fails() {
        let reply = PYMODBUS[0].reply;
        split_replies(&reply[..reply.len() - 1]);
    }

    #[test]
    #[should_panic(expected = "length field 2")]
    fn a_reply_without_a_byte_after_its_function_code_fails() {
        split_replies(&adu(1, 0, 1, &[0x83]));
    }
}
