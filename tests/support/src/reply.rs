//! What a reply to a request may be, written from the specification alone
//! (Modbus Application Protocol V1.1b3, 6.1-6.12, 6.8, 6.21 and 7; the
//! Implementation Guide for the header): the fuzz targets and the property
//! test check every reply the server gives against it.

use crate::framer::{HEADER_LEN, length_field};

/// The function codes the server implements: read coils, read holding
/// registers, write single coil, write single register, diagnostics, write
/// multiple coils, write multiple registers, and encapsulated interface
/// transport (for MEI type 0E, Read Device Identification, alone).
pub const FUNCTIONS: [u8; 8] = [0x01, 0x03, 0x05, 0x06, 0x08, 0x0f, 0x10, 0x2b];
/// Those of them that write.
pub const WRITE_FUNCTIONS: [u8; 4] = [0x05, 0x06, 0x0f, 0x10];
/// The Diagnostics sub-functions the server implements (6.8.1): return
/// query data, clear counters, and the six counters 0B-0F and 12.
pub const DIAGNOSTICS: [u16; 8] = [0x00, 0x0a, 0x0b, 0x0c, 0x0d, 0x0e, 0x0f, 0x12];
/// Diagnostics: Return Query Data, whose data is any and echoed.
pub const RETURN_QUERY_DATA: u16 = 0x00;
/// Diagnostics: Clear Counters and Diagnostic Register, a change.
pub const CLEAR_COUNTERS: u16 = 0x0a;
/// The MEI type of Read Device Identification.
pub const READ_DEVICE_ID: u8 = 0x0e;
/// The object ids the server has: every basic (0-2) and regular (3-6) one.
pub const OBJECTS: std::ops::RangeInclusive<u8> = 0x00..=0x06;
/// Its conformity level: regular identification, stream and individual access.
pub const CONFORMITY: u8 = 0x82;

/// Whether a request PDU asks for a change: a write function, or
/// Diagnostics' Clear Counters (a client that may not write gets 01 for it).
pub fn is_write(pdu: &[u8]) -> bool {
    match pdu {
        [0x08, hi, lo, ..] => u16::from_be_bytes([*hi, *lo]) == CLEAR_COUNTERS,
        [function, ..] => WRITE_FUNCTIONS.contains(function),
        [] => false,
    }
}

/// The exceptions the specification allows to a request of Diagnostics or
/// Read Device Identification that is not refused for its unit or client,
/// in its state diagram's order: none for a request the server must answer.
fn device_exceptions(pdu: &[u8]) -> &'static [u8] {
    match pdu {
        [0x08, hi, lo, data @ ..] => match u16::from_be_bytes([*hi, *lo]) {
            sub if !DIAGNOSTICS.contains(&sub) => &[0x01],
            RETURN_QUERY_DATA => &[],
            _ if data != [0, 0] => &[0x03],
            _ => &[],
        },
        [0x08, ..] => &[0x03],
        [0x2b, READ_DEVICE_ID, fields @ ..] => match *fields {
            [0x01 | 0x02, _] => &[],
            [0x04, object_id] if OBJECTS.contains(&object_id) => &[],
            [0x04, _] => &[0x02],
            _ => &[0x03],
        },
        _ => &[0x01],
    }
}

/// What the server was told to refuse.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Refusals {
    /// Answer only this unit id (and 0 and 0xFF); another gets exception 0B
    /// (gateway target device failed to respond).
    pub unit_id: Option<u8>,
    /// The client may not write: its write functions and Clear Counters get exception 01.
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
    /// The normal response of Diagnostics (its echo, or a counter's value,
    /// which only a model of the counters can check).
    Diagnostics,
    /// The normal response of Read Device Identification: its objects are
    /// those asked for, in order, their values the server's.
    Identification,
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
    let refused_write = refusals.read_only && is_write(pdu);
    let other_unit = refusals.unit_id.is_some_and(|id| ![id, 0, 0xff].contains(&request[6]));
    let device = matches!(function, 0x08 | 0x2b);
    if answer[0] == function | 0x80 && answer.len() == 2 {
        let allowed: &[u8] = match (other_unit, known && !refused_write) {
            (true, _) => &[0x0b],
            (false, false) => &[0x01],
            (false, true) if device => device_exceptions(pdu),
            (false, true) => &[0x02, 0x03],
        };
        assert!(allowed.contains(&answer[1]), "exception {:#04x} to {pdu:02x?} ({refusals:?})", answer[1]);
        return Answer::Exception(answer[1]);
    }
    assert!(known && !refused_write && !other_unit, "a normal reply {answer:02x?} to {pdu:02x?} ({refusals:?})");
    assert_eq!(answer[0], function, "the function code of {answer:02x?} to {pdu:02x?}");
    if device {
        let allowed = device_exceptions(pdu);
        assert!(allowed.is_empty(), "a normal reply {answer:02x?} to {pdu:02x?}, which must get one of {allowed:02x?}");
        return if function == 0x08 { check_diagnostics(pdu, answer) } else { check_identification(pdu, answer) };
    }
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

