//! What the HTTP API needs from the program it runs in: [`Backend`], which
//! each board and hal-sim implement, and the values that cross it.
//!
//! The API reads the Modbus server and the device itself (through
//! [`Backend::server`]); the backend adds what only the program knows (its
//! model, its MAC, the address in force, the flash store, the password
//! hash) and does what only it can do (save, reboot, blink).

use embassy_time::Duration;

use crate::device::Device;
use crate::server::Server;
use crate::settings::{Cidr, Ipv4, NetMode, Settings};
pub use crate::storage::StorageStatus;

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
    /// board's backend reports.
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

/// Where the robot's points come from (DEVICE.md section 2, `robot.source`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RobotSource {
    /// No source: NOT READY and zeros.
    #[default]
    None,
    /// The simulated robot (hal-sim, demo images).
    Sim,
    /// The robot link (DEVICE.md section 4).
    Link,
}

/// The robot link's health (DEVICE.md section 4).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RobotLinkStatus {
    pub connected: bool,
    pub polls: u32,
    pub errors: u32,
    /// Milliseconds since the last good poll (`None`: none yet).
    pub last_ok_ms: Option<u32>,
}

/// Why the backend did not do what it was asked; nothing changed.
/// Why an update file was not taken (`POST /api/firmware`); the running
/// image stays.
#[cfg(feature = "update")]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FirmwareRefusal {
    /// The file is not one this device takes: not an update file, another
    /// board's, a bad signature, cut off (400, with the message).
    Invalid(&'static str),
    /// The body could not be read whole (answered as any such request).
    Body(super::Error),
    /// The update partition failed (500).
    Storage,
    /// This program takes no updates (501).
    Unsupported,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Refusal {
    /// The store failed to save (500).
    Storage,
    /// This program cannot do it (yet): no store, no password support (501).
    Unsupported,
}

/// The program around the API: one per board, one in hal-sim.
///
/// Methods are called from the HTTP tasks, between `.await`s: each must
/// return quickly and must not hold a blocking lock across an `.await` of
/// its own (the Modbus sessions share the executor). Changes
/// ([`Backend::apply`], [`Backend::set_password`]) never run two at once:
/// the API serializes them.
#[allow(async_fn_in_trait, reason = "the executor is single-threaded: no future needs to be Send")]
pub trait Backend {
    /// The Modbus server, and through it the device: the status document's
    /// `io`, `connections`, `counters` and `watchdog`, and the
    /// `modbus.allow_write` list in force, which decides who may change things.
    fn server(&self) -> &Server<'_, Device<'_>>;

    /// The settings as saved: those in force, and those that apply at the
    /// next start as they will be.
    fn settings(&self) -> Settings;

    /// Saves `settings` (validated whole already), then puts in force what
    /// applies at once ([`crate::settings::Field::applies`]): the server's
    /// configuration, the watchdog, the device name. Returns whether a
    /// reboot is required for the rest: [`Settings::reboot_required`] from
    /// the settings in force to `settings`.
    ///
    /// All or nothing: on `Err` nothing was saved and nothing changed.
    async fn apply(&self, settings: &Settings) -> Result<bool, Refusal>;

    /// Whether an admin password is set.
    fn password_set(&self) -> bool;

    /// Whether `password` is the admin password (the hashing is the
    /// backend's; it may take its time, yielding between rounds).
    async fn verify_password(&self, password: &[u8]) -> bool;

    /// Sets the admin password: `password` is 8-64 bytes (checked by the
    /// API). Stored as a salted hash, never readable again.
    async fn set_password(&self, password: &[u8]) -> Result<(), Refusal>;

    /// Reboots now. Called after the response went out and the connection closed.
    fn reboot(&self);

    /// Erases the saved settings and the password, then reboots. Called
    /// after the response went out and the connection closed.
    async fn factory_reset(&self);

    /// Blinks the status LED for `duration`, to find the device in a cabinet.
    fn locate(&self, duration: Duration);

    /// The board, as `/api/status` names it (`nucleo-f429zi`).
    fn model(&self) -> &'static str;

    /// The Ethernet MAC address.
    fn mac(&self) -> [u8; 6];

    /// The network as it is now.
    fn network(&self) -> NetworkStatus;

    /// The port the API listens on, which `modbus.port` may not take.
    fn http_port(&self) -> u16 {
        super::HTTP_PORT
    }

    /// The executor's busy share over the last second (DEVICE.md section 6):
    /// what the program's executor loop reported to [`crate::load::CPU_LOAD`].
    fn cpu_load_percent(&self) -> Option<u8> {
        crate::load::CPU_LOAD.percent()
    }

    // Hooks for what the adapter does not measure or have yet: each
    // reports `null` in `/api/status` until a board implements it.

    /// Why the device last reset (`power-on`, `watchdog`, ...). Hook: `None`.
    fn reset_reason(&self) -> Option<&'static str> {
        None
    }

    /// Where the robot's points come from. Hook: [`RobotSource::None`].
    fn robot_source(&self) -> RobotSource {
        RobotSource::None
    }

    /// The robot link's health (the link is not built yet). Hook: `None`.
    fn robot_link(&self) -> Option<RobotLinkStatus> {
        None
    }

    /// The settings store's health (the store is not built yet). Hook: `None`.
    fn storage(&self) -> Option<StorageStatus> {
        None
    }

    /// The largest update file the device takes (header and payload);
    /// 0: none. Hook: 0.
    #[cfg(feature = "update")]
    fn firmware_capacity(&self) -> usize {
        0
    }

    /// Takes an update file from `body` (at most the capacity, checked by
    /// the API), checks it whole, signature included, and arms the swap to
    /// it at the next reset. Returns the new image's version; the API then
    /// reboots the device once the response has gone out. On `Err` nothing
    /// is armed and the running image stays. Runs with the change lock held
    /// (one change at a time). Hook: [`FirmwareRefusal::Unsupported`].
    #[cfg(feature = "update")]
    async fn receive_firmware<R: embedded_io_async::Read>(
        &self,
        body: &mut super::request::Stream<'_, R>,
    ) -> Result<crate::io::Version, FirmwareRefusal> {
        let _ = body;
        Err(FirmwareRefusal::Unsupported)
    }
}
