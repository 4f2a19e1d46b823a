//! The checks of the fuzz targets beyond test-support's reference (the
//! framing and what a reply may be, written from the specification): what
//! this library's map and counters promise, and the pins.

use std::sync::Mutex;

use adapter::io::{OutputPins, Outputs};
use adapter::map::{Image, WritePolicy};
use adapter::server::{Counters, Policy};
use test_support::reply::{Answer, Refusals, WRITE_FUNCTIONS, check_reply};

/// What `policy` refuses, in the reference's terms.
pub fn refusals(policy: &Policy) -> Refusals {
    Refusals { unit_id: policy.unit_id, read_only: policy.read_only }
}

/// Checks `reply` against its `request` (both whole frames, protocol id 0)
/// with the reference ([`check_reply`]), and that a read answered reaches
/// past no end of the map (coils 0-265, registers 0-435).
pub fn reply(request: &[u8], reply: &[u8], policy: &Policy) -> Answer {
    let answer = check_reply(request, reply, &refusals(policy));
    if answer == Answer::Read {
        let space = if request[7] == 0x01 { 266 } else { 436 };
        let start = usize::from(u16::from_be_bytes([request[8], request[9]]));
        let quantity = usize::from(u16::from_be_bytes([request[10], request[11]]));
        assert!(start + quantity <= space, "a read of {quantity} from {start} answered");
    }
    answer
}

/// The diagnostics counters a session over these frames must leave: every
/// Modbus frame counted, each exception by its code, a discarded frame as a
/// bad protocol id, a lost stream as a bad length, and nothing else.
pub fn expected_counters(
    requests: &[&[u8]],
    replies: &[Vec<u8>],
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
        let write = WRITE_FUNCTIONS.contains(&request[7]);
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
    let now = image.outputs();
    match driven {
        Some(driven) => assert_eq!(driven, now, "the pins lag the map"),
        None => assert_eq!(now, Image::new().outputs(), "outputs changed without driving the pins"),
    }
}

/// A write policy from one bit.
pub fn write_policy(strict: bool) -> WritePolicy {
    if strict { WritePolicy::Strict } else { WritePolicy::Seed }
}
