//! The checks of the fuzz targets beyond test-support's reference (the
//! framing and what a reply may be, written from the specification): what
//! this library's map and counters promise, and the pins.

use std::sync::Mutex;

use adapter::io::{OutputPins, Outputs};
use adapter::map::{Image, WritePolicy};
use adapter::server::{Counters, Policy};
use test_support::framer::is_modbus;
use test_support::reply::{Answer, CLEAR_COUNTERS, Refusals, check_reply, is_write};

/// What `policy` refuses, in the reference's terms.
pub fn refusals(policy: &Policy) -> Refusals {
    Refusals { unit_id: policy.unit_id, read_only: !policy.rights.allow(true) }
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

/// The diagnostics counters a session over `frames` (every whole frame, in
/// order) must leave, the Modbus ones answered by `replies`: every Modbus
/// frame counted, each exception by its code, a discarded frame as a bad
/// protocol id, a lost stream as a bad length, and nothing else; all of
/// them 0 after an acknowledged Clear Counters, which then counts itself.
///
/// On the way, each Diagnostics count must be what the counters held when
/// it was asked for ([`serial_line_count`]).
pub fn counters(frames: &[&[u8]], replies: &[Vec<u8>], lost: bool, policy: &Policy) -> Counters {
    let mut c = Counters::default();
    let mut replies = replies.iter();
    for frame in frames {
        if !is_modbus(frame) {
            c.bad_protocol += 1;
            continue;
        }
        let reply = replies.next().expect("a reply to every Modbus frame");
        let (pdu, answer) = (&frame[7..], &reply[7..]);
        match answer {
            [0x08, hi, lo, count @ ..] if pdu.len() == 5 => {
                let sub = u16::from_be_bytes([*hi, *lo]);
                if sub == CLEAR_COUNTERS {
                    c = Counters::default();
                } else if let Some(want) = serial_line_count(&c, sub) {
                    assert_eq!(count, want.to_be_bytes(), "count {sub:#06x} to {frame:02x?}");
                }
            }
            [code, exception] if code & 0x80 != 0 => match exception {
                0x01 if is_write(pdu) && !policy.rights.allow(true) => c.refused_writes += 1,
                0x01 => c.bad_function += 1,
                0x02 => c.bad_address += 1,
                0x03 => c.bad_value += 1,
                0x0b => c.other_unit += 1,
                other => panic!("exception {other:#04x} to {frame:02x?}"),
            },
            _ => {}
        }
        c.requests += 1;
    }
    c.bad_length = u32::from(lost);
    c
}

/// What Diagnostics' counter `sub` returns from the counters `c`, as
/// docs/data-map.md maps the serial-line counters to the adapter's: bus
/// messages are every whole frame, communication errors the lost streams,
/// exceptions every exception, server messages the requests for this
/// unit, no response the frames skipped, overrun the sessions evicted.
pub fn serial_line_count(c: &Counters, sub: u16) -> Option<u16> {
    let count = match sub {
        0x0b => c.requests.wrapping_add(c.bad_protocol),
        0x0c => c.bad_length,
        0x0d => [c.bad_function, c.bad_address, c.bad_value, c.refused_writes, c.other_unit]
            .into_iter()
            .fold(0u32, u32::wrapping_add),
        0x0e => c.requests.saturating_sub(c.other_unit),
        0x0f => c.bad_protocol,
        0x12 => c.evictions,
        _ => return None,
    };
    Some(count as u16)
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
