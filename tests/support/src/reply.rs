//! What a reply to a request may be, written from the specification alone
//! (Modbus Application Protocol V1.1b3, 6.1-6.12 and 7; the Implementation
//! Guide for the header): the fuzz targets and the property test check every
//! reply the server gives against it.

use crate::framer::{HEADER_LEN, length_field};

/// The function codes the server implements: read coils, read holding
/// registers, write single coil, write single register, write multiple
/// coils, write multiple registers.
pub const FUNCTIONS: [u8; 6] = [0x01, 0x03, 0x05, 0x06, 0x0f, 0x10];
/// Those of them that write.
pub const WRITE_FUNCTIONS: [u8; 4] = [0x05, 0x06, 0x0f, 0x10];

/// What the server was told to refuse.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Refusals {
    /// Answer only this unit id (and 0 and 0xFF); another gets exception 0B
    /// (gateway target device failed to respond).
    pub unit_id: Option<u8>,
    /// The client may not write: its write functions get exception 01.
    pub read_only: bool,
}

/// How the server answered, as [`check_reply`] found it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Answer {
    /// An exception the specification allows for that request, with its code.
    Exception(u8),
    /// The normal response of a read (FC 01 or FC 03).
    Read,
    /// The normal response of a write: the write was acknowledged.
    Write,
}

