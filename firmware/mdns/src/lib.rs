//! A Multicast DNS responder (RFC 6762) with DNS-based service discovery
//! (RFC 6763) for embassy-net, IPv4 only, with no heap: the device answers
//! for `NAME.local` and advertises `_modbus._tcp` and `_http._tcp`, with
//! its name, model and firmware version in TXT (docs/discovery.md). One
//! UDP socket and its buffers, about 10 KiB of flash.
//!
//! - [`wire`]: DNS messages read by length (the query) and written into a
//!   fixed buffer (the response).
//! - [`responder`]: the device's records, which a query asks for, and the
//!   response's bytes; pure functions, so the tests and the fuzz target
//!   drive them without a network.
//! - [`run`]: the responder on an embassy-net stack: one UDP socket,
//!   announcements at start and when the name or the address changes.
//!
//! Left out (docs/discovery.md says why): probing and conflict resolution,
//! known-answer suppression, unicast responses to QU questions (responses
//! go to the group), IPv6.

#![cfg_attr(not(test), no_std)]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing))]

#[macro_use]
mod fmt;
mod listener;
mod name;
pub mod responder;
pub mod wire;

pub use listener::{
    ANNOUNCE_INTERVAL, ANNOUNCEMENTS, LOOK_EVERY, MIN_REPEAT, RX_PACKETS, SOCKET_RX_LEN, SOCKET_TX_LEN, Send, State,
    TX_PACKETS, run,
};
pub use name::{HostName, MAX_NAME_LEN, NameSource};
pub use responder::{Identity, MAX_RESPONSE_LEN, Plan, Service, Services};

/// The mDNS port (RFC 6762 section 3).
pub const PORT: u16 = 5353;
/// The IPv4 group (RFC 6762 section 3).
pub const GROUP: [u8; 4] = [224, 0, 0, 251];

#[cfg(test)]
mod tests;
