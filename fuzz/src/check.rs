//! The checks, written from the specification rather than from the
//! library's code: MBAP framing, the shape of each reply, and the pins.

use std::sync::Mutex;

use adapter::io::{OutputPins, Outputs};
use adapter::map::{Image, WritePolicy};
use adapter::server::{Counters, Policy};

use crate::be_u16;

/// MBAP framing (Implementation Guide V1.0b, 3.1.3): 6 bytes, then `length`
/// more, with `length` in 2..=254. Returns the whole frames, and whether the
/// stream was lost at a bad length field.
pub fn oracle_frames(mut stream: &[u8]) -> (Vec<&[u8]>, bool) {
    let mut out = Vec::new();
    while let Some(length) = be_u16(stream, 4) {
        let length = usize::from(length);
        if !(2..=254).contains(&length) {
            return (out, true);
        }
        let Some((frame, rest)) = stream.split_at_checked(6 + length) else { break };
        out.push(frame);
        stream = rest;
    }
    (out, false)
}

/// Splits what the server sent into frames; it must end on a frame boundary.
pub fn split_replies(mut bytes: &[u8]) -> Vec<&[u8]> {
    let mut out = Vec::new();
    while !bytes.is_empty() {
        let length = be_u16(bytes, 4).unwrap_or_else(|| panic!("a reply cut short: {bytes:02x?}"));
        assert!((3..=254).contains(&length), "a reply with length field {length}");
        let (frame, rest) = bytes
            .split_at_checked(6 + usize::from(length))
            .unwrap_or_else(|| panic!("the reply stream ends with a partial frame: {bytes:02x?}"));
        out.push(frame);
        bytes = rest;
    }
    out
}

/// Checks `reply` against its `request` (both whole frames, protocol id 0):
/// header echoed, and either an exception the specification allows for that
/// request or the normal response of its function. Returns whether it
/// acknowledged a write.
pub fn check_reply(request: &[u8], reply: &[u8], policy: &Policy) -> bool {
    assert_eq!(reply[..2], request[..2], "transaction id");
    assert_eq!(reply[2..4], [0, 0], "protocol id");
    assert_eq!(usize::from(be_u16(reply, 4).unwrap()), reply.len() - 6, "length field");
    assert_eq!(reply[6], request[6], "unit id");
    let (pdu, answer) = (&request[7..], &reply[7..]);
    let function = pdu[0];
    let known = [0x01, 0x03, 0x05, 0x06, 0x0f, 0x10].contains(&function);
    let write = [0x05, 0x06, 0x0f, 0x10].contains(&function);
    let other_unit = policy.unit_id.is_some_and(|id| ![id, 0, 0xff].contains(&request[6]));
    let refused = other_unit || !known || (write && policy.read_only);
    if answer[0] == function | 0x80 && answer.len() == 2 {
        let allowed: &[u8] = match (other_unit, known && !(write && policy.read_only)) {
            (true, _) => &[0x0b],
            (false, false) => &[0x01],
            (false, true) => &[0x02, 0x03],
        };
        assert!(allowed.contains(&answer[1]), "exception {:#04x} to {pdu:02x?}", answer[1]);
        return false;
    }
    assert!(!refused, "a normal reply {answer:02x?} to {pdu:02x?} under {policy:?}");
    assert_eq!(answer[0], function);
    let quantity = usize::from(be_u16(pdu, 3).unwrap());
    match function {
        0x01 => {
            assert!((1..=2000).contains(&quantity), "read {quantity} coils");
            assert_eq!(answer[1], quantity.div_ceil(8) as u8, "coil byte count");
        }
        0x03 => {
            assert!((1..=125).contains(&quantity), "read {quantity} registers");
            assert_eq!(answer[1], (2 * quantity) as u8, "register byte count");
        }
        0x05 => {
            assert!(pdu[3..] == [0xff, 0x00] || pdu[3..] == [0, 0], "coil value {:02x?}", &pdu[3..]);
            assert_eq!(answer, pdu, "a single write echoes");
        }
        0x06 => assert_eq!(answer, pdu, "a single write echoes"),
        0x0f => {
            assert!((1..=1968).contains(&quantity), "write {quantity} coils");
            assert_eq!(usize::from(pdu[5]), quantity.div_ceil(8), "byte count of {quantity} coils");
            assert_eq!(answer, &pdu[..5], "a multiple write echoes start and quantity");
        }
        _ => {
            assert!((1..=123).contains(&quantity), "write {quantity} registers");
            assert_eq!(usize::from(pdu[5]), 2 * quantity, "byte count of {quantity} registers");
            assert_eq!(answer, &pdu[..5], "a multiple write echoes start and quantity");
        }
    }
    if matches!(function, 0x01 | 0x03) {
        assert_eq!(answer.len(), 2 + usize::from(answer[1]), "read reply length");
        // A read reaches past no end of the map (coils 0-265, registers 0-435).
        let space = if function == 0x01 { 266 } else { 436 };
        let start = usize::from(be_u16(pdu, 1).unwrap());
        assert!(start + quantity <= space, "a read of {quantity} from {start} answered");
        return false;
    }
    true
}

/// The diagnostics counters a session over these frames must leave: every
/// Modbus frame counted, each exception by its code, a discarded frame as a
/// bad protocol id, a lost stream as a bad length, and nothing else.
pub fn expected_counters(
    requests: &[&[u8]],
    replies: &[&[u8]],
    discarded: usize,
    lost: bool,
    policy: &Policy,
) -> Counters {
    let mut c = Counters {
        requests: requests.len() as u32,
        bad_protocol: discarded as u32,
        bad_length: u32::from(lost),
        ..Counters::default()
    };
    for (request, reply) in requests.iter().zip(replies) {
        if reply[7] & 0x80 == 0 {
            continue;
        }
        let write = [0x05, 0x06, 0x0f, 0x10].contains(&request[7]);
        match reply[8] {
            0x01 if write && policy.read_only => c.refused_writes += 1,
            0x01 => c.bad_function += 1,
            0x02 => c.bad_address += 1,
            0x03 => c.bad_value += 1,
            0x0b => c.other_unit += 1,
            other => panic!("exception {other:#04x} to {request:02x?}"),
        }
    }
    c
}

/// Output pins that remember what they were last told to drive.
#[derive(Debug, Default)]
pub struct Pins {
    last: Mutex<Option<Outputs>>,
}

impl OutputPins for Pins {
    fn drive(&self, outputs: &Outputs) {
        *self.last.lock().unwrap_or_else(std::sync::PoisonError::into_inner) = Some(*outputs);
    }
}

/// The pins show what the map says: what was last driven is the map's
/// outputs, or, if nothing was ever driven, the map's outputs are still
/// those of a fresh map.
pub fn pins_follow_map(pins: &Pins, image: &Image) {
    let driven = *pins.last.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let now = Outputs::from_image(image);
    match driven {
        Some(driven) => assert_eq!(driven, now, "the pins lag the map"),
        None => assert_eq!(now, Outputs::from_image(&Image::new()), "outputs changed without driving the pins"),
    }
}

/// A write policy from one bit.
pub fn write_policy(strict: bool) -> WritePolicy {
    if strict { WritePolicy::Strict } else { WritePolicy::Seed }
}