/// Checks `reply` against its `request`, both whole Modbus frames (protocol
/// id 0): the header echoed with a correct length field, and either an
/// exception the specification allows for that request and `refusals`, or
/// the normal response of its function (byte counts, echoes, quantities
/// within the protocol's limits). Panics, naming what is wrong, otherwise.
pub fn check_reply(request: &[u8], reply: &[u8], refusals: &Refusals) -> Answer {
    assert!(request.len() > HEADER_LEN, "a request without a PDU: {request:02x?}");
    assert!(reply.len() > HEADER_LEN + 1, "a reply too short: {reply:02x?} to {request:02x?}");
    assert_eq!(reply[..2], request[..2], "the transaction id of {reply:02x?} to {request:02x?}");
    assert_eq!(reply[2..4], [0, 0], "the protocol id of {reply:02x?} to {request:02x?}");
    assert_eq!(length_field(reply).map(usize::from), Some(reply.len() - 6), "the length field of {reply:02x?}");
    assert_eq!(reply[6], request[6], "the unit id of {reply:02x?} to {request:02x?}");
    let (pdu, answer) = (&request[HEADER_LEN..], &reply[HEADER_LEN..]);
    let function = pdu[0];
    let known = FUNCTIONS.contains(&function);
    let refused_write = refusals.read_only && WRITE_FUNCTIONS.contains(&function);
    let other_unit = refusals.unit_id.is_some_and(|id| ![id, 0, 0xff].contains(&request[6]));
    if answer[0] == function | 0x80 && answer.len() == 2 {
        let allowed: &[u8] = match (other_unit, known && !refused_write) {
            (true, _) => &[0x0b],
            (false, false) => &[0x01],
            (false, true) => &[0x02, 0x03],
        };
        assert!(allowed.contains(&answer[1]), "exception {:#04x} to {pdu:02x?} ({refusals:?})", answer[1]);
        return Answer::Exception(answer[1]);
    }
    assert!(known && !refused_write && !other_unit, "a normal reply {answer:02x?} to {pdu:02x?} ({refusals:?})");
    assert_eq!(answer[0], function, "the function code of {answer:02x?} to {pdu:02x?}");
    assert!(pdu.len() >= 5, "a normal reply {answer:02x?} to a PDU cut short: {pdu:02x?}");
    if [0x01, 0x03, 0x05, 0x06].contains(&function) {
        assert_eq!(pdu.len(), 5, "a normal reply {answer:02x?} to a PDU of the wrong length: {pdu:02x?}");
    }
    let quantity = usize::from(u16::from_be_bytes([pdu[3], pdu[4]]));
    match function {
        0x01 | 0x03 => {
            let (limit, count) = if function == 0x01 { (2000, quantity.div_ceil(8)) } else { (125, 2 * quantity) };
            assert!((1..=limit).contains(&quantity), "a read of {quantity} answered: {pdu:02x?}");
            assert_eq!(usize::from(answer[1]), count, "the byte count of a read of {quantity}: {answer:02x?}");
            assert_eq!(answer.len(), 2 + count, "the length of a read's reply: {answer:02x?}");
            Answer::Read
        }
        0x05 | 0x06 => {
            if function == 0x05 {
                assert!(pdu[3..] == [0xff, 0x00] || pdu[3..] == [0, 0], "coil value {:02x?} accepted", &pdu[3..]);
            }
            assert_eq!(answer, pdu, "a single write echoes the request");
            Answer::Write
        }
        _ => {
            let (limit, count) = if function == 0x0f { (1968, quantity.div_ceil(8)) } else { (123, 2 * quantity) };
            assert!((1..=limit).contains(&quantity), "a write of {quantity} acknowledged: {pdu:02x?}");
            assert_eq!(pdu.get(5).map(|&n| usize::from(n)), Some(count), "the byte count of {pdu:02x?}");
            assert_eq!(pdu.len(), 6 + count, "the values of {pdu:02x?}");
            assert_eq!(answer, &pdu[..5], "a multiple write echoes its start and quantity");
            Answer::Write
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures::PYMODBUS;
    use crate::framer::adu;

    const ALL: Refusals = Refusals { unit_id: None, read_only: false };

    #[test]
    fn the_captured_replies_pass() {
        let answers = PYMODBUS.map(|f| check_reply(f.request, f.reply, &ALL));
        use Answer::{Read, Write};
        assert_eq!(answers, [Read, Read, Write, Write, Write, Write]);
    }

    #[test]
    fn exceptions_as_the_refusals_say() {
        let read = adu(1, 0, 7, &[0x03, 0x00, 0x80, 0x00, 0x01]);
        let write = adu(2, 0, 7, &[0x06, 0x00, 0x80, 0x00, 0x01]);
        let exception = |request: &[u8], code: u8| adu(request[1].into(), 0, 7, &[request[7] | 0x80, code]);
        let other_unit = Refusals { unit_id: Some(1), ..ALL };
        let read_only = Refusals { read_only: true, ..ALL };
        assert_eq!(check_reply(&read, &exception(&read, 0x0b), &other_unit), Answer::Exception(0x0b));
        assert_eq!(check_reply(&write, &exception(&write, 0x01), &read_only), Answer::Exception(0x01));
        assert_eq!(check_reply(&read, &exception(&read, 0x02), &read_only), Answer::Exception(0x02));
        let unknown = adu(3, 0, 7, &[0x2b, 0x0e]);
        assert_eq!(check_reply(&unknown, &exception(&unknown, 0x01), &ALL), Answer::Exception(0x01));
    }

    #[test]
    #[should_panic(expected = "exception 0x02")]
    fn another_unit_gets_0b_only() {
        let read = adu(1, 0, 7, &[0x03, 0x00, 0x80, 0x00, 0x01]);
        check_reply(&read, &adu(1, 0, 7, &[0x83, 0x02]), &Refusals { unit_id: Some(1), ..ALL });
    }

    #[test]
    #[should_panic(expected = "a normal reply")]
    fn a_read_only_client_s_write_is_not_acknowledged() {
        let write = PYMODBUS[2].request;
        check_reply(write, PYMODBUS[2].reply, &Refusals { read_only: true, ..ALL });
    }

    #[test]
    #[should_panic(expected = "a read of 0 answered")]
    fn a_read_of_nothing_is_not_answered() {
        let read = adu(1, 0, 1, &[0x03, 0x00, 0x80, 0x00, 0x00]);
        check_reply(&read, &adu(1, 0, 1, &[0x03, 0x00]), &ALL);
    }

    #[test]
    #[should_panic(expected = "the transaction id")]
    fn the_transaction_id_is_echoed() {
        let mut reply = PYMODBUS[0].reply.to_vec();
        reply[1] ^= 1;
        check_reply(PYMODBUS[0].request, &reply, &ALL);
    }
}
