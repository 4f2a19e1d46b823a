//! Modbus TCP I/O adapter: the logic shared by the firmware images and hal-sim.
//!
//! - [`modbus`]: the wire codec (its own crate, re-exported).
//! - [`map`]: the data map as one declarative table, and the process image.
//! - [`io`]: the hardware seam a board implements (pins, robot data): traits and their types.
//! - [`device`]: the shared state: image, outputs, watchdog, counters, refresh.
//! - [`server`]: the Modbus TCP server: request handling, sessions over any
//!   `embedded-io-async` stream, connection slots, access, the embassy-net listener.
//! - [`settings`]: the one settings model, and [`net`]: the boards' network policy.
//! - [`storage`]: the settings and the admin password saved on the device,
//!   power-fail safe, over any `embedded-storage-async` NOR flash.
//! - [`control`]: the settings service: the store, the password, apply,
//!   factory reset, over a small board seam; every front end calls it.
//! - `http` (feature `http`): the HTTP JSON API, a front end of the settings service.
//! - `robot_link` (feature `robot-link`): the robot link, a client of the robot controller's own Modbus TCP server.
//! - `mdns` (feature `mdns`, the `mdns` crate): the mDNS responder: `NAME.local` and the device's services.
//! - `identity` (feature `tls`): the device's TLS key, its certificate and the
//!   client CA, kept in the store.
//! - `server::secure` (feature `tls`): Modbus/TCP Security on port 802, over
//!   the `tls` crate (Mbed TLS in a fixed arena), each client's rights from its
//!   certificate's role.
//! - `update` (feature `update`): firmware update: a signed image streamed into
//!   the DFU partition, checked, and the bootloader's swap armed; confirmation.
//!
//! The library is `no_std` and allocation-free; every size is a named constant.
#![cfg_attr(not(test), no_std)]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing))]

#[macro_use]
pub mod fmt;

pub mod access;
pub mod analog;
pub mod control;
pub mod cpu_load;
pub mod device;
#[cfg(feature = "http")]
pub mod http;
#[cfg(feature = "tls")]
pub mod identity;
pub mod map;
pub mod name;
pub mod net;
pub mod program;
#[cfg(feature = "robot-link")]
pub mod robot_link;
pub mod server;
pub mod settings;
pub mod storage;
pub mod text;
#[cfg(feature = "update")]
pub mod update;

/// The wire codec this core speaks (its own crate: no map, no async).
pub use modbus;

/// The TLS engine (its own crate; feature `tls`): Mbed TLS in a fixed arena.
#[cfg(feature = "tls")]
pub use tls;

/// The mDNS responder (its own crate; feature `mdns`).
#[cfg(feature = "mdns")]
pub use mdns;

/// The hardware seam a board implements (its own crate, as
/// embassy-net-driver is the network's).
pub use adapter_io as io;

/// This firmware's version: Read Device Identification's MajorMinorRevision
/// and `/api/status`'s `firmware`. (Registers 256-258 are the robot
/// controller's version, from the [`io::Robot`] source.) The manifest's
/// version, or `FIRMWARE_VERSION` at build time (build.rs checks it).
pub const VERSION: io::Version = io::Version {
    major: parse_u16(env!("FIRMWARE_VERSION_MAJOR")),
    minor: parse_u16(env!("FIRMWARE_VERSION_MINOR")),
    patch: parse_u16(env!("FIRMWARE_VERSION_PATCH")),
};

/// This firmware's version as text (`0.1.0`): the same version as
/// [`VERSION`], as Read Device Identification sends it (MajorMinorRevision).
pub const VERSION_TEXT: &str = env!("FIRMWARE_VERSION_TEXT");

/// Parses a decimal `u16` at compile time (0 for anything else).
pub(crate) const fn parse_u16(text: &str) -> u16 {
    match u16::from_str_radix(text, 10) {
        Ok(value) => value,
        Err(_) => 0,
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_version_as_text_is_the_version() {
        let super::io::Version { major, minor, patch } = super::VERSION;
        assert_eq!(super::VERSION_TEXT, format!("{major}.{minor}.{patch}"));
    }
}
