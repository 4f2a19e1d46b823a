//! The network: the STM32 MAC with the NUCLEO's LAN8742A over RMII and its
//! buffers (the stack, its runner and the network policy are the
//! program's: `program::network`, `program::spawn`).

use embassy_stm32::eth::{Ethernet, GenericPhy, PacketQueue, Sma};
use embassy_stm32::peripherals::{ETH, ETH_SMA};
use static_cell::StaticCell;

/// The Ethernet driver: the MAC with a generic SMI PHY (the LAN8742A answers at address 0).
pub type Device = Ethernet<'static, ETH, GenericPhy<Sma<'static, ETH_SMA>>>;

/// Frames the MAC can hold waiting for the stack (1536 bytes each).
pub const RX_PACKETS: usize = 4;
/// Frames the stack can queue for the MAC (1514 bytes each). Replies are
/// small and the MAC sends one in microseconds, so 3 keep it busy; each
/// one more costs 1.5 KiB of the 64 KiB budget.
pub const TX_PACKETS: usize = 3;
/// The DMA descriptors and frame buffers (in SRAM: the MAC's DMA cannot reach CCM RAM).
pub fn packets() -> &'static mut PacketQueue<TX_PACKETS, RX_PACKETS> {
    static PACKETS: StaticCell<PacketQueue<TX_PACKETS, RX_PACKETS>> = StaticCell::new();
    PACKETS.init(PacketQueue::new())
}
