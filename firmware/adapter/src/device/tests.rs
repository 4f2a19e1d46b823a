//! The device every session and task shares: counters, the communication
//! watchdog, the refresh and the event setters.

use embassy_time::Duration;

use super::*;
use crate::io::{AnalogType, NoRobot, RobotState, RobotStatus, Telemetry, Version};
use crate::map::WritePolicy;
use crate::server::Counters;
use crate::server::testing::{Clock, RecordingPins};
use crate::settings::Name;
use test_support::framer::adu;

/// The device name the requests are answered under.
const NAME: &Name = &match Name::parse("cell-2") {
    Ok(name) => name,
    Err(_) => Name::UNSET,
};

fn shared_with(watchdog: Watchdog) -> (&'static Device<'static>, &'static RecordingPins) {
    let pins: &'static RecordingPins = Box::leak(Box::default());
    (Box::leak(Box::new(Device::new(watchdog, crate::server::testing::MODEL, pins))), pins)
}

fn ask(shared: &Device<'_>, pdu: &[u8]) -> Vec<u8> {
    let mut reply = [0u8; MAX_ADU_LEN];
    match shared.respond(&adu(1, 0, 1, pdu), &mut reply, &Policy::default(), NAME) {
        Outcome::Reply { len, .. } => reply[7..len].to_vec(),
        Outcome::Discard { .. } | Outcome::NotWhole => Vec::new(),
    }
}

const WRITE_COIL_16_ON: [u8; 5] = [0x05, 0x00, 0x10, 0xff, 0x00];
const READ_128: [u8; 5] = [0x03, 0x00, 0x80, 0x00, 0x01];

#[test]
fn counters_follow_what_the_server_sees() {
    let _clock = Clock::take();
    let (shared, _) = shared_with(Watchdog::OFF);
    ask(shared, &READ_128);
    ask(shared, &[0x07]); // Read Exception Status, serial line only: 01
    ask(shared, &[0x03, 0x01, 0xb4, 0x00, 0x01]); // register 436: 02
    ask(shared, &[0x05, 0x00, 0x10, 0x12, 0x34]); // bad coil value: 03
    let foreign = adu(1, 1, 1, &READ_128);
    assert_eq!(
        shared.respond(&foreign, &mut [0; MAX_ADU_LEN], &Policy::default(), NAME),
        Outcome::Discard { protocol_id: 1 }
    );
    let c = shared.stats().snapshot();
    assert_eq!((c.requests, c.bad_function, c.bad_address, c.bad_value, c.bad_protocol), (4, 1, 1, 1, 1));
}

/// Counter `sub` as Diagnostics (08) reads it.
fn count(shared: &Device<'_>, sub: u8) -> u16 {
    let reply = ask(shared, &[0x08, 0x00, sub, 0x00, 0x00]);
    assert_eq!(reply[..3], [0x08, 0x00, sub]);
    u16::from_be_bytes([reply[3], reply[4]])
}

#[test]
fn diagnostics_read_the_counters_as_they_stand_and_clear_them() {
    let _clock = Clock::take();
    let (shared, _) = shared_with(Watchdog::OFF);
    ask(shared, &READ_128);
    ask(shared, &[0x07]); // 01
    ask(shared, &[0x03, 0x01, 0xb4, 0x00, 0x01]); // 02
    shared.respond(&adu(1, 1, 1, &READ_128), &mut [0; MAX_ADU_LEN], &Policy::default(), NAME); // skipped
    let other_unit = Policy { unit_id: Some(9), ..Policy::default() };
    shared.respond(&adu(1, 0, 1, &READ_128), &mut [0; MAX_ADU_LEN], &other_unit, NAME); // 0B
    // Each read counts what came before it: 4 requests (+ the reads before it), 1 skipped.
    assert_eq!(count(shared, 0x0b), 5, "bus messages: 4 requests and 1 frame skipped");
    assert_eq!(count(shared, 0x0d), 3, "exceptions: 01, 02 and 0B");
    assert_eq!(count(shared, 0x0e), 6 - 1, "server messages: 6 requests by now, 1 for another unit");
    assert_eq!(count(shared, 0x0f), 1, "no response: the skipped frame");
    assert_eq!((count(shared, 0x0c), count(shared, 0x12)), (0, 0));
    // A clear empties them all; the clear itself is then counted, as every request is.
    assert_eq!(ask(shared, &[0x08, 0x00, 0x0a, 0x00, 0x00]), [0x08, 0x00, 0x0a, 0x00, 0x00]);
    assert_eq!(shared.stats().snapshot(), Counters { requests: 1, ..Counters::default() });
    assert_eq!(count(shared, 0x0b), 1);
    assert_eq!(count(shared, 0x0b), 2);
    // A client that may not write cannot clear them: refused, and counted as a refused write.
    let read_only = Policy { rights: crate::access::Rights::Read, ..Policy::default() };
    let mut reply = [0u8; MAX_ADU_LEN];
    shared.respond(&adu(1, 0, 1, &[0x08, 0x00, 0x0a, 0x00, 0x00]), &mut reply, &read_only, NAME);
    assert_eq!(reply[7..9], [0x88, 0x01]);
    let c = shared.stats().snapshot();
    assert_eq!((c.requests, c.refused_writes, c.bad_function), (4, 1, 0));
}

