//! The settings service over a real store on a rule-keeping flash.

use core::cell::Cell;
use core::ops::Range;

use embassy_futures::block_on;

use super::*;
use crate::device::Watchdog;
use crate::server::Config;
use crate::server::testing::{Clock, server_with};
use crate::settings::Field;
use crate::storage::flash::RuleFlash;

const PAGE: usize = 4096;
const RANGE: Range<u32> = 0..(2 * PAGE) as u32;
type Flash = RuleFlash<'static, 4, PAGE>;

/// A platform that remembers whether it was told to reboot.
#[derive(Default)]
struct TestPlatform {
    reboots: Cell<u32>,
}

impl Platform for TestPlatform {
    fn model(&self) -> &'static str {
        "test"
    }
    fn mac(&self) -> [u8; 6] {
        [2, 0, 0, 0, 0, 1]
    }
    fn network(&self) -> NetworkStatus {
        NetworkStatus { mode: NetMode::Static, address: None, gateway: None, link: true }
    }
    fn reboot(&self) {
        self.reboots.set(self.reboots.get() + 1);
    }
    fn locate(&self, _: Duration) {}
    fn salt(&self) -> [u8; 16] {
        [9; 16]
    }
}

fn controller(memory: &'static mut [u8]) -> Controller<'static, Flash, TestPlatform> {
    let (server, _) = server_with(Config::DEFAULT, Watchdog::OFF);
    let mut store = Store::new(Flash::new(memory), RANGE).unwrap();
    let loaded = block_on(store.load(&Settings::DEFAULT));
    let controller = Controller::new(server, TestPlatform::default(), store, &loaded);
    #[cfg(feature = "robot-link")]
    let controller = controller.with_robot_link(Box::leak(Box::default()));
    controller
}

fn memory() -> &'static mut [u8] {
    Box::leak(vec![0xff; 2 * PAGE].into_boxed_slice())
}

#[test]
fn the_device_name_follows_a_change_at_once() {
    use crate::net::DeviceName;
    let _clock = Clock::take();
    let control = controller(memory());
    assert_eq!(control.device_name().as_str(), "mbio-000001", "unset: made from the MAC");
    let mut changed = control.settings();
    changed.set(Field::DeviceName, "press-7").unwrap();
    assert_eq!(block_on(control.apply(&changed)), Ok(false));
    assert_eq!(control.device_name().as_str(), "press-7");
}

#[test]
fn a_change_is_saved_then_in_force_and_survives_a_restart() {
    let _clock = Clock::take();
    let memory = memory();
    let address = memory.as_ptr() as usize;
    let control = controller(memory);
    let mut changed = control.settings();
    changed.set(Field::ModbusUnitId, "7").unwrap();
    changed.set(Field::WatchdogTimeout, "500").unwrap();
    changed.set(Field::ModbusPort, "1502").unwrap();
    assert_eq!(block_on(control.apply(&changed)), Ok(true), "the port needs a reboot");
    assert_eq!(control.settings(), changed);
    let config = control.server().config();
    assert_eq!(config.policy.unit_id, Some(7), "the unit id is in force at once");
    assert_eq!(config.port, 502, "the port waits for the reboot");
    assert_eq!(control.server().service().watchdog().timeout, Some(Duration::from_millis(500)));
    let storage = control.storage();
    assert_eq!((storage.ok, storage.records > 0), (true, true));
    // A restart on the same flash finds the change.
    drop(control);
    // SAFETY (test): the controller that borrowed the memory is gone.
    let memory = unsafe { core::slice::from_raw_parts_mut(address as *mut u8, 2 * PAGE) };
    assert_eq!(controller(memory).settings(), changed);
}

#[cfg(feature = "robot-link")]
#[test]
fn the_robot_settings_reach_the_link_at_once() {
    let _clock = Clock::take();
    let control = controller(memory());
    assert_eq!(control.robot_source(), RobotSource::None, "no link set: the platform's own source");
    assert_eq!(control.robot_link(), None);
    let mut changed = control.settings();
    changed.set(Field::RobotLinkAddress, "198.18.0.1:1502/2").unwrap();
    changed.set(Field::RobotPollInterval, "250").unwrap();
    assert_eq!(block_on(control.apply(&changed)), Ok(false), "no reboot");
    assert_eq!(control.link.map(|link| link.health().target), Some(changed.robot.link));
    assert_eq!(control.robot_source(), RobotSource::Link);
    assert_eq!(control.robot_link().map(|link| link.up), Some(false), "set, not up yet");
}

#[test]
fn the_password_is_saved_hashed_and_checked() {
    let _clock = Clock::take();
    let control = controller(memory());
    assert!(!control.password_set());
    assert_eq!(block_on(control.set_password(b"correct horse")), Ok(()));
    assert!(control.password_set());
    assert!(block_on(control.verify_password(b"correct horse")));
    assert!(!block_on(control.verify_password(b"correct horsf")));
}

#[test]
fn a_factory_reset_erases_and_reboots() {
    let _clock = Clock::take();
    let control = controller(memory());
    let mut changed = control.settings();
    changed.set(Field::DeviceName, "saved").unwrap();
    block_on(control.apply(&changed)).unwrap();
    block_on(control.factory_reset());
    assert_eq!(control.platform().reboots.get(), 1);
}

/// The first password may be set within the window from the start, and
/// not after it, until the button opens it again; a set password is
/// changed at any time.
#[test]
fn the_first_password_only_within_the_window_of_power_up_or_the_button() {
    let clock = Clock::take();
    let control = controller(memory());
    assert!(control.first_password_open(), "at power-up");
    clock.advance(FIRST_PASSWORD_WINDOW - Duration::from_secs(1));
    assert!(control.first_password_open(), "a second before the window closes");
    clock.advance(Duration::from_secs(1));
    assert!(!control.first_password_open(), "10 minutes after power-up");
    assert_eq!(block_on(control.set_password(b"too late!")), Err(Refusal::FirstPasswordClosed));
    assert!(!control.password_set(), "nothing saved");

    control.open_first_password_window();
    assert!(control.first_password_open(), "the button opens it again");
    assert_eq!(block_on(control.set_password(b"the owner's")), Ok(()));
    assert!(!control.first_password_open(), "closed once a password is set");

    clock.advance(FIRST_PASSWORD_WINDOW * 3);
    assert_eq!(block_on(control.set_password(b"a new one")), Ok(()), "a change of a set password needs no window");
    assert!(block_on(control.verify_password(b"a new one")));
}
