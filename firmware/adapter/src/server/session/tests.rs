//! Sessions over an in-memory duplex, with embassy-time's mock clock.

use core::pin::pin;
use core::task::Poll;

use embassy_time::{Duration, Instant};
use embedded_io_async::ErrorKind;

use super::{Error, serve};
use crate::device::Device;
use crate::device::Watchdog;
use crate::server::testing::{Clock, server_with};
use crate::server::{Config, Outcome, Rights, Server};
use test_support::duplex::{Wire, poll_once};
use test_support::fixtures::PYMODBUS;
use test_support::framer::{self, adu, split_replies};

const IDLE: Duration = Duration::from_secs(10);
const FRAME: Duration = Duration::from_secs(2);

fn shared(max_connections: usize, idle_timeout: Option<Duration>) -> &'static Server<'static, Device<'static>> {
    let config = Config { max_connections, idle_timeout, frame_timeout: FRAME, ..Config::DEFAULT };
    server_with(config, Watchdog::OFF).0
}

/// Every captured request, back to back.
fn pipeline() -> Vec<u8> {
    PYMODBUS.iter().flat_map(|f| f.request.iter().copied()).collect()
}

/// The replies a fresh server gives to `requests`, one frame at a time
/// (framed by the reference framer, not the session's).
fn expected(requests: &[u8]) -> Vec<Vec<u8>> {
    let oracle = shared(1, None);
    let mut reply = [0u8; crate::modbus::mbap::MAX_ADU_LEN];
    let mut out = Vec::new();
    for frame in framer::split(requests).frames {
        if let Outcome::Reply { len, .. } = oracle.respond(frame, &mut reply) {
            out.push(reply[..len].to_vec());
        }
    }
    out
}

/// Runs a whole session over `bytes` sent in reads of at most `segment` bytes.
fn run(bytes: &[u8], segment: usize) -> (Result<(), Error<ErrorKind>>, Vec<Vec<u8>>) {
    let _clock = Clock::take();
    let shared = shared(8, Some(IDLE));
    let (wire, mut end) = Wire::new();
    wire.read_sizes([segment]);
    wire.send(bytes);
    wire.close();
    let mut session = pin!(serve(&mut end, shared, 0));
    let Poll::Ready(result) = poll_once(session.as_mut()) else { panic!("session waits with all input there") };
    (result, split_replies(&wire.take_replies()))
}

#[test]
fn pipelined_requests_are_each_answered_in_order() {
    let (result, replies) = run(&pipeline(), 0);
    assert_eq!(result, Ok(()));
    assert_eq!(replies, expected(&pipeline()));
    let ids: Vec<u16> = replies.iter().map(|r| u16::from_be_bytes([r[0], r[1]])).collect();
    assert_eq!(ids, [1, 2, 3, 4, 5, 6]);
}

#[test]
fn every_split_of_the_stream_gives_the_same_replies() {
    let want = expected(&pipeline());
    for segment in 1..=40 {
        let (result, replies) = run(&pipeline(), segment);
        assert_eq!(result, Ok(()), "segments of {segment}");
        assert_eq!(replies, want, "segments of {segment}");
    }
}

#[test]
fn a_request_sent_one_byte_at_a_time_is_answered_once_complete() {
    let _clock = Clock::take();
    let shared = shared(8, Some(IDLE));
    let (wire, mut end) = Wire::new();
    let mut session = pin!(serve(&mut end, shared, 0));
    let request = PYMODBUS[0].request;
    for (i, byte) in request.iter().enumerate() {
        wire.send(&[*byte]);
        assert!(poll_once(session.as_mut()).is_pending());
        let replies = wire.take_replies();
        if i + 1 < request.len() {
            assert!(replies.is_empty(), "no reply after {} of {} bytes", i + 1, request.len());
        } else {
            assert_eq!(split_replies(&replies), expected(request));
        }
    }
}

