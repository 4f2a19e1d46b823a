//! The network: the STM32 MAC with the NUCLEO's LAN8742A over RMII, its
//! buffers, and the tasks that run the stack and follow the link with the
//! adapter's network policy ([`adapter::net`]).

use embassy_net::{Stack, StackResources};
use embassy_stm32::eth::{Ethernet, GenericPhy, PacketQueue, Sma};
use embassy_stm32::peripherals::{ETH, ETH_SMA};
use static_cell::StaticCell;

use crate::ModbusServer;
#[cfg(feature = "http")]
use adapter::settings::NetworkSettings;

/// The Ethernet driver: the MAC with a generic SMI PHY (the LAN8742A answers at address 0).
pub type Device = Ethernet<'static, ETH, GenericPhy<Sma<'static, ETH_SMA>>>;
/// The network stack's runner for [`Device`].
pub type Runner = embassy_net::Runner<'static, Device>;

/// Frames the MAC can hold waiting for the stack (1536 bytes each).
pub const RX_PACKETS: usize = 4;
/// Frames the stack can queue for the MAC (1514 bytes each). Replies are
/// small and the MAC sends one in microseconds, so 3 keep it busy; each
/// one more costs 1.5 KiB of the 64 KiB budget.
pub const TX_PACKETS: usize = 3;
/// Sockets in the stack: the Modbus listeners and DHCP's (and the HTTP
/// listeners with the `http` feature, mDNS's with `mdns`).
pub const NET_SOCKETS: usize = adapter::program::STACK_SOCKETS;

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

/// Runs the network stack.
#[embassy_executor::task]
pub async fn runner_task(mut runner: Runner) -> ! {
    runner.run().await
}

/// Follows the link with `network` (the settings in force): the address on
/// each link-up (DHCP with the name `names` gives then), closed sessions on
/// each link loss.
#[embassy_executor::task]
pub async fn link_task(
    stack: Stack<'static>,
    #[cfg(feature = "http")] network: &'static NetworkSettings,
    server: &'static ModbusServer,
    names: &'static dyn adapter::net::DeviceName,
) -> ! {
    #[cfg(not(feature = "http"))]
    let network = &crate::SETTINGS.network;
    adapter::net::run(stack, network, server, names).await
}
