//! The [`Backend`] every program uses: the settings saved and in force, the
//! store they live in, and the admin password, over a [`Platform`] that
//! says what only the board knows (its model, its MAC, its network) and
//! does what only it can do (reboot, blink, draw a random salt).
//!
//! A change goes store first, then the running device: a setting is never
//! in force without being saved, and a failed save changes nothing.

use core::cell::RefCell;

use embassy_sync::blocking_mutex::Mutex as BlockingMutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embassy_time::Duration;
use embedded_storage_async::nor_flash::NorFlash;

use super::backend::{Backend, NetworkStatus, Refusal, RobotLinkStatus, RobotSource};
use crate::device::Device;
use crate::server::Server;
use crate::settings::Settings;
use crate::storage::{Loaded, Password, PasswordHash, StorageStatus, Store};

/// What only the program around the adapter knows or can do.
#[allow(async_fn_in_trait, reason = "the executor is single-threaded: no future needs to be Send")]
pub trait Platform {
    /// The board, as `/api/status` names it (`nucleo-f429zi`).
    fn model(&self) -> &'static str;
    /// The Ethernet MAC address.
    fn mac(&self) -> [u8; 6];
    /// The network as it is now.
    fn network(&self) -> NetworkStatus;
    /// Reboots now (never returns on a board; hal-sim exits for its supervisor).
    fn reboot(&self);
    /// Blinks the status LED for `duration`.
    fn locate(&self, duration: Duration);
    /// 16 unpredictable bytes for a password's salt.
    fn salt(&self) -> [u8; 16];
    /// The port the API listens on (hal-sim: `--http-port`).
    fn http_port(&self) -> u16 {
        super::HTTP_PORT
    }
    /// Why the device last reset, where the chip says (`power-on`, `watchdog`, ...).
    fn reset_reason(&self) -> Option<&'static str> {
        None
    }
    /// Where the robot's points come from while no robot link is set: none
    /// on the boards, the simulated robot in hal-sim.
    fn local_robot(&self) -> RobotSource {
        RobotSource::None
    }
    /// The robot link the program runs (feature `robot-link`): it takes the
    /// `robot` settings at once, and its health is in the status.
    #[cfg(feature = "robot-link")]
    fn link(&self) -> Option<&crate::link::Link> {
        None
    }
    /// The largest update file the device takes; 0: none (feature `update`).
    #[cfg(feature = "update")]
    fn firmware_capacity(&self) -> usize {
        0
    }
    /// Takes an update file from `body` and arms the swap to it
    /// ([`super::Backend::receive_firmware`]); a board feeds its updater
    /// with [`super::feed_update`].
    #[cfg(feature = "update")]
    async fn receive_firmware<R: embedded_io_async::Read>(
        &self,
        body: &mut super::request::Stream<'_, R>,
    ) -> Result<crate::io::Version, super::FirmwareRefusal> {
        let _ = body;
        Err(super::FirmwareRefusal::Unsupported)
    }
}

/// The settings and the password as saved and in force.
struct State {
    settings: Settings,
    password: Password,
    storage: StorageStatus,
}

/// The program's [`Backend`]: settings, store and password over a [`Platform`].
pub struct Controller<'a, F: NorFlash, P: Platform> {
    server: &'a Server<'a, Device<'a>>,
    platform: P,
    store: Mutex<CriticalSectionRawMutex, Store<F>>,
    state: BlockingMutex<CriticalSectionRawMutex, RefCell<State>>,
}

impl<F: NorFlash, P: Platform> core::fmt::Debug for Controller<'_, F, P> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Controller").finish_non_exhaustive()
    }
}

impl<'a, F: NorFlash, P: Platform> Controller<'a, F, P> {
    /// A controller over `store` as `loaded` found it, with the server
    /// (and its device) built from `loaded.settings`.
    pub fn new(server: &'a Server<'a, Device<'a>>, platform: P, store: Store<F>, loaded: &Loaded) -> Self {
        let state = State { settings: loaded.settings, password: loaded.password, storage: loaded.status };
        Self { server, platform, store: Mutex::new(store), state: BlockingMutex::new(RefCell::new(state)) }
    }

    /// The platform.
    pub fn platform(&self) -> &P {
        &self.platform
    }

    fn password(&self) -> Password {
        self.state.lock(|state| state.borrow().password)
    }
}

