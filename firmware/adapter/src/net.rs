//! The network policy every board runs (and hal-sim, on its TAP): how the
//! device gets its address, and what a link change does. One policy, so the
//! QEMU image exercises the logic the NUCLEO runs.
//!
//! - `dhcp`: every link-up starts a fresh DHCP exchange (a renewal after a
//!   cable was pulled). No lease within `dhcp_timeout_s`: the static
//!   `address`, if one is set, applies until the next link-up; with none,
//!   DHCP keeps trying.
//! - `static`: the static address from the start, on every link-up.
//! - Link loss closes every Modbus session at once: its peer may be gone,
//!   and after a renewal the address may have changed.
//! - DHCP sends the device name in force as its hostname (option 12). A
//!   name changed at run time goes out with the next fresh exchange: the
//!   next link-up, the next start, or when the lease is lost and DHCP starts
//!   over. A renewal keeps the name the lease was taken with (changing it
//!   would mean dropping the address the sessions run on).

use embassy_net::{ConfigV4, DhcpConfig, Ipv4Address, Ipv4Cidr, Stack, StaticConfigV4};
use embassy_time::{Duration, Instant, Ticker};

use crate::fmt::Ip;
use crate::server::{Server, Service};
use crate::settings::{Cidr, Name, NetMode, NetworkSettings};

/// The device name in force (DHCP's hostname, the mDNS name): fixed for a
/// program without the settings store, or the settings' name, which the
/// HTTP API may change at run time (`http::Controller`).
pub trait DeviceName {
    /// The name now (the MAC-made default when none is set).
    fn device_name(&self) -> Name;
}

/// A fixed name.
impl DeviceName for Name {
    fn device_name(&self) -> Name {
        *self
    }
}

/// The name in force, as the mDNS responder announces it (`NAME.local`).
#[cfg(feature = "mdns")]
impl mdns::NameSource for dyn DeviceName + '_ {
    fn host_name(&self) -> mdns::HostName {
        mdns::HostName::new(self.device_name().as_bytes())
    }
}

// Every device name is a host name as it is.
#[cfg(feature = "mdns")]
const _: () = assert!(crate::name::MAX_NAME_LEN <= mdns::MAX_NAME_LEN);

/// DHCP, sending `name` as the hostname (option 12).
pub fn dhcp_config(name: &Name) -> DhcpConfig {
    let mut config = DhcpConfig::default();
    // A name is at most 32 bytes, embassy-net's limit for the hostname.
    config.hostname = heapless::String::try_from(name.as_str()).ok();
    config
}

/// A locally administered, unicast MAC address from a chip's 96-bit unique
/// ID: `02` then 40 bits of the ID's FNV-1a hash. The same chip always gets
/// the same address; two chips collide with odds of about 1 in 10^12.
pub const fn mac_from_uid(uid: &[u8; 12]) -> [u8; 6] {
    const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
    const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;
    let mut hash = FNV_OFFSET;
    let mut rest = uid.as_slice();
    while let [byte, tail @ ..] = rest {
        hash ^= *byte as u64;
        hash = hash.wrapping_mul(FNV_PRIME);
        rest = tail;
    }
    let [a, b, c, d, e, ..] = hash.to_be_bytes();
    // Bit 1 of the first octet: locally administered; bit 0 clear: unicast.
    [0x02, a, b, c, d, e]
}

/// The address configuration to start with: DHCP (with `name` as the
/// hostname), or the static address.
pub fn initial_config(settings: &NetworkSettings, name: &Name) -> embassy_net::Config {
    match static_config(settings) {
        Some(config) if settings.mode == NetMode::Static => embassy_net::Config::ipv4_static(config),
        _ => embassy_net::Config::dhcpv4(dhcp_config(name)),
    }
}

