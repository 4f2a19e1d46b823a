//! Random byte streams through a whole session.
//!
//! For any stream, cut into reads of any size:
//! - the session never panics and ends as the stream says (clean end, or
//!   `BadLength` where a length field is out of range);
//! - every reply answers a request that was actually sent, in order, with
//!   its transaction and unit id, and is a well-formed response of that
//!   request's function or an exception the spec allows;
//! - the map changes only through acknowledged writes: replaying just those
//!   on a fresh map gives the session's map.
//!
//! Framing is checked against the few lines of `oracle_frames` below, not
//! against the library's own framer.

use core::pin::pin;
use core::task::Poll;

use proptest::prelude::*;

use super::{Error, serve};
use crate::device::Device;
use crate::map::WritePolicy;
use crate::modbus::mbap::MAX_ADU_LEN;
use crate::server::testing::{Clock, Wire, frames, poll_once, server_with};
use crate::server::{Config, Outcome, Policy, Server, Watchdog};

/// MBAP framing from the Implementation Guide: 6 bytes, then `length` more.
fn oracle_frames(mut stream: &[u8]) -> (Vec<&[u8]>, bool) {
    let mut out = Vec::new();
    while stream.len() >= 6 {
        let length = usize::from(u16::from_be_bytes([stream[4], stream[5]]));
        if !(2..=254).contains(&length) {
            return (out, true);
        }
        let Some(frame) = stream.get(..6 + length) else { break };
        out.push(frame);
        stream = &stream[6 + length..];
    }
    (out, false)
}

fn address() -> impl Strategy<Value = u16> {
    prop_oneof![4 => 0u16..440, 1 => any::<u16>()]
}

fn quantity() -> impl Strategy<Value = u16> {
    prop_oneof![4 => 0u16..=130, 1 => 0u16..=2100, 1 => any::<u16>()]
}

/// A request PDU: mostly the six functions with plausible fields.
fn pdu() -> impl Strategy<Value = Vec<u8>> {
    let head = |code: u8, a: u16, b: u16| {
        let mut pdu = vec![code];
        pdu.extend(a.to_be_bytes());
        pdu.extend(b.to_be_bytes());
        pdu
    };
    let multiple = move |code: u8, unit_bytes: fn(u16) -> usize| {
        (address(), quantity(), prop_oneof![4 => Just(0i8), 1 => -2i8..=2], any::<u8>()).prop_map(
            move |(start, quantity, skew, fill)| {
                let count = unit_bytes(quantity).saturating_add_signed(skew.into()).min(255);
                let mut pdu = head(code, start, quantity);
                pdu.push(count as u8);
                pdu.extend(std::iter::repeat_n(fill, count));
                pdu
            },
        )
    };
    prop_oneof![
        (prop::sample::select(vec![0x01u8, 0x03]), address(), quantity()).prop_map(move |(c, a, q)| head(c, a, q)),
        (address(), prop_oneof![Just(0xff00u16), Just(0), any::<u16>()]).prop_map(move |(a, v)| head(0x05, a, v)),
        (address(), prop_oneof![0u16..=3, 0u16..=25_000, any::<u16>()]).prop_map(move |(a, v)| head(0x06, a, v)),
        multiple(0x0f, |q| usize::from(q).div_ceil(8)),
        multiple(0x10, |q| 2 * usize::from(q)),
        prop::collection::vec(any::<u8>(), 1..12),
    ]
}

/// One MBAP frame around a PDU (its length field may be out of range if the PDU is huge).
fn request() -> impl Strategy<Value = Vec<u8>> {
    (
        any::<u16>(),
        prop_oneof![9 => Just(0u16), 1 => any::<u16>()],
        prop_oneof![3 => Just(1u8), 1 => any::<u8>()],
        pdu(),
    )
        .prop_map(|(transaction, protocol, unit, pdu)| {
            let mut frame = transaction.to_be_bytes().to_vec();
            frame.extend(protocol.to_be_bytes());
            frame.extend(((pdu.len() + 1) as u16).to_be_bytes());
            frame.push(unit);
            frame.extend(pdu);
            frame
        })
}

fn stream() -> impl Strategy<Value = Vec<u8>> {
    let item = prop_oneof![
        20 => request(),
        1 => prop::collection::vec(any::<u8>(), 0..16),
        1 => (any::<u16>()).prop_map(|len| vec![0, 1, 0, 0, (len >> 8) as u8, len as u8]),
    ];
    prop::collection::vec(item, 0..24).prop_map(|items| items.concat())
}