#[test]
fn the_largest_frames_fit() {
    // FC 10 with 123 registers: a 259-byte ADU.
    let mut pdu = vec![0x10, 0x00, 0x80, 0x00, 123, 246];
    pdu.extend((0..123u16).flat_map(|v| v.to_be_bytes()));
    let write = adu(7, 0, 1, &pdu);
    // An unknown function code with the longest PDU (253 bytes): a 260-byte ADU.
    let unknown = adu(8, 0, 1, &[0x64; 253]);
    assert_eq!((write.len(), unknown.len()), (259, 260));
    let stream = [write.clone(), unknown.clone(), write].concat();
    for segment in [0, 1, 7, 100, 259] {
        let (result, replies) = run(&stream, segment);
        assert_eq!(result, Ok(()));
        assert_eq!(replies.len(), 3, "segments of {segment}");
        assert_eq!(replies[1][7..], [0xe4, 0x01], "unknown function: exception 01");
    }
}

#[test]
fn a_bad_length_closes_the_session_after_the_frames_before_it() {
    for bad in [0u16, 1, 255, 256, u16::MAX] {
        let mut stream = PYMODBUS[0].request.to_vec();
        stream.extend_from_slice(&[0x00, 0x09, 0x00, 0x00]);
        stream.extend_from_slice(&bad.to_be_bytes());
        stream.extend_from_slice(PYMODBUS[1].request);
        let (result, replies) = run(&stream, 0);
        assert_eq!(result, Err(Error::BadLength(bad)));
        assert_eq!(replies, expected(PYMODBUS[0].request), "only the frame before it is answered");
    }
}

#[test]
fn a_bad_length_is_seen_without_waiting_for_more_bytes() {
    let _clock = Clock::take();
    let shared = shared(8, Some(IDLE));
    let (wire, mut end) = Wire::new();
    let mut session = pin!(serve(&mut end, shared, 0));
    wire.send(&[0x00, 0x01, 0x00, 0x00, 0x01, 0x00]); // length 256
    assert_eq!(poll_once(session.as_mut()), Poll::Ready(Err(Error::BadLength(256))));
}

#[test]
fn a_foreign_protocol_id_is_skipped_and_the_session_carries_on() {
    let _clock = Clock::take();
    let shared = shared(8, Some(IDLE));
    let (wire, mut end) = Wire::new();
    let mut session = pin!(serve(&mut end, shared, 0));
    // Protocol id 1, a well-formed length, then a Modbus request.
    wire.send(&[0x00, 0x09, 0x00, 0x01, 0x00, 0x06, 0x01, 0x03, 0x01, 0x00, 0x00, 0x03]);
    wire.send(PYMODBUS[1].request);
    assert!(poll_once(session.as_mut()).is_pending(), "the connection stays open");
    assert_eq!(split_replies(&wire.take_replies()), expected(PYMODBUS[1].request));
}

#[test]
fn an_idle_session_times_out() {
    let clock = Clock::take();
    let shared = shared(8, Some(IDLE));
    let (wire, mut end) = Wire::new();
    let mut session = pin!(serve(&mut end, shared, 0));
    assert!(poll_once(session.as_mut()).is_pending());
    clock.advance(Duration::from_secs(5));
    wire.send(PYMODBUS[0].request); // a request restarts the idle clock
    assert!(poll_once(session.as_mut()).is_pending());
    clock.advance(IDLE - Duration::from_millis(1));
    assert!(poll_once(session.as_mut()).is_pending());
    clock.advance(Duration::from_millis(1));
    assert_eq!(poll_once(session.as_mut()), Poll::Ready(Err(Error::IdleTimeout)));
    assert_eq!(split_replies(&wire.take_replies()).len(), 1);
}

#[test]
fn without_an_idle_timeout_a_session_waits_forever() {
    let clock = Clock::take();
    let shared = shared(8, None);
    let (_wire, mut end) = Wire::new();
    let mut session = pin!(serve(&mut end, shared, 0));
    assert!(poll_once(session.as_mut()).is_pending());
    clock.advance(Duration::from_secs(24 * 3600));
    assert!(poll_once(session.as_mut()).is_pending());
}