#[test]
fn identification_names_the_board_and_the_name_it_is_given() {
    let _clock = Clock::take();
    let (shared, _) = shared_with(Watchdog::OFF);
    assert_eq!(shared.model(), "test-board");
    let mut reply = [0u8; MAX_ADU_LEN];
    let name = |shared: &Device<'_>, name: &str, reply: &mut [u8; MAX_ADU_LEN]| {
        let name = Name::parse(name).unwrap();
        let frame = adu(1, 0, 1, &[0x2b, 0x0e, 0x04, 0x06]);
        let Outcome::Reply { len, .. } = shared.respond(&frame, reply, &Policy::default(), &name) else { panic!() };
        reply[14..len].to_vec()
    };
    assert_eq!(name(shared, "cell-2", &mut reply), [0x06, 6, b'c', b'e', b'l', b'l', b'-', b'2']);
    assert_eq!(name(shared, "x", &mut reply), [0x06, 1, b'x']);
    let Outcome::Reply { len, .. } =
        shared.respond(&adu(1, 0, 1, &[0x2b, 0x0e, 0x04, 0x05]), &mut reply, &Policy::default(), NAME)
    else {
        panic!()
    };
    assert_eq!(&reply[14..len], [&[0x05, 10][..], b"test-board"].concat());
}

#[test]
fn the_watchdog_puts_outputs_in_their_safe_state_until_written_again() {
    let clock = Clock::take();
    let safe_state = SafeState { digital: 0b1000_0000_0000_0000, tool: 0, analog: [4_000, 0] };
    let watchdog = Watchdog { timeout: Some(Duration::from_millis(500)), safe_state };
    let (shared, pins) = shared_with(watchdog);
    let outputs = || pins.last.lock().unwrap().unwrap_or_default();

    // Outputs on, analog output 2 at 15 mA.
    assert_eq!(ask(shared, &[0x06, 0x00, 0x01, 0x00, 0xff]), [0x06, 0x00, 0x01, 0x00, 0xff]);
    assert_eq!(ask(shared, &[0x06, 0x00, 0x12, 0x3a, 0x98])[0], 0x06);
    clock.advance(Duration::from_millis(499));
    assert!(!shared.check_watchdog());
    ask(shared, &READ_128); // a valid request restarts the timer
    clock.advance(Duration::from_millis(499));
    assert!(!shared.check_watchdog());
    ask(shared, &[0x03, 0x01, 0xb4, 0x00, 0x01]); // an exception is not a valid request
    clock.advance(Duration::from_millis(1));
    assert!(!shared.watchdog_tripped());
    assert!(shared.check_watchdog());
    assert!(shared.watchdog_tripped());
    assert_eq!(outputs().digital, 0b1000_0000_0000_0000);
    assert_eq!([outputs().analog[0].value, outputs().analog[1].value], [4_000, 0]);
    assert_eq!(shared.read(|image| image.register(1)), 0b1000_0000_0000_0000, "both views show the safe state");
    assert!(shared.read(|image| image.coil(31)) && !shared.read(|image| image.coil(16)));
    assert_eq!(shared.stats().snapshot().watchdog_trips, 1);

    // It trips once per silence; reading re-arms it but leaves the outputs safe.
    clock.advance(Duration::from_secs(10));
    assert!(!shared.check_watchdog());
    ask(shared, &READ_128);
    assert!(!shared.watchdog_tripped(), "re-armed");
    assert_eq!(outputs().digital, 0b1000_0000_0000_0000);
    // A write restores them; silence trips it again.
    ask(shared, &WRITE_COIL_16_ON);
    assert_eq!(outputs().digital, 0b1000_0000_0000_0001);
    clock.advance(Duration::from_millis(500));
    assert!(shared.check_watchdog());
    assert_eq!(shared.stats().snapshot().watchdog_trips, 2);
}

#[test]
fn without_a_timeout_the_watchdog_never_trips() {
    let clock = Clock::take();
    let (shared, _) = shared_with(Watchdog::OFF);
    ask(shared, &WRITE_COIL_16_ON);
    clock.advance(Duration::from_secs(24 * 3600));
    assert!(!shared.check_watchdog());
    assert!(shared.read(|image| image.coil(16)));
}

/// Inputs that read fixed values.
struct FixedInputs;

