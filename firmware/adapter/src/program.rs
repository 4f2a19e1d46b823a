//! What every program built on the adapter has the same: the top of the
//! crate's layers, which may use every module below it (the boards and
//! hal-sim keep only what their platform has).

/// Sockets a program's stack holds with this build's features: the Modbus
/// listeners, DHCP's, the HTTP listeners (`http`), mDNS's (`mdns`) and the robot
/// link's client (`robot-link`).
pub const STACK_SOCKETS: usize = crate::server::SOCKET_POOL + 1 + HTTP_SOCKETS + MDNS_SOCKETS + LINK_SOCKETS;
#[cfg(feature = "http")]
const HTTP_SOCKETS: usize = crate::http::MAX_HTTP_CONNECTIONS;
#[cfg(not(feature = "http"))]
const HTTP_SOCKETS: usize = 0;
#[cfg(feature = "mdns")]
const MDNS_SOCKETS: usize = 1;
#[cfg(not(feature = "mdns"))]
const MDNS_SOCKETS: usize = 0;
/// The robot link's client connection (`robot-link`).
#[cfg(feature = "robot-link")]
const LINK_SOCKETS: usize = 1;
#[cfg(not(feature = "robot-link"))]
const LINK_SOCKETS: usize = 0;

/// The services a board announces over mDNS: this firmware's version,
/// Modbus on `modbus_port`, and HTTP on [`crate::http::HTTP_PORT`] when the
/// build has the API.
#[cfg(feature = "mdns")]
pub fn mdns_services(model: &'static str, modbus_port: u16) -> crate::mdns::Services {
    #[cfg(feature = "http")]
    let http_port = Some(crate::http::HTTP_PORT);
    #[cfg(not(feature = "http"))]
    let http_port = None;
    crate::mdns::Services { model, version: crate::VERSION_TEXT, modbus_port, http_port }
}
