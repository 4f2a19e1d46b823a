//! The network: the STM32 MAC with the NUCLEO's LAN8742A over RMII, the IP
//! configuration from [`settings`], and what happens when the link changes.
//!
//! - With DHCP on, every link-up starts a fresh DHCP exchange (a renewal after
//!   a cable was pulled). No lease within [`settings::DHCP_TIMEOUT_S`]: the
//!   static address applies until the next link-up.
//! - With DHCP off, the static address applies from the start.
//! - Link loss closes every Modbus session at once: its peer may be gone, and
//!   after a renewal the address may have changed.

use adapter::fmt::Ip;
use embassy_futures::select::select;
use embassy_net::{ConfigV4, DhcpConfig, Ipv4Address, Ipv4Cidr, Stack, StackResources, StaticConfigV4};
use embassy_stm32::eth::{Ethernet, GenericPhy, PacketQueue, Sma};
use embassy_stm32::peripherals::{ETH, ETH_SMA};
use embassy_time::{Duration, with_timeout};
use static_cell::StaticCell;

use crate::settings;
use adapter::server::{SOCKET_POOL, Shared};

/// The Ethernet driver: the MAC with a generic SMI PHY (the LAN8742A answers at address 0).
pub type Device = Ethernet<'static, ETH, GenericPhy<Sma<'static, ETH_SMA>>>;
/// The network stack's runner for [`Device`].
pub type Runner = embassy_net::Runner<'static, Device>;

/// Frames the MAC can hold waiting for the stack (1536 bytes each).
pub const RX_PACKETS: usize = 4;
/// Frames the stack can queue for the MAC (1514 bytes each).
pub const TX_PACKETS: usize = 4;
/// Sockets in the stack: the Modbus listeners and DHCP's.
pub const NET_SOCKETS: usize = SOCKET_POOL + 1;

/// The DMA descriptors and frame buffers (in SRAM: the MAC's DMA cannot reach CCM RAM).
pub fn packets() -> &'static mut PacketQueue<TX_PACKETS, RX_PACKETS> {
    static PACKETS: StaticCell<PacketQueue<TX_PACKETS, RX_PACKETS>> = StaticCell::new();
    PACKETS.init(PacketQueue::new())
}

/// The stack's socket storage.
pub fn resources() -> &'static mut StackResources<NET_SOCKETS> {
    static RESOURCES: StaticCell<StackResources<NET_SOCKETS>> = StaticCell::new();
    RESOURCES.init(StackResources::new())
}

/// The static address from the build settings.
pub fn static_config() -> StaticConfigV4 {
    let (address, prefix) = settings::STATIC_IP;
    StaticConfigV4 {
        address: Ipv4Cidr::new(Ipv4Address::from(address), prefix),
        gateway: settings::GATEWAY.map(Ipv4Address::from),
        dns_servers: Default::default(),
    }
}

/// The stack's configuration at start-up.
pub fn config() -> embassy_net::Config {
    if settings::DHCP {
        embassy_net::Config::dhcpv4(DhcpConfig::default())
    } else {
        embassy_net::Config::ipv4_static(static_config())
    }
}

/// Runs the network stack.
#[embassy_executor::task]
pub async fn runner_task(mut runner: Runner) -> ! {
    runner.run().await
}

/// Follows the link: configures the address on each link-up, closes the
/// sessions on each link loss.
#[embassy_executor::task]
pub async fn link_task(stack: Stack<'static>, shared: &'static Shared<'static>) -> ! {
    loop {
        stack.wait_link_up().await;
        defmt::info!("link up");
        select(stack.wait_link_down(), configure(stack)).await;
        defmt::warn!("link down: closing {} sessions", shared.slots().open_count());
        shared.slots().evict_all();
    }
}

/// Sets the address for this link-up, then logs each change. Never returns.
async fn configure(stack: Stack<'static>) -> ! {
    if settings::DHCP {
        stack.set_config_v4(ConfigV4::Dhcp(DhcpConfig::default()));
        let timeout = Duration::from_secs(settings::DHCP_TIMEOUT_S);
        if with_timeout(timeout, stack.wait_config_up()).await.is_err() {
            defmt::warn!("no DHCP lease after {} s: using the static address", settings::DHCP_TIMEOUT_S);
            stack.set_config_v4(ConfigV4::Static(static_config()));
        }
    }
    loop {
        stack.wait_config_up().await;
        if let Some(config) = stack.config_v4() {
            let gateway = config.gateway.map(|gateway| Ip(gateway.octets()));
            defmt::info!(
                "address {}/{}, gateway {}",
                Ip(config.address.address().octets()),
                config.address.prefix_len(),
                gateway
            );
        }
        stack.wait_config_down().await;
        defmt::warn!("address lost; waiting for DHCP");
    }
}
