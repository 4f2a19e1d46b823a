//! The settings service: the settings saved and in force, the store they
//! live in, the admin password, and what changes the device as a whole
//! (apply, factory reset, reboot, locate), over a [`Platform`] that says
//! what only the board knows (its model, its MAC, its network) and does
//! what only it can do (reboot, blink, draw a random salt).
//!
//! Every front end changes the device through this one [`Controller`]: the
//! HTTP API (the `http` module) translates requests into its calls, and a
//! button, a command line or a serial console would call the same. The
//! robot link and the firmware updater are optional parts: the link is
//! passed in ([`Controller::with_robot_link`]), the updater through the
//! platform's two update hooks.
//!
//! A change goes store first, then the running device: a setting is never
//! in force without being saved, and a failed save changes nothing.
//! Callers serialize changes (the API holds one lock for them); reads take
//! a blocking lock for a copy and never across an `.await`.

use core::cell::RefCell;

use embassy_sync::blocking_mutex::Mutex as BlockingMutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embassy_time::{Duration, Instant};
use embedded_storage_async::nor_flash::NorFlash;

use crate::device::Device;
use crate::name::Name;
use crate::net::DeviceName;
use crate::server::{Config, Server};
use crate::settings::{Cidr, Ipv4, NetMode, Settings};
use crate::storage::{Loaded, Password, PasswordHash, StorageStatus, Store};

/// What only the program around the adapter knows or can do: the board
/// seam of the settings service.
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
    /// Why the device last reset, where the chip says (`power-on`, `watchdog`, ...).
    fn reset_reason(&self) -> Option<&'static str> {
        None
    }
    /// Where the robot's points come from while no robot link is set: none
    /// on the boards, the simulated robot in hal-sim.
    fn local_robot(&self) -> RobotSource {
        RobotSource::None
    }
    /// The largest update file the device takes; 0: none (feature `update`).
    #[cfg(feature = "update")]
    fn firmware_capacity(&self) -> usize {
        0
    }
    /// Takes an update file from `body`, checks it whole, signature
    /// included, and arms the swap to it: a board gives it to its updater
    /// ([`crate::update::boot::BoardUpdate::receive`]).
    #[cfg(feature = "update")]
    async fn receive_firmware<S: crate::update::boot::Source>(
        &self,
        body: &mut S,
    ) -> Result<crate::io::Version, crate::update::boot::Refused<S::Error>> {
        let _ = body;
        Err(crate::update::boot::Refused::Unsupported)
    }
}

/// The network as it is now (not as the settings say it will be after a reboot).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NetworkStatus {
    /// The mode the device started with.
    pub mode: NetMode,
    /// The address in use (from DHCP or static); `None` while there is none.
    pub address: Option<Cidr>,
    pub gateway: Option<Ipv4>,
    /// The Ethernet link is up.
    pub link: bool,
}

impl NetworkStatus {
    /// The network of `stack` now, which started in `mode`: what every
    /// board's platform reports.
    pub fn of(stack: embassy_net::Stack<'_>, mode: NetMode) -> Self {
        let config = stack.config_v4();
        Self {
            mode,
            address: config
                .as_ref()
                .map(|c| Cidr { address: c.address.address().octets(), prefix_len: c.address.prefix_len() }),
            gateway: config.and_then(|c| c.gateway).map(|gateway| Ipv4(gateway.octets())),
            link: stack.is_link_up(),
        }
    }
}

/// Where the robot's points come from (`/api/status`'s `robot.source`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RobotSource {
    /// No source: NOT READY and zeros.
    #[default]
    None,
    /// The simulated robot (hal-sim, demo images).
    Sim,
    /// The robot link (docs/robot-link.md).
    Link,
}

/// Why the service did not make a change; nothing changed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Refusal {
    /// The store failed to save.
    Storage,
    /// This device cannot do it: the password could not be hashed.
    Unsupported,
    /// No password is set and the first one may not be set now: only
    /// within [`FIRST_PASSWORD_WINDOW`] of power-up or of a press of the
    /// device's button ([`Controller::open_first_password_window`]).
    FirstPasswordClosed,
}

/// How long after power-up, or after a press of the device's button, the
/// first admin password may be set (docs/http-api.md, "The first
/// password"): a device left unconfigured on a network cannot be claimed
/// by someone else later.
pub const FIRST_PASSWORD_WINDOW: Duration = Duration::from_secs(600);