/// The static address and gateway, if an address is set.
pub fn static_config(settings: &NetworkSettings) -> Option<StaticConfigV4> {
    let Cidr { address, prefix_len } = settings.address?;
    Some(StaticConfigV4 {
        address: Ipv4Cidr::new(Ipv4Address::from(address), prefix_len),
        gateway: settings.gateway.map(|gateway| Ipv4Address::from(gateway.0)),
        dns_servers: Default::default(),
    })
}

/// How often the policy looks at the link and the address: a link loss
/// closes the sessions at most this late.
pub const LINK_POLL: Duration = Duration::from_millis(100);

/// A change of the link, as the network policy acts on it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum LinkChange {
    /// The link came up; `reconfigure`: set the address configuration
    /// again (a fresh DHCP exchange, or the static address).
    Up { reconfigure: bool },
    /// The link went down: the sessions close.
    Down,
}

/// The link as the policy saw it at its last look, and whether it has
/// been lost since the start.
///
/// Until the first link loss the stack runs on its initial configuration
/// (`initial_config`, what a link-up would set), which may already serve
/// clients: the first link-up, at whichever look it is seen (the driver
/// may report it between two), is not a link change, and setting the
/// configuration again would restart DHCP over a lease just taken and
/// reset the connections accepted meanwhile.
#[derive(Debug)]
struct LinkWatch {
    link: bool,
    lost: bool,
}

impl LinkWatch {
    const fn new() -> Self {
        Self { link: false, lost: false }
    }

    /// What the link at this look changes.
    fn look(&mut self, link_now: bool) -> Option<LinkChange> {
        let change = match (self.link, link_now) {
            (false, true) => Some(LinkChange::Up { reconfigure: self.lost }),
            (true, false) => {
                self.lost = true;
                Some(LinkChange::Down)
            }
            _ => None,
        };
        self.link = link_now;
        change
    }
}

