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
//! Framing and replies are checked against test-support's reference framer
//! (`test_support::framer`, `test_support::reply`), written from the
//! specification, not against the library's own framer.

use core::pin::pin;
use core::task::Poll;

use proptest::prelude::*;

use test_support::duplex::{Wire, poll_once};
use test_support::framer::{self, adu, split_replies};
use test_support::reply::{Answer, Refusals, check_reply};

use super::{Error, serve};
use crate::access::Rights;
use crate::device::Device;
use crate::device::Watchdog;
use crate::map::WritePolicy;
use crate::modbus::mbap::MAX_ADU_LEN;
use crate::server::testing::{Clock, server_with};
use crate::server::{Config, Outcome, Policy, Server};

fn address() -> impl Strategy<Value = u16> {
    prop_oneof![4 => 0u16..440, 1 => any::<u16>()]
}

fn quantity() -> impl Strategy<Value = u16> {
    prop_oneof![4 => 0u16..=130, 1 => 0u16..=2100, 1 => any::<u16>()]
}

/// A request PDU: mostly the six functions of the map with plausible
/// fields, some Diagnostics and Read Device Identification.
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
        (
            prop_oneof![0u16..=0x14, any::<u16>()],
            prop_oneof![Just(vec![0, 0]), prop::collection::vec(any::<u8>(), 0..6)]
        )
            .prop_map(|(sub, data)| [&[0x08][..], &sub.to_be_bytes(), &data].concat()),
        (prop_oneof![Just(0x0eu8), any::<u8>()], 0u8..=5, prop_oneof![0u8..=8, any::<u8>()], 0usize..=1)
            .prop_map(|(mei, code, object, extra)| [&[0x2b, mei, code, object][..], &[0][..extra]].concat()),
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
        .prop_map(|(transaction, protocol, unit, pdu)| adu(transaction, protocol, unit, &pdu))
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
        prop_oneof![3 => Just(Rights::ReadWrite), 1 => Just(Rights::Read)],
    )
        .prop_map(|(unit_id, write_policy, rights)| Policy { unit_id, write_policy, rights })
}

fn shared(policy: Policy) -> &'static Server<'static, Device<'static>> {
    let config = Config { policy, idle_timeout: None, ..Config::DEFAULT };
    server_with(config, Watchdog::OFF).0
}

/// What `policy` refuses, in the reference's terms.
fn refusals(policy: &Policy) -> Refusals {
    Refusals { unit_id: policy.unit_id, read_only: !policy.rights.allow(true) }
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
        wire.read_sizes([segment]);
        wire.send(&bytes);
        wire.close();
        let result = {
            let mut session = pin!(serve(&mut end, server, 0));
            match poll_once(session.as_mut()) {
                Poll::Ready(result) => result,
                Poll::Pending => return Err(TestCaseError::fail("the session waits with all input there")),
            }
        };

        let framed = framer::split(&bytes);
        match result {
            Ok(()) => prop_assert_eq!(framed.bad_length, None, "a clean end on a lost stream"),
            Err(Error::BadLength(length)) => prop_assert_eq!(framed.bad_length, Some(length)),
            Err(other) => return Err(TestCaseError::fail(format!("session ended with {other:?}"))),
        }
        let requests = framed.requests();
        let replies = split_replies(&wire.take_replies());
        prop_assert_eq!(replies.len(), requests.len(), "one reply per Modbus frame, none for others");

        let model = shared(policy);
        let mut scratch = [0u8; MAX_ADU_LEN];
        for (request, reply) in requests.iter().zip(&replies) {
            if check_reply(request, reply, &refusals(&policy)) == Answer::Write {
                let replayed = model.respond(request, &mut scratch);
                let acknowledged = matches!(replayed, Outcome::Reply { exception: None, .. });
                prop_assert!(acknowledged, "replaying an acknowledged write succeeds");
            }
        }
        prop_assert_eq!(server.service().read(Clone::clone), model.service().read(Clone::clone), "the map holds exactly the acknowledged writes");
    }
}