impl<F: NorFlash, P: Platform> Backend for Controller<'_, F, P> {
    fn server(&self) -> &Server<'_, Device<'_>> {
        self.server
    }

    fn settings(&self) -> Settings {
        self.state.lock(|state| state.borrow().settings)
    }

    async fn apply(&self, settings: &Settings) -> Result<bool, Refusal> {
        let mut store = self.store.lock().await;
        let saved = store.save_settings(settings).await;
        let storage = store.status();
        self.state.lock(|state| state.borrow_mut().storage = storage);
        if saved.is_err() {
            warn!("settings: the save failed; nothing changed");
            return Err(Refusal::Storage);
        }
        let before = self.state.lock(|state| core::mem::replace(&mut state.borrow_mut().settings, *settings));
        // What applies at once goes in force now; the port stays as the
        // listeners opened it until the reboot.
        let port = self.server.with_config(|config| config.port);
        self.server.set_config(crate::server::Config { port, ..settings.server_config(self.platform.mac()) });
        self.server.service().set_watchdog(settings.watchdog());
        #[cfg(feature = "robot-link")]
        if let Some(link) = self.platform.link() {
            link.configure(&settings.robot);
        }
        info!("settings: saved and applied");
        Ok(before.reboot_required(settings))
    }

    fn password_set(&self) -> bool {
        self.password().is_set()
    }

    async fn verify_password(&self, password: &[u8]) -> bool {
        self.password().verify(password)
    }

    async fn set_password(&self, password: &[u8]) -> Result<(), Refusal> {
        let Ok(hash) = PasswordHash::new(password, self.platform.salt()) else { return Err(Refusal::Unsupported) };
        let mut store = self.store.lock().await;
        let saved = store.save_password(&hash).await;
        let storage = store.status();
        self.state.lock(|state| state.borrow_mut().storage = storage);
        if saved.is_err() {
            warn!("password: the save failed; nothing changed");
            return Err(Refusal::Storage);
        }
        self.state.lock(|state| state.borrow_mut().password = Password::Set(hash));
        info!("password: set");
        Ok(())
    }

    fn reboot(&self) {
        self.platform.reboot();
    }

    async fn factory_reset(&self) {
        let mut store = self.store.lock().await;
        if store.factory_reset().await.is_err() {
            warn!("factory reset: erasing the settings failed");
        }
        drop(store);
        self.platform.reboot();
    }

    fn locate(&self, duration: Duration) {
        self.platform.locate(duration);
    }

    fn model(&self) -> &'static str {
        self.platform.model()
    }

    fn mac(&self) -> [u8; 6] {
        self.platform.mac()
    }

    fn http_port(&self) -> u16 {
        self.platform.http_port()
    }

    fn reset_reason(&self) -> Option<&'static str> {
        self.platform.reset_reason()
    }

    fn network(&self) -> NetworkStatus {
        self.platform.network()
    }

    fn robot_source(&self) -> RobotSource {
        #[cfg(feature = "robot-link")]
        if self.platform.link().is_some_and(crate::link::Link::is_set) {
            return RobotSource::Link;
        }
        self.platform.local_robot()
    }

    fn robot_link(&self) -> Option<RobotLinkStatus> {
        #[cfg(feature = "robot-link")]
        return self.platform.link().and_then(|link| robot_link_status(link.status()));
        #[cfg(not(feature = "robot-link"))]
        None
    }

    fn storage(&self) -> Option<StorageStatus> {
        Some(self.state.lock(|state| state.borrow().storage))
    }

    #[cfg(feature = "update")]
    fn firmware_capacity(&self) -> usize {
        self.platform.firmware_capacity()
    }

    #[cfg(feature = "update")]
    async fn receive_firmware<R: embedded_io_async::Read>(
        &self,
        body: &mut super::request::Stream<'_, R>,
    ) -> Result<crate::io::Version, super::FirmwareRefusal> {
        let received = self.platform.receive_firmware(body).await;
        if received.is_ok() {
            self.server.service().set_firmware_update_state(crate::update::BootState::Armed);
        }
        received
    }
}

/// The name in the settings in force, as the API changes it.
impl<F: NorFlash, P: Platform> crate::net::DeviceName for Controller<'_, F, P> {
    fn device_name(&self) -> crate::settings::Name {
        self.settings().device.name.or_default(self.platform.mac())
    }
}

/// The link's health as `/api/status` reports it (`connected` is the
/// link being up); `None` while no link is set.
#[cfg(feature = "robot-link")]
fn robot_link_status(status: crate::link::Status) -> Option<RobotLinkStatus> {
    status.target?;
    let last_ok_ms = status.last_ok.map(|at| u32::try_from(at.elapsed().as_millis()).unwrap_or(u32::MAX));
    Some(RobotLinkStatus { connected: status.up, polls: status.polls, errors: status.errors, last_ok_ms })
}

#[cfg(test)]
mod tests {
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

    /// A platform that remembers whether it was told to reboot, with a robot link.
    #[derive(Default)]
    struct TestPlatform {
        reboots: Cell<u32>,
        #[cfg(feature = "robot-link")]
        link: crate::link::Link,
    }

    impl Platform for TestPlatform {
        fn model(&self) -> &'static str {
            "test"
        }
        fn mac(&self) -> [u8; 6] {
            [2, 0, 0, 0, 0, 1]
        }
        fn network(&self) -> NetworkStatus {
            NetworkStatus { mode: crate::settings::NetMode::Static, address: None, gateway: None, link: true }
        }
        fn reboot(&self) {
            self.reboots.set(self.reboots.get() + 1);
        }
        fn locate(&self, _: Duration) {}
        fn salt(&self) -> [u8; 16] {
            [9; 16]
        }
        #[cfg(feature = "robot-link")]
        fn link(&self) -> Option<&crate::link::Link> {
            Some(&self.link)
        }
    }

    fn controller(memory: &'static mut [u8]) -> Controller<'static, Flash, TestPlatform> {
        let (server, _) = server_with(Config::DEFAULT, Watchdog::OFF);
        let mut store = Store::new(Flash::new(memory), RANGE).unwrap();
        let loaded = block_on(store.load(&Settings::DEFAULT));
        Controller::new(server, TestPlatform::default(), store, &loaded)
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
        assert_eq!(control.storage().map(|s| (s.ok, s.records > 0)), Some((true, true)));
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
        assert_eq!(control.platform().link.status().target, changed.robot.link);
        assert_eq!(control.robot_source(), RobotSource::Link);
        assert_eq!(control.robot_link().map(|link| link.connected), Some(false), "set, not up yet");
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
}