/// Follows the link forever: configures the address on each link-up (DHCP
/// with `name`'s name then) and closes the sessions on each link loss. One
/// small state machine on a 100 ms tick ([`LINK_POLL`]): cheaper in flash
/// than a future per event.
pub async fn run<S: Service, N: DeviceName + ?Sized>(
    stack: Stack<'_>,
    settings: &NetworkSettings,
    server: &Server<'_, S>,
    name: &N,
) -> ! {
    let port = server.with_config(|config| config.port);
    let fallback = static_config(settings);
    let mut ticker = Ticker::every(LINK_POLL);
    let mut watch = LinkWatch::new();
    let mut address = false;
    // While DHCP runs with a fallback address: when the fallback applies.
    let mut fallback_at = None;
    loop {
        let link_now = stack.is_link_up();
        match watch.look(link_now) {
            Some(LinkChange::Up { reconfigure }) => {
                info!("link up");
                fallback_at = match (settings.mode, &fallback) {
                    (NetMode::Static, Some(config)) => {
                        if reconfigure {
                            stack.set_config_v4(ConfigV4::Static(config.clone()));
                        }
                        None
                    }
                    (_, fallback) => {
                        if reconfigure {
                            stack.set_config_v4(ConfigV4::Dhcp(dhcp_config(&name.device_name())));
                        }
                        let timeout = Duration::from_secs(u64::from(settings.dhcp_timeout_s));
                        fallback.as_ref().map(|_| Instant::now() + timeout)
                    }
                };
            }
            Some(LinkChange::Down) => {
                warn!("link down: closing {} sessions", server.slots().open_count());
                server.slots().evict_all();
            }
            None => {}
        }

        // DHCP gave nothing in time: the fallback applies (at once, so the
        // address is logged below in this same tick, before any client).
        if let (false, Some(at), Some(config)) = (stack.is_config_up(), fallback_at, &fallback)
            && Instant::now() >= at
        {
            warn!("no DHCP lease after {} s: using the static address", settings.dhcp_timeout_s);
            stack.set_config_v4(ConfigV4::Static(config.clone()));
            fallback_at = None;
        }
        let address_now = stack.is_config_up();
        if address_now && !address {
            fallback_at = None;
            if let Some(config) = stack.config_v4() {
                info!("Modbus TCP server at {}:{}", Ip(config.address.address().octets()), port);
            }
        } else if address && !address_now && link_now {
            warn!("address lost; waiting for DHCP");
            // A fresh exchange, with the name in force now.
            stack.set_config_v4(ConfigV4::Dhcp(dhcp_config(&name.device_name())));
        }
        address = address_now;
        ticker.next().await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The first link-up keeps the initial configuration whenever it is
    /// seen: at the first look, or later (the driver reported it between
    /// two looks, which once restarted DHCP over a fresh lease); every
    /// link-up after a loss sets it again.
    #[test]
    fn only_a_link_up_after_a_loss_sets_the_configuration_again() {
        let mut watch = LinkWatch::new();
        assert_eq!(watch.look(true), Some(LinkChange::Up { reconfigure: false }), "up at the first look");

        let mut watch = LinkWatch::new();
        assert_eq!(watch.look(false), None, "down at the first look: the driver has not said yet");
        assert_eq!(watch.look(false), None);
        assert_eq!(watch.look(true), Some(LinkChange::Up { reconfigure: false }), "up at a later look: no change");
        assert_eq!(watch.look(true), None);
        assert_eq!(watch.look(false), Some(LinkChange::Down));
        assert_eq!(watch.look(true), Some(LinkChange::Up { reconfigure: true }), "after a loss: a fresh exchange");
        assert_eq!(watch.look(false), Some(LinkChange::Down));
        assert_eq!(watch.look(true), Some(LinkChange::Up { reconfigure: true }));
    }

    #[test]
    fn the_mac_is_local_unicast_and_stable() {
        let uid = [0x33, 0x00, 0x2f, 0x00, 0x0d, 0x51, 0x33, 0x30, 0x34, 0x38, 0x37, 0x30];
        let mac = mac_from_uid(&uid);
        assert_eq!(mac[0], 0x02);
        assert_eq!(mac, mac_from_uid(&uid));
        let mut other = uid;
        other[11] ^= 1;
        assert_ne!(mac, mac_from_uid(&other));
    }

    #[test]
    fn static_and_dhcp_start_as_the_settings_say() {
        let mut network = crate::settings::Settings::DEFAULT.network;
        let name = Name::parse("mbio-1").unwrap();
        assert!(static_config(&network).is_none());
        assert!(matches!(initial_config(&network, &name).ipv4, ConfigV4::Dhcp(_)));
        network.address = Cidr::parse_optional("198.18.0.2/24").unwrap();
        network.gateway = crate::settings::Ipv4::parse_optional("198.18.0.1").unwrap();
        assert!(matches!(initial_config(&network, &name).ipv4, ConfigV4::Dhcp(_)), "the address is DHCP's fallback");
        network.mode = NetMode::Static;
        let ConfigV4::Static(config) = initial_config(&network, &name).ipv4 else { panic!("static") };
        assert_eq!(config.address, Ipv4Cidr::new(Ipv4Address::new(198, 18, 0, 2), 24));
        assert_eq!(config.gateway, Some(Ipv4Address::new(198, 18, 0, 1)));
    }

    #[test]
    fn dhcp_sends_the_name_as_its_hostname() {
        let network = crate::settings::Settings::DEFAULT.network;
        let name = Name::from_mac([2, 0x4d, 0x42, 0x53, 0x49, 0x4d]);
        let ConfigV4::Dhcp(config) = initial_config(&network, &name).ipv4 else { panic!("dhcp") };
        assert_eq!(config.hostname.as_deref(), Some("mbio-53494d"));
        // The longest name a setting may hold still fits embassy-net's hostname.
        let longest = Name::parse(&"a".repeat(crate::settings::MAX_NAME_LEN)).unwrap();
        assert_eq!(dhcp_config(&longest).hostname.as_deref(), Some(longest.as_str()));
    }
}
