//! The Modbus TCP server: who may connect and write (the allow-lists of
//! [`crate::access`]), the sessions over any `embedded-io-async` stream
//! ([`serve`]), the connection slots with eviction ([`Slots`]), the
//! counters of what it sees ([`Stats`]) and the embassy-net listener
//! ([`listen`]). It answers through a [`Service`], which the device
//! implements; it knows nothing of the device, pins or boards.

pub mod handler;
pub mod identity;
mod listener;
#[cfg(feature = "tls")]
pub mod secure;
mod session;
mod slots;
mod stats;

use core::cell::RefCell;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_time::Duration;

pub use crate::access::{Access, AllowList, Network, Rights, Roles};
pub use handler::{Context, Outcome, Policy};
pub use identity::Identity;
#[cfg(all(feature = "tls", feature = "http"))]
pub(crate) use listener::first_bytes;
pub use listener::{CLOSE_TIMEOUT, SOCKET_RX_LEN, SOCKET_TX_LEN, listen};
#[cfg(feature = "http")]
pub(crate) use listener::{Peer, close};
pub use session::{Error, SESSION_BUFFER_LEN, serve};
pub use slots::{Session, SlotId, Slots};

use crate::modbus::mbap::MAX_ADU_LEN;
use crate::name::Name;
pub use stats::{Counters, Stats};

/// The Modbus TCP port (Implementation Guide V1.0b, 4.1).
pub const MODBUS_PORT: u16 = 502;

/// Sessions served at once. Override at build time with the environment
/// variable `MODBUS_MAX_CONNECTIONS` (1..=32).
pub const MAX_CONNECTIONS: usize = match option_env!("MODBUS_MAX_CONNECTIONS") {
    Some(text) => {
        let n = crate::parse_u16(text) as usize;
        assert!(n >= 1 && n <= 32, "MODBUS_MAX_CONNECTIONS must be 1..=32");
        n
    }
    None => 8,
};

/// Listening sockets kept beyond the sessions: a new client is accepted even
/// when all sessions are busy (then the idlest session is closed to make
/// room), and still finds one listening while another socket is closing,
/// which can take up to [`CLOSE_TIMEOUT`] twice when packets are lost. Two,
/// also because QEMU's slirp accepts a connection before the guest does.
pub const SPARE_SOCKETS: usize = 2;

/// Sockets (and listener tasks): [`MAX_CONNECTIONS`] + [`SPARE_SOCKETS`].
pub const SOCKET_POOL: usize = MAX_CONNECTIONS + SPARE_SOCKETS;

/// Modbus/TCP Security's sockets (and listener tasks) on port 802 (`tls`).
#[cfg(feature = "tls")]
pub const SECURE_POOL: usize = secure::SECURE_POOL;
#[cfg(not(feature = "tls"))]
pub const SECURE_POOL: usize = 0;

/// Session slots: the plain listeners' (`0..SOCKET_POOL`), then the
/// secure ones' (`SOCKET_POOL..SLOT_COUNT`).
pub const SLOT_COUNT: usize = SOCKET_POOL + SECURE_POOL;

/// Default for [`Config::idle_timeout`].
pub const IDLE_TIMEOUT: Duration = Duration::from_secs(60);
/// Default for [`Config::frame_timeout`].
pub const FRAME_TIMEOUT: Duration = Duration::from_secs(2);

/// How the server runs: made from the settings (their `server_config`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config {
    /// TCP port to listen on.
    pub port: u16,
    /// Sessions served at once (1..=[`MAX_CONNECTIONS`]).
    pub max_connections: usize,
    /// Unit id filtering and write policy.
    pub policy: Policy,
    /// A session with no complete request for this long is closed (`None`: never).
    pub idle_timeout: Option<Duration>,
    /// A frame that has started must be complete within this time.
    pub frame_timeout: Duration,
    /// Who may connect and who may write.
    pub access: Access,
    /// The device name, Read Device Identification's UserApplicationName
    /// (made from the settings with the MAC's default when none is set).
    pub name: Name,
    /// Modbus/TCP Security's roles and the rights each gives (`tls`).
    pub roles: Roles,
}