/// The settings and the password as saved and in force.
struct State {
    settings: Settings,
    password: Password,
    storage: StorageStatus,
    /// Until when the first password may be set (while none is).
    first_password_until: Instant,
}

/// The settings service over a [`Platform`] and a settings [`Store`].
pub struct Controller<'a, F: NorFlash, P: Platform> {
    server: &'a Server<'a, Device<'a>>,
    platform: P,
    store: Mutex<CriticalSectionRawMutex, Store<F>>,
    state: BlockingMutex<CriticalSectionRawMutex, RefCell<State>>,
    /// The robot link the program runs: it takes the `robot` settings at
    /// once, and its health is in the status.
    #[cfg(feature = "robot-link")]
    link: Option<&'a crate::robot_link::Link>,
}

impl<F: NorFlash, P: Platform> core::fmt::Debug for Controller<'_, F, P> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Controller").finish_non_exhaustive()
    }
}

impl<'a, F: NorFlash, P: Platform> Controller<'a, F, P> {
    /// The service over `store` as `loaded` found it, with the server (and
    /// its device) built from `loaded.settings`. The storage's status is the
    /// store's now (records saved since the load, the TLS identity's, count).
    pub fn new(server: &'a Server<'a, Device<'a>>, platform: P, store: Store<F>, loaded: &Loaded) -> Self {
        let state = State {
            settings: loaded.settings,
            password: loaded.password,
            storage: store.status(),
            first_password_until: Instant::now() + FIRST_PASSWORD_WINDOW,
        };
        Self {
            server,
            platform,
            store: Mutex::new(store),
            state: BlockingMutex::new(RefCell::new(state)),
            #[cfg(feature = "robot-link")]
            link: None,
        }
    }

    /// With the robot link the program runs: it takes the `robot`
    /// settings at once ([`Self::apply`]), and it is the robot's source
    /// while set.
    #[cfg(feature = "robot-link")]
    #[must_use]
    pub fn with_robot_link(self, link: &'a crate::robot_link::Link) -> Self {
        Self { link: Some(link), ..self }
    }

    /// The platform.
    pub fn platform(&self) -> &P {
        &self.platform
    }