fn policy() -> impl Strategy<Value = Policy> {
    (
        prop_oneof![Just(None), Just(Some(1u8))],
        prop_oneof![Just(WritePolicy::Seed), Just(WritePolicy::Strict)],
        prop_oneof![3 => Just(false), 1 => Just(true)],
    )
        .prop_map(|(unit_id, write_policy, read_only)| Policy { unit_id, write_policy, read_only })
}

fn shared(policy: Policy) -> &'static Server<'static, Device<'static>> {
    let config = Config { policy, idle_timeout: None, ..Config::DEFAULT };
    server_with(config, Watchdog::OFF).0
}

/// Checks `reply` against `request`; returns whether it acknowledged a write.
fn check_reply(request: &[u8], reply: &[u8], policy: &Policy) -> Result<bool, TestCaseError> {
    prop_assert_eq!(&reply[..2], &request[..2], "transaction id");
    prop_assert_eq!(&reply[2..4], &[0, 0], "protocol id");
    prop_assert_eq!(reply[6], request[6], "unit id");
    let (function, pdu) = (request[7], &request[7..]);
    let answer = &reply[7..];
    let known = [0x01, 0x03, 0x05, 0x06, 0x0f, 0x10].contains(&function);
    let other_unit = policy.unit_id.is_some_and(|id| ![id, 0, 0xff].contains(&request[6]));
    let refused_write = policy.read_only && [0x05, 0x06, 0x0f, 0x10].contains(&function);
    if answer[0] == function | 0x80 && answer.len() == 2 {
        let allowed: &[u8] = match (other_unit, known, refused_write) {
            (true, _, _) => &[0x0b],
            (false, false, _) | (false, true, true) => &[0x01],
            (false, true, false) => &[0x02, 0x03],
        };
        prop_assert!(allowed.contains(&answer[1]), "exception {:#04x} to {:02x?}", answer[1], pdu);
        return Ok(false);
    }
    prop_assert!(known && !other_unit && !refused_write, "a normal reply to {:02x?}", pdu);
    prop_assert_eq!(answer[0], function);
    let quantity = usize::from(u16::from_be_bytes([pdu[3], pdu[4]]));
    match function {
        0x01 => prop_assert_eq!(&answer[1..2], &[quantity.div_ceil(8) as u8], "coil byte count"),
        0x03 => prop_assert_eq!(&answer[1..2], &[(2 * quantity) as u8], "register byte count"),
        0x05 | 0x06 => prop_assert_eq!(answer, pdu, "single writes echo"),
        _ => prop_assert_eq!(answer, &pdu[..5], "multiple writes echo start and quantity"),
    }
    if matches!(function, 0x01 | 0x03) {
        prop_assert_eq!(answer.len(), 2 + usize::from(answer[1]));
    }
    Ok(!matches!(function, 0x01 | 0x03))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn any_stream_is_answered_correctly_and_changes_the_map_only_by_acknowledged_writes(
        bytes in stream(),
        segment in 0usize..80,
        policy in policy(),
    ) {
        let _clock = Clock::take();
        let server = shared(policy);
        let (wire, mut end) = Wire::new();
        wire.segment(segment);
        wire.send(&bytes);
        wire.close();
        let result = {
            let mut session = pin!(serve(&mut end, server, 0));
            match poll_once(session.as_mut()) {
                Poll::Ready(result) => result,
                Poll::Pending => return Err(TestCaseError::fail("the session waits with all input there")),
            }
        };

        let (requests, lost) = oracle_frames(&bytes);
        match result {
            Ok(()) => prop_assert!(!lost),
            Err(Error::BadLength(_)) => prop_assert!(lost),
            Err(other) => return Err(TestCaseError::fail(format!("session ended with {other:?}"))),
        }
        let modbus: Vec<&[u8]> = requests.into_iter().filter(|r| r[2..4] == [0, 0]).collect();
        let replies = frames(&wire.take_replies());
        prop_assert_eq!(replies.len(), modbus.len(), "one reply per Modbus frame, none for others");

        let model = shared(policy);
        let mut scratch = [0u8; MAX_ADU_LEN];
        for (request, reply) in modbus.iter().zip(&replies) {
            if check_reply(request, reply, &policy)? {
                let replayed = model.respond(request, &mut scratch);
                let acknowledged = matches!(replayed, Outcome::Reply { exception: None, .. });
                prop_assert!(acknowledged, "replaying an acknowledged write succeeds");
            }
        }
        prop_assert_eq!(server.service().read(Clone::clone), model.service().read(Clone::clone), "the map holds exactly the acknowledged writes");
    }
}
