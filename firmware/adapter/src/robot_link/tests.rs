//! The link's bookkeeping without a network: what a poll, a failure and a
//! change of target do to the image, the status and the counters.

use super::*;
use crate::device::Watchdog;
use crate::io::RobotState;
use crate::server::testing::{Clock, MODEL, RecordingPins};
use crate::settings::Settings;

fn device() -> &'static Device<'static> {
    let pins: &'static RecordingPins = Box::leak(Box::default());
    Box::leak(Box::new(Device::new(Watchdog::OFF, MODEL, pins)))
}

fn target() -> RobotSettings {
    RobotSettings { link: RobotLink::parse_optional("198.18.1.2:1502/3").unwrap(), poll_ms: 100 }
}

/// A poll as a controller OPERATING with servo on would answer: version
/// 2.11.3, and every telemetry register `generation` (reserved ones too,
/// which the image must not take).
fn snapshot(generation: u16) -> Snapshot {
    let mut s = Snapshot { head: [generation; HEAD_LEN], task: [generation; TASK_LEN] };
    s.head[..9].copy_from_slice(&[2, 11, 3, RobotState::Operating as u16, 1, 0, 0, 0, 1]);
    s
}

struct NoPins;

impl crate::io::InputPins for NoPins {
    fn digital(&mut self) -> u16 {
        0
    }
    fn tool(&mut self) -> u8 {
        0
    }
    fn analog(&mut self, _: usize, _: crate::io::AnalogType) -> u16 {
        0
    }
}

fn robot_points(device: &Device<'_>) -> Vec<u16> {
    device.read(|image| (256..=435).map(|a| image.register(a)).collect())
}

#[test]
fn blocks_cover_the_robot_points_in_two_reads() {
    assert_eq!((HEAD.start, HEAD.quantity), (256, 60));
    assert_eq!((TASK.start, TASK.quantity), (400, 36));
    // Every robot register of the map is in one of them, and nothing else but reserved ones.
    for address in 256..=435u16 {
        let row = table::register_row(address).unwrap();
        let covered = (256..=315).contains(&address) || (400..=435).contains(&address);
        assert!(covered || row.access == Permission::Reserved, "{address}");
    }
}

#[test]
fn timeouts_are_twice_the_period_at_least_200_ms() {
    assert_eq!(timeout(Duration::from_millis(20)), Duration::from_millis(200));
    assert_eq!(timeout(Duration::from_millis(100)), Duration::from_millis(200));
    assert_eq!(timeout(Duration::from_millis(250)), Duration::from_millis(500));
    assert_eq!(timeout(Duration::from_millis(1000)), Duration::from_millis(2000));
}

#[test]
fn values_that_cannot_be_are_nonsense() {
    assert!(snapshot(7).makes_sense());
    assert!(Snapshot::ZERO.makes_sense());
    let mut bad_state = snapshot(7);
    bad_state.head[3] = 11;
    assert!(!bad_state.makes_sense());
    let mut not_ready = snapshot(7);
    not_ready.head[3] = 15;
    assert!(not_ready.makes_sense());
    let mut bad_flag = snapshot(7);
    bad_flag.head[4] = 2;
    assert!(!bad_flag.makes_sense());
    let mut bad_safety = snapshot(7);
    bad_safety.head[6] = 3;
    assert!(!bad_safety.makes_sense());
    let mut reserved = snapshot(7);
    reserved.head[9] = 0xffff; // 265
    assert!(reserved.makes_sense(), "reserved registers are not looked at");
}