impl Config {
    /// Port 502, 8 connections, every unit id, `seed` writes, 60 s idle, 2 s
    /// per frame, everyone may connect and write, no name.
    pub const DEFAULT: Self = Self {
        port: MODBUS_PORT,
        max_connections: MAX_CONNECTIONS,
        policy: Policy { unit_id: None, write_policy: crate::map::WritePolicy::Seed, rights: Rights::ReadWrite },
        idle_timeout: Some(IDLE_TIMEOUT),
        frame_timeout: FRAME_TIMEOUT,
        access: Access::OPEN,
        name: Name::UNSET,
        roles: Roles::DEFAULT,
    };
}

impl Default for Config {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// What the server answers with: the device, or a test's stand-in.
pub trait Service {
    /// Answers one request frame into `reply` under `policy`, as the device
    /// named `name`.
    fn respond(&self, frame: &[u8], reply: &mut [u8; MAX_ADU_LEN], policy: &Policy, name: &Name) -> Outcome;
    /// Where the server counts what it sees.
    fn stats(&self) -> &Stats;
}

/// The server: its configuration in force (changed at once by
/// [`Server::set_config`]), the session slots, and the service it answers with.
pub struct Server<'a, S: Service> {
    service: &'a S,
    config: Mutex<CriticalSectionRawMutex, RefCell<Config>>,
    slots: Slots,
}

impl<S: Service> core::fmt::Debug for Server<'_, S> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Server").field("config", &self.config()).finish_non_exhaustive()
    }
}

impl<'a, S: Service> Server<'a, S> {
    /// A server answering with `service`.
    pub fn new(config: Config, service: &'a S) -> Self {
        Self { service, config: Mutex::new(RefCell::new(Self::clamped(config))), slots: Slots::new() }
    }

    fn clamped(config: Config) -> Config {
        Config { max_connections: config.max_connections.clamp(1, MAX_CONNECTIONS), ..config }
    }

    /// The configuration in force.
    pub fn config(&self) -> Config {
        self.with_config(|config| *config)
    }

    /// Reads the configuration in force without copying all of it.
    pub fn with_config<R>(&self, f: impl FnOnce(&Config) -> R) -> R {
        self.config.lock(|config| f(&config.borrow()))
    }

    /// Puts `config` in force for every request from now on, and closes
    /// the sessions it no longer admits (outside its allow-lists, beyond its
    /// `max_connections`). The port applies to the listeners after the next
    /// reboot.
    pub fn set_config(&self, config: Config) {
        let config = Self::clamped(config);
        let old_roles = self.config.lock(|cell| core::mem::replace(&mut *cell.borrow_mut(), config).roles);
        let mut closed = self.slots.enforce(&config.access, config.max_connections);
        // A secure session's rights came from its role: new roles, new sessions.
        if config.roles != old_roles {
            closed += self.slots.evict_range(SOCKET_POOL..SLOT_COUNT);
        }
        if closed > 0 {
            info!("new configuration: closing {} sessions", closed);
        }
    }

    /// The session slots.
    pub fn slots(&self) -> &Slots {
        &self.slots
    }

    /// What the server answers with.
    pub fn service(&self) -> &S {
        self.service
    }

    /// The diagnostics counters.
    pub fn stats(&self) -> &Stats {
        self.service.stats()
    }

    /// Answers one request frame into `reply` under the configuration in force.
    pub fn respond(&self, frame: &[u8], reply: &mut [u8; MAX_ADU_LEN]) -> Outcome {
        self.answer(frame, reply, Rights::ReadWrite).0
    }

    /// Answers one request frame into `reply` under the configuration in
    /// force, for a client with `rights`; also returns
    /// the idle timeout in force. The configuration stays locked while the
    /// service answers, so the device name is read in place, never copied
    /// (the service takes the image lock inside: a nested critical section).
    pub(crate) fn answer(
        &self,
        frame: &[u8],
        reply: &mut [u8; MAX_ADU_LEN],
        rights: Rights,
    ) -> (Outcome, Option<Duration>) {
        self.with_config(|config| {
            let policy = Policy { rights: config.policy.rights.and(rights), ..config.policy };
            (self.service.respond(frame, reply, &policy, &config.name), config.idle_timeout)
        })
    }
}

#[cfg(test)]
pub(crate) mod testing;
#[cfg(test)]
mod tests;