#[test]
fn a_frame_that_stops_halfway_times_out() {
    let clock = Clock::take();
    for idle in [Some(IDLE), None] {
        let shared = shared(8, idle);
        let (wire, mut end) = Wire::new();
        let mut session = pin!(serve(&mut end, shared, 0));
        wire.send(&PYMODBUS[0].request[..5]);
        assert!(poll_once(session.as_mut()).is_pending());
        clock.advance(FRAME - Duration::from_millis(1));
        assert!(poll_once(session.as_mut()).is_pending());
        clock.advance(Duration::from_millis(1));
        assert_eq!(poll_once(session.as_mut()), Poll::Ready(Err(Error::FrameTimeout)), "idle {idle:?}");
        assert!(wire.take_replies().is_empty());
    }
}

#[test]
fn a_frame_completed_in_time_is_answered() {
    let clock = Clock::take();
    let shared = shared(8, Some(IDLE));
    let (wire, mut end) = Wire::new();
    let mut session = pin!(serve(&mut end, shared, 0));
    let request = PYMODBUS[0].request;
    wire.send(&request[..5]);
    assert!(poll_once(session.as_mut()).is_pending());
    clock.advance(FRAME - Duration::from_millis(1));
    wire.send(&request[5..]);
    assert!(poll_once(session.as_mut()).is_pending());
    assert_eq!(split_replies(&wire.take_replies()), expected(request));
    // The frame clock restarts with the next frame.
    wire.send(&request[..3]);
    clock.advance(FRAME - Duration::from_millis(1));
    assert!(poll_once(session.as_mut()).is_pending());
}

#[test]
fn the_idlest_session_is_closed_to_make_room() {
    let clock = Clock::take();
    let shared = shared(2, Some(IDLE));
    let slots = shared.slots();
    let (wire_a, mut end_a) = Wire::new();
    let (_wire_b, mut end_b) = Wire::new();
    let (_wire_c, mut end_c) = Wire::new();

    assert_eq!(slots.open(0, 2, Instant::now(), [198, 18, 0, 1], Rights::ReadWrite), None);
    let mut a = pin!(serve(&mut end_a, shared, 0));
    assert!(poll_once(a.as_mut()).is_pending());
    clock.advance(Duration::from_millis(100));
    assert_eq!(slots.open(1, 2, Instant::now(), [198, 18, 0, 1], Rights::ReadWrite), None);
    let mut b = pin!(serve(&mut end_b, shared, 1));
    assert!(poll_once(b.as_mut()).is_pending());

    // A is older but has just made a request: B is now the idlest.
    clock.advance(Duration::from_secs(1));
    wire_a.send(PYMODBUS[0].request);
    assert!(poll_once(a.as_mut()).is_pending());
    clock.advance(Duration::from_secs(1));

    assert_eq!(slots.open(2, 2, Instant::now(), [198, 18, 0, 1], Rights::ReadWrite), Some(1));
    let mut c = pin!(serve(&mut end_c, shared, 2));
    assert!(poll_once(c.as_mut()).is_pending());
    assert_eq!(poll_once(b.as_mut()), Poll::Ready(Err(Error::Evicted)));
    assert!(poll_once(a.as_mut()).is_pending(), "the busy session is kept");
}

#[test]
fn a_reset_ends_the_session() {
    let _clock = Clock::take();
    let shared = shared(8, Some(IDLE));
    let (wire, mut end) = Wire::new();
    let mut session = pin!(serve(&mut end, shared, 0));
    assert!(poll_once(session.as_mut()).is_pending());
    wire.reset();
    assert_eq!(poll_once(session.as_mut()), Poll::Ready(Err(Error::Transport(ErrorKind::ConnectionReset))));
}

#[test]
fn a_client_that_closes_mid_frame_ends_the_session_cleanly() {
    let (result, replies) = run(&PYMODBUS[0].request[..9], 0);
    assert_eq!(result, Ok(()));
    assert!(replies.is_empty());
}