    /// The Modbus server, and through it the device.
    pub fn server(&self) -> &'a Server<'a, Device<'a>> {
        self.server
    }

    /// The settings as saved: those in force, and those that apply at the
    /// next start as they will be.
    pub fn settings(&self) -> Settings {
        self.state.lock(|state| state.borrow().settings)
    }

    /// Saves `settings` (validated whole already), then puts in force what
    /// applies at once ([`crate::settings::Field::applies`]): the server's
    /// configuration, the watchdog, the device name, the robot link.
    /// Returns whether a reboot is required for the rest:
    /// [`Settings::reboot_required`] from the settings in force to `settings`.
    ///
    /// All or nothing: on `Err` nothing was saved and nothing changed.
    pub async fn apply(&self, settings: &Settings) -> Result<bool, Refusal> {
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
        self.server.set_config(Config { port, ..settings.server_config(self.platform.mac()) });
        self.server.service().set_watchdog(settings.watchdog());
        #[cfg(feature = "robot-link")]
        if let Some(link) = self.link {
            link.configure(&settings.robot);
        }
        info!("settings: saved and applied");
        Ok(before.reboot_required(settings))
    }

    fn password(&self) -> Password {
        self.state.lock(|state| state.borrow().password)
    }

    /// Whether an admin password is set.
    pub fn password_set(&self) -> bool {
        self.password().is_set()
    }

    /// Whether `password` is the admin password.
    pub async fn verify_password(&self, password: &[u8]) -> bool {
        self.password().verify(password)
    }

    /// Whether the first admin password may be set now: none is set, and
    /// the device started, or its button was pressed, less than
    /// [`FIRST_PASSWORD_WINDOW`] ago.
    pub fn first_password_open(&self) -> bool {
        self.state.lock(|state| {
            let state = state.borrow();
            !state.password.is_set() && Instant::now() < state.first_password_until
        })
    }

    /// The device's button was pressed (a physical act: only someone at the
    /// device can): the first password may be set for
    /// [`FIRST_PASSWORD_WINDOW`] from now. Nothing changes once one is set.
    pub fn open_first_password_window(&self) {
        let opened = self.state.lock(|state| {
            let mut state = state.borrow_mut();
            state.first_password_until = Instant::now() + FIRST_PASSWORD_WINDOW;
            !state.password.is_set()
        });
        if opened {
            info!("password: the first password may be set for {} s", FIRST_PASSWORD_WINDOW.as_secs());
        }
    }

    /// Sets the admin password (its length is the caller's to check).
    /// Stored as a salted hash, never readable again. The first one only
    /// while [`Self::first_password_open`].
    pub async fn set_password(&self, password: &[u8]) -> Result<(), Refusal> {
        if !self.password_set() && !self.first_password_open() {
            warn!("password: refused: the first one only within 10 minutes of power-up or of the button");
            return Err(Refusal::FirstPasswordClosed);
        }
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

    /// Reboots now.
    pub fn reboot(&self) {
        self.platform.reboot();
    }

    /// Erases the saved settings and the password, then reboots.
    pub async fn factory_reset(&self) {
        let mut store = self.store.lock().await;
        if store.factory_reset().await.is_err() {
            warn!("factory reset: erasing the settings failed");
        }
        drop(store);
        self.platform.reboot();
    }

    /// Blinks the status LED for `duration`, to find the device in a cabinet.
    pub fn locate(&self, duration: Duration) {
        self.platform.locate(duration);
    }

    /// Where the robot's points come from: the link while one is set, else
    /// the platform's own source.
    pub fn robot_source(&self) -> RobotSource {
        #[cfg(feature = "robot-link")]
        if self.link.is_some_and(crate::robot_link::Link::is_set) {
            return RobotSource::Link;
        }
        self.platform.local_robot()
    }

    /// The robot link's health; `None` while no link is set.
    #[cfg(feature = "robot-link")]
    pub fn robot_link(&self) -> Option<crate::robot_link::Health> {
        self.link.map(crate::robot_link::Link::health).filter(|status| status.target.is_some())
    }

    /// Calls `f` with the store's record under `key` (the TLS records).
    #[cfg(feature = "tls")]
    pub async fn with_record<R>(&self, key: u8, f: impl FnOnce(Option<&[u8]>) -> R) -> Result<R, Refusal> {
        let mut store = self.store.lock().await;
        store.with_record(key, f).await.map_err(|_| Refusal::Storage)
    }

    /// Saves the client CA (`None`: removes it); it applies at the next start.
    #[cfg(feature = "tls")]
    pub async fn save_client_ca(&self, der: Option<&[u8]>) -> Result<(), Refusal> {
        let mut store = self.store.lock().await;
        let saved = crate::identity::save_client_ca(&mut store, der).await;
        let storage = store.status();
        self.state.lock(|state| state.borrow_mut().storage = storage);
        saved.map_err(|_| Refusal::Storage)
    }

    /// Saves the device's certificate a plant installed, with its key
    /// (`None`: the self-signed one again); it applies at the next start.
    #[cfg(feature = "tls")]
    pub async fn save_installed(
        &self,
        installed: Option<(&[u8; tls::identity::KEY_LEN], &[u8])>,
    ) -> Result<(), Refusal> {
        let mut store = self.store.lock().await;
        let saved = crate::identity::save_installed(&mut store, installed).await;
        let storage = store.status();
        self.state.lock(|state| state.borrow_mut().storage = storage);
        saved.map_err(|_| Refusal::Storage)
    }

    /// The settings store's health.
    pub fn storage(&self) -> StorageStatus {
        self.state.lock(|state| state.borrow().storage)
    }

    /// Takes an update file from `body` ([`Platform::receive_firmware`]);
    /// once it is armed, the device reports so.
    #[cfg(feature = "update")]
    pub async fn receive_firmware<S: crate::update::boot::Source>(
        &self,
        body: &mut S,
    ) -> Result<crate::io::Version, crate::update::boot::Refused<S::Error>> {
        let received = self.platform.receive_firmware(body).await;
        if received.is_ok() {
            self.server.service().set_firmware_update_state(crate::update::BootState::Armed);
        }
        received
    }
}

/// The name in the settings in force, as the service changes it.
impl<F: NorFlash, P: Platform> DeviceName for Controller<'_, F, P> {
    fn device_name(&self) -> Name {
        self.settings().device.name.or_default(self.platform.mac())
    }
}

#[cfg(test)]
mod tests;
