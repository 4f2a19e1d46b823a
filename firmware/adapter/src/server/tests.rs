//! The server over a device: read-only clients, counted session errors.

use core::pin::pin;

use embassy_time::Duration;

use test_support::duplex::{Wire, poll_once};
use test_support::framer::{adu, split_replies};

use super::testing::{Clock, RecordingPins, server_with};
use super::*;
use crate::device::Watchdog;
use crate::modbus::mbap::MAX_ADU_LEN;

const WRITE_COIL_16_ON: [u8; 5] = [0x05, 0x00, 0x10, 0xff, 0x00];
const READ_128: [u8; 5] = [0x03, 0x00, 0x80, 0x00, 0x01];

fn shared_with(config: Config) -> (&'static Server<'static, crate::device::Device<'static>>, &'static RecordingPins) {
    server_with(config, Watchdog::OFF)
}

#[test]
fn a_read_only_client_may_read_and_its_writes_get_exception_01() {
    let _clock = Clock::take();
    let (shared, pins) = shared_with(Config::DEFAULT);
    shared.slots().open(0, 8, embassy_time::Instant::now(), [198, 18, 0, 1], Rights::Read);
    let (wire, mut end) = Wire::new();
    let mut session = pin!(serve(&mut end, shared, 0));
    let writes: [&[u8]; 4] = [
        &WRITE_COIL_16_ON,
        &[0x06, 0x00, 0x80, 0x00, 0x01],
        &[0x0f, 0x00, 0x10, 0x00, 0x01, 0x01, 0x01],
        &[0x10, 0x00, 0x80, 0x00, 0x01, 0x02, 0x00, 0x01],
    ];
    for pdu in writes {
        wire.send(&adu(7, 0, 1, pdu));
    }
    wire.send(&adu(8, 0, 1, &READ_128));
    assert!(poll_once(session.as_mut()).is_pending());
    let replies = split_replies(&wire.take_replies());
    for (reply, pdu) in replies.iter().zip(writes) {
        assert_eq!(reply[7..], [pdu[0] | 0x80, 0x01]);
    }
    assert_eq!(replies[4][7..], [0x03, 0x02, 0x00, 0x00], "reads are served");
    assert_eq!(shared.service().read(|image| image.register(1)), 0);
    assert_eq!(pins.calls.load(std::sync::atomic::Ordering::Relaxed), 0, "no output was driven");
    assert_eq!(shared.stats().snapshot().refused_writes, 4);
    assert_eq!(shared.stats().snapshot().bad_function, 0);
}

#[test]
fn a_server_wide_read_only_policy_holds_whatever_the_slot_says() {
    let _clock = Clock::take();
    let config = Config { policy: Policy { rights: Rights::Read, ..Policy::default() }, ..Config::DEFAULT };
    let (shared, _) = shared_with(config);
    shared.slots().open(0, 8, embassy_time::Instant::now(), [198, 18, 0, 1], Rights::ReadWrite);
    let (wire, mut end) = Wire::new();
    let mut session = pin!(serve(&mut end, shared, 0));
    wire.send(&adu(1, 0, 1, &WRITE_COIL_16_ON));
    assert!(poll_once(session.as_mut()).is_pending());
    assert_eq!(split_replies(&wire.take_replies())[0][7..], [0x85, 0x01]);
}

#[test]
fn sessions_count_bad_lengths_and_timeouts() {
    let clock = Clock::take();
    let (shared, _) = shared_with(Config { idle_timeout: Some(Duration::from_secs(5)), ..Config::DEFAULT });
    let (wire, mut end) = Wire::new();
    wire.send(&[0, 1, 0, 0, 0, 0]);
    assert!(poll_once(pin!(serve(&mut end, shared, 0))).is_ready());
    let (_wire, mut end) = Wire::new();
    let mut idle = pin!(serve(&mut end, shared, 1));
    assert!(poll_once(idle.as_mut()).is_pending());
    clock.advance(Duration::from_secs(5));
    assert!(poll_once(idle.as_mut()).is_ready());
    let c = shared.stats().snapshot();
    assert_eq!((c.bad_length, c.timeouts), (1, 1));
    drop(wire);
}

