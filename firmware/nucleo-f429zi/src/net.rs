//! The network: the STM32 MAC with the NUCLEO's LAN8742A over RMII and its
//! buffers (the stack, its runner and the network policy are the
//! program's: `program::network`, `program::spawn`).

use embassy_stm32::eth::{Ethernet, PacketQueue};
use embassy_stm32::peripherals::ETH;
use static_cell::StaticCell;

use crate::phy::Lan8742a;

/// The Ethernet driver: the MAC with the LAN8742A, which sets the MAC's
/// speed and duplex to what it negotiated ([`crate::phy`]).
pub type Device = Ethernet<'static, ETH, Lan8742a>;

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