impl InputPins for FixedInputs {
    fn digital(&mut self) -> u16 {
        0x00f0
    }
    fn tool(&mut self) -> u8 {
        0b10_0001
    }
    fn analog(&mut self, channel: usize, kind: AnalogType) -> u16 {
        // 25 000 is over either range: the refresh clamps it.
        if channel == 0 { 25_000 } else { kind.max() / 2 }
    }
}

#[test]
fn the_refresh_samples_the_sources_and_re_asserts_them_over_seed_writes() {
    let _clock = Clock::take();
    let (shared, _) = shared_with(Watchdog::OFF);
    // `seed` lets a master write read-only points until the next refresh.
    assert_eq!(ask(shared, &[0x06, 0x01, 0x00, 0x00, 0x63])[0], 0x06); // controller version major := 99
    assert_eq!(ask(shared, &[0x06, 0x00, 0x00, 0x00, 0x01])[0], 0x06); // inputs := 1
    assert_eq!(ask(shared, &[0x06, 0x00, 0x07, 0x00, 0x01])[0], 0x06); // analog input 2: voltage
    shared.refresh(&mut FixedInputs, &mut NoRobot);
    shared.read(|image| {
        assert_eq!([256, 257, 258].map(|a| image.register(a)), [0, 0, 0], "no robot: no controller version");
        assert_eq!(image.register(0), 0x00f0);
        assert!(image.coil(4) && !image.coil(0));
        assert_eq!(image.register(21), 0b10_0001);
        assert!(image.coil(32) && image.coil(37));
        assert_eq!(image.register(4), 20_000, "clamped to the current range");
        assert_eq!(image.register(6), 5_000, "half the voltage range");
        assert_eq!(image.register(259), 15, "no robot: NOT READY");
    });
    assert_eq!(WritePolicy::default(), WritePolicy::Seed);
}

/// A robot source that knows its controller's version.
struct VersionedRobot;

impl Robot for VersionedRobot {
    fn status(&mut self) -> RobotStatus {
        RobotStatus { state: RobotState::Standby, servo_on: true, ..RobotStatus::NOT_READY }
    }
    fn telemetry(&mut self) -> Telemetry {
        Telemetry::default()
    }
    fn version(&mut self) -> Version {
        Version { major: 4, minor: 12, patch: 301 }
    }
}

#[test]
fn registers_256_to_258_are_the_robot_controller_s_version() {
    let _clock = Clock::take();
    let (shared, _) = shared_with(Watchdog::OFF);
    let version = |shared: &Device<'_>| shared.read(|image| [256, 257, 258].map(|a| image.register(a)));
    assert_eq!(version(shared), [0, 0, 0], "until the first refresh: unknown");
    shared.refresh(&mut FixedInputs, &mut VersionedRobot);
    assert_eq!(version(shared), [4, 12, 301]);
    assert_ne!(version(shared), crate::VERSION.registers(), "not the adapter's own");
    assert_eq!(ask(shared, &[0x03, 0x01, 0x00, 0x00, 0x04]), [0x03, 0x08, 0, 4, 0, 12, 0x01, 0x2d, 0, 1]);
    // A source that loses its controller says so; the registers follow.
    shared.refresh(&mut FixedInputs, &mut NoRobot);
    assert_eq!(version(shared), [0, 0, 0]);
}

#[test]
fn event_setters_change_both_views_at_once() {
    let _clock = Clock::take();
    let (shared, _) = shared_with(Watchdog::OFF);
    shared.set_digital_inputs(0x8001);
    shared.set_tool_inputs(0b100);
    shared.set_analog_input(1, 30_000);
    let status = RobotStatus { state: RobotState::EmergencyStop, emergency_stop: true, ..RobotStatus::NOT_READY };
    shared.set_robot_status(&status);
    shared.read(|image| {
        assert_eq!(image.register(0), 0x8001);
        assert!(image.coil(0) && image.coil(15) && !image.coil(1));
        assert!(image.coil(34) && image.register(21) == 0b100);
        assert_eq!(image.register(6), 20_000, "clamped to the current range");
        assert_eq!((image.register(259), image.register(261)), (6, 1));
        assert!(image.coil(261));
    });
}

#[test]
fn a_new_watchdog_applies_at_once() {
    let clock = Clock::take();
    let (shared, pins) = shared_with(Watchdog::OFF);
    ask(shared, &WRITE_COIL_16_ON);
    let safe_state = SafeState { digital: 0b10, ..SafeState::OFF };
    shared.set_watchdog(Watchdog { timeout: Some(Duration::from_millis(100)), safe_state });
    clock.advance(Duration::from_millis(100));
    assert!(shared.check_watchdog());
    assert_eq!(pins.last.lock().unwrap().unwrap().digital, 0b10);
}