#[test]
fn identification_answers_the_name_in_force() {
    let _clock = Clock::take();
    let named = |name: &str| Config { name: crate::settings::Name::parse(name).unwrap(), ..Config::DEFAULT };
    let (shared, _) = shared_with(named("press-4"));
    let (wire, mut end) = Wire::new();
    let mut session = pin!(serve(&mut end, shared, 0));
    let user_application_name = [0x2b, 0x0e, 0x04, 0x06];
    wire.send(&adu(1, 0, 1, &user_application_name));
    assert!(poll_once(session.as_mut()).is_pending());
    // The settings API changes the name: the next request sees it.
    shared.set_config(named("press-5"));
    wire.send(&adu(2, 0, 1, &user_application_name));
    assert!(poll_once(session.as_mut()).is_pending());
    let replies = split_replies(&wire.take_replies());
    assert_eq!(replies[0][7..], [&[0x2b, 0x0e, 0x04, 0x82, 0, 0, 1, 6, 7][..], b"press-4"].concat());
    assert_eq!(replies[1][7..], [&[0x2b, 0x0e, 0x04, 0x82, 0, 0, 1, 6, 7][..], b"press-5"].concat());
    let mut reply = [0u8; MAX_ADU_LEN];
    let Outcome::Reply { len, .. } = shared.respond(&adu(3, 0, 1, &[0x2b, 0x0e, 0x04, 0x05]), &mut reply) else {
        panic!()
    };
    assert_eq!(reply[14..len], [&[5, 10][..], b"test-board"].concat(), "the device's model");
}

#[test]
fn a_read_only_client_may_not_clear_the_counters() {
    let _clock = Clock::take();
    let (shared, _) = shared_with(Config::DEFAULT);
    shared.slots().open(0, 8, embassy_time::Instant::now(), [198, 18, 0, 1], Rights::Read);
    let (wire, mut end) = Wire::new();
    let mut session = pin!(serve(&mut end, shared, 0));
    wire.send(&adu(1, 0, 1, &READ_128));
    wire.send(&adu(2, 0, 1, &[0x08, 0x00, 0x0a, 0x00, 0x00]));
    wire.send(&adu(3, 0, 1, &[0x08, 0x00, 0x0b, 0x00, 0x00]));
    assert!(poll_once(session.as_mut()).is_pending());
    let replies = split_replies(&wire.take_replies());
    assert_eq!(replies[1][7..], [0x88, 0x01], "Clear Counters is a change: refused");
    assert_eq!(replies[2][7..], [0x08, 0x00, 0x0b, 0x00, 0x02], "nothing cleared: two requests before");
    assert_eq!(shared.stats().snapshot().refused_writes, 1);
}

#[test]
fn a_new_configuration_applies_to_the_next_request() {
    let _clock = Clock::take();
    let (shared, _) = shared_with(Config::DEFAULT);
    let (wire, mut end) = Wire::new();
    let mut session = pin!(serve(&mut end, shared, 0));
    wire.send(&adu(1, 0, 9, &READ_128));
    assert!(poll_once(session.as_mut()).is_pending());
    shared.set_config(Config { policy: Policy { unit_id: Some(7), ..Policy::default() }, ..Config::DEFAULT });
    wire.send(&adu(2, 0, 9, &READ_128));
    assert!(poll_once(session.as_mut()).is_pending());
    let replies = split_replies(&wire.take_replies());
    assert_eq!(replies[0][7..], [0x03, 0x02, 0x00, 0x00]);
    assert_eq!(replies[1][7..], [0x83, 0x0b], "unit 9 is no longer answered");
}
