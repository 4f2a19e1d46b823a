//! A Multicast DNS responder (RFC 6762) with DNS-based service discovery
//! (RFC 6763), IPv4 only (feature `mdns`; DEVICE.md section 3,
//! docs/discovery.md): the device answers for `NAME.local` and advertises
//! `_modbus._tcp` and `_http._tcp`, with its name, model and firmware
//! version in TXT.
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

mod listener;
pub mod responder;
pub mod wire;

pub use listener::{
    ANNOUNCE_INTERVAL, ANNOUNCEMENTS, LOOK_EVERY, MIN_REPEAT, RX_PACKETS, SOCKET_RX_LEN, SOCKET_TX_LEN, Send, State,
    TX_PACKETS, run,
};
pub use responder::{Identity, MAX_RESPONSE_LEN, Plan, Service, Services};

/// The mDNS port (RFC 6762 section 3).
pub const PORT: u16 = 5353;
/// The IPv4 group (RFC 6762 section 3).
pub const GROUP: [u8; 4] = [224, 0, 0, 251];

#[cfg(test)]
mod tests;