#[test]
fn a_good_poll_is_applied_whole_and_counted() {
    let clock = Clock::take();
    let device = device();
    let link = Link::new();
    link.configure(&target());
    link.reset(device);
    assert_eq!(device.read(|i| i.register(259)), 15);
    link.good(device, &snapshot(42));
    let points = robot_points(device);
    for (address, value) in (256u16..).zip(&points) {
        let expected = match address {
            256..=264 => [2, 11, 3, 2, 1, 0, 0, 0, 1][usize::from(address - 256)],
            _ if table::register_row(address).unwrap().access == Permission::Reserved => 0,
            _ => 42,
        };
        assert_eq!(*value, expected, "register {address}");
    }
    assert!(device.read(|i| i.coil(260)), "coil 260 follows register 260");
    clock.advance(Duration::from_millis(30));
    let status = link.health();
    assert!(status.up);
    assert_eq!((status.polls, status.errors), (1, 0));
    assert_eq!(status.last_ok.map(|at| at.elapsed()), Some(Duration::from_millis(30)));
    let counters = device.stats().snapshot();
    assert_eq!((counters.robot_polls, counters.robot_errors, counters.robot_link_downs), (1, 0, 0));
}

#[test]
fn three_failed_polls_in_a_row_take_the_link_down() {
    let _clock = Clock::take();
    let device = device();
    let link = Link::new();
    link.configure(&target());
    link.good(device, &snapshot(5));
    link.failed(device, true);
    link.failed(device, true);
    assert!(link.health().up, "two failures: still up, the last poll's values");
    assert_eq!(device.read(|i| i.register(270)), 5);
    link.good(device, &snapshot(6));
    link.failed(device, true);
    link.failed(device, true);
    assert!(link.health().up, "a good poll starts the count afresh");
    link.failed(device, true);
    assert!(!link.health().up);
    let points = robot_points(device);
    assert_eq!(points[3], 15, "259 reads NOT READY");
    assert!(points.iter().enumerate().all(|(i, &v)| i == 3 || v == 0), "the rest reads 0: {points:?}");
    let counters = device.stats().snapshot();
    assert_eq!((counters.robot_polls, counters.robot_errors, counters.robot_link_downs), (2, 5, 1));
    link.good(device, &snapshot(7));
    assert!(link.health().up, "and back with the next good poll");
    assert_eq!(device.read(|i| i.register(259)), 2);
}

#[test]
fn no_connection_is_down_at_once() {
    let _clock = Clock::take();
    let device = device();
    let link = Link::new();
    link.configure(&target());
    link.good(device, &snapshot(5));
    link.failed(device, false);
    assert!(!link.health().up);
    assert_eq!(device.read(|i| (i.register(259), i.register(256), i.register(270))), (15, 0, 0));
}

#[test]
fn a_set_link_keeps_the_board_source_off_the_robot_points() {
    let _clock = Clock::take();
    let device = device();
    let link = Link::new();
    struct Operating;
    impl Robot for Operating {
        fn status(&mut self) -> RobotStatus {
            RobotStatus { state: RobotState::Operating, ..RobotStatus::NOT_READY }
        }
        fn telemetry(&mut self) -> Telemetry {
            Telemetry { joint_position: [9; 6], ..Telemetry::default() }
        }
        fn version(&mut self) -> Version {
            Version { major: 1, minor: 2, patch: 3 }
        }
    }
    let mut robot = Gated::new(&link, Operating);
    device.refresh(&mut NoPins, &mut robot);
    assert_eq!(device.read(|i| (i.register(259), i.register(270))), (2, 9), "no link: the board's robot");
    link.configure(&target());
    assert!(link.is_set());
    link.reset(device);
    device.refresh(&mut NoPins, &mut robot);
    assert_eq!(device.read(|i| (i.register(259), i.register(270))), (15, 0), "a link set: not the board's");
    link.configure(&Settings::DEFAULT.robot);
    assert!(!link.is_set());
    device.refresh(&mut NoPins, &mut robot);
    assert_eq!(device.read(|i| i.register(259)), 2);
}

#[test]
fn a_new_period_is_in_force_at_once() {
    let link = Link::new();
    link.configure(&target());
    assert_eq!(link.period(), Duration::from_millis(100));
    link.configure(&RobotSettings { poll_ms: 250, ..target() });
    assert_eq!(link.period(), Duration::from_millis(250));
}