/// A Diagnostics reply to `pdu`, a request the server must answer: an echo,
/// or the sub-function and a count of two bytes.
fn check_diagnostics(pdu: &[u8], answer: &[u8]) -> Answer {
    let sub_function = u16::from_be_bytes([pdu[1], pdu[2]]);
    if matches!(sub_function, RETURN_QUERY_DATA | CLEAR_COUNTERS) {
        assert_eq!(answer, pdu, "Diagnostics {sub_function:#06x} echoes the request");
    } else {
        assert_eq!(answer.len(), 5, "a count of two bytes: {answer:02x?} to {pdu:02x?}");
        assert_eq!(answer[..3], pdu[..3], "the sub-function of {answer:02x?} to {pdu:02x?}");
    }
    Answer::Diagnostics
}

/// A Read Device Identification reply to `pdu`, a request the server must
/// answer: its header, and the objects asked for, each once and in order.
/// A stream (codes 01, 02) starts at the object id if it is one of the
/// category's, else at 0 (6.21), and goes on to the category's last object
/// unless "more follows" says where the next response starts.
fn check_identification(pdu: &[u8], answer: &[u8]) -> Answer {
    let (code, object_id) = (pdu[2], pdu[3]);
    assert!(answer.len() >= 7, "a Read Device Identification reply cut short: {answer:02x?}");
    assert_eq!(answer[..3], [0x2b, READ_DEVICE_ID, code], "the header of {answer:02x?} to {pdu:02x?}");
    assert_eq!(answer[3], CONFORMITY, "the conformity level of {answer:02x?}");
    let (more, next, count) = (answer[4], answer[5], answer[6]);
    let mut ids = Vec::new();
    let mut rest = &answer[7..];
    while let [id, len, tail @ ..] = rest {
        assert!(tail.len() >= usize::from(*len), "object {id} cut short in {answer:02x?}");
        ids.push(*id);
        rest = &tail[usize::from(*len)..];
    }
    assert!(rest.is_empty(), "a byte after the objects of {answer:02x?}");
    assert_eq!(usize::from(count), ids.len(), "the object count of {answer:02x?}");
    let last = match code {
        0x04 => {
            assert_eq!((more, next, &ids[..]), (0x00, 0x00, &[object_id][..]), "one object: {answer:02x?}");
            return Answer::Identification;
        }
        0x01 => 0x02,
        _ => 0x06,
    };
    let first = if object_id <= last { object_id } else { 0 };
    let expected_end = match more {
        0x00 => {
            assert_eq!(next, 0x00, "no more follows, and a next object id in {answer:02x?}");
            last + 1
        }
        0xff => next,
        other => panic!("more follows {other:#04x} in {answer:02x?}"),
    };
    assert!(!ids.is_empty() || more == 0xff, "no object in {answer:02x?}");
    assert_eq!(ids, (first..expected_end).collect::<Vec<_>>(), "the objects of {answer:02x?} to {pdu:02x?}");
    Answer::Identification
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
        let unknown = adu(3, 0, 7, &[0x07]); // Read Exception Status: serial line only
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

    /// A Read Device Identification reply with these objects (each value `x`).
    fn identification(request: &[u8], code: u8, more: u8, next: u8, ids: &[u8]) -> Vec<u8> {
        let mut pdu = vec![0x2b, 0x0e, code, CONFORMITY, more, next, ids.len() as u8];
        for &id in ids {
            pdu.extend([id, 1, b'x']);
        }
        adu(u16::from_be_bytes([request[0], request[1]]), 0, request[6], &pdu)
    }

    #[test]
    fn identification_streams_start_where_the_spec_says() {
        let request = |code: u8, object: u8| adu(1, 0, 1, &[0x2b, 0x0e, code, object]);
        let check = |request: &[u8], reply: Vec<u8>| check_reply(request, &reply, &ALL);
        let regular = request(0x02, 4);
        assert_eq!(check(&regular, identification(&regular, 0x02, 0, 0, &[4, 5, 6])), Answer::Identification);
        // Object 5 is not basic: a basic stream from it starts at 0.
        let basic = request(0x01, 5);
        assert_eq!(check(&basic, identification(&basic, 0x01, 0, 0, &[0, 1, 2])), Answer::Identification);
        // More follows: this one ends before object 4.
        assert_eq!(check(&regular, identification(&regular, 0x02, 0xff, 6, &[4, 5])), Answer::Identification);
        let one = request(0x04, 6);
        assert_eq!(check(&one, identification(&one, 0x04, 0, 0, &[6])), Answer::Identification);
        // No object 7: 02; a code of 03, or another MEI type: 03 and 01.
        let exception = |code: u8| adu(1, 0, 1, &[0xab, code]);
        let seven = request(0x04, 7);
        assert_eq!(check(&seven, exception(0x02)), Answer::Exception(0x02));
        let extended = request(0x03, 0);
        assert_eq!(check(&extended, exception(0x03)), Answer::Exception(0x03));
        let canopen = adu(1, 0, 1, &[0x2b, 0x0d, 0x01, 0x00]);
        assert_eq!(check(&canopen, exception(0x01)), Answer::Exception(0x01));
    }

    #[test]
    #[should_panic(expected = "the objects of")]
    fn a_stream_leaves_no_object_out() {
        let regular = adu(1, 0, 1, &[0x2b, 0x0e, 0x02, 0x00]);
        check_reply(&regular, &identification(&regular, 0x02, 0, 0, &[0, 1, 2, 4, 5, 6]), &ALL);
    }

    #[test]
    #[should_panic(expected = "which must get one of [02]")]
    fn an_object_the_server_lacks_is_exception_02() {
        let specific = adu(1, 0, 1, &[0x2b, 0x0e, 0x04, 0x80]);
        check_reply(&specific, &identification(&specific, 0x04, 0, 0, &[0x80]), &ALL);
    }

    #[test]
    fn diagnostics_echo_or_count_and_clear_is_a_write() {
        let query = adu(1, 0, 1, &[0x08, 0x00, 0x00, 0x12, 0x34, 0x56]);
        assert_eq!(check_reply(&query, &query, &ALL), Answer::Diagnostics);
        let count = adu(2, 0, 1, &[0x08, 0x00, 0x0e, 0x00, 0x00]);
        assert_eq!(check_reply(&count, &adu(2, 0, 1, &[0x08, 0x00, 0x0e, 0x01, 0x02]), &ALL), Answer::Diagnostics);
        let clear = adu(3, 0, 1, &[0x08, 0x00, 0x0a, 0x00, 0x00]);
        assert_eq!(check_reply(&clear, &clear, &ALL), Answer::Diagnostics);
        let refused = adu(3, 0, 1, &[0x88, 0x01]);
        assert_eq!(check_reply(&clear, &refused, &Refusals { read_only: true, ..ALL }), Answer::Exception(0x01));
        let unknown = adu(4, 0, 1, &[0x08, 0x00, 0x01, 0x00, 0x00]);
        assert_eq!(check_reply(&unknown, &adu(4, 0, 1, &[0x88, 0x01]), &ALL), Answer::Exception(0x01));
        let bad_data = adu(5, 0, 1, &[0x08, 0x00, 0x0b, 0x00, 0x01]);
        assert_eq!(check_reply(&bad_data, &adu(5, 0, 1, &[0x88, 0x03]), &ALL), Answer::Exception(0x03));
        assert!(is_write(&[0x08, 0x00, 0x0a]) && !is_write(&[0x08, 0x00, 0x0b]) && is_write(&[0x10]));
    }

    #[test]
    #[should_panic(expected = "exception 0x01")]
    fn a_read_only_client_may_read_counters() {
        let count = adu(2, 0, 1, &[0x08, 0x00, 0x0b, 0x00, 0x00]);
        check_reply(&count, &adu(2, 0, 1, &[0x88, 0x01]), &Refusals { read_only: true, ..ALL });
    }
}
