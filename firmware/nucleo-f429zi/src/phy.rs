//! The NUCLEO's Ethernet PHY, a LAN8742A at SMI address 0 (UM1974), with
//! the MAC set to the speed and duplex the PHY negotiated.
//!
//! embassy-stm32 0.6 sets the MAC to 100 Mbit/s full duplex once, at init
//! (eth/v1: MACCR.FES and DM), and its `GenericPhy` reports the link up
//! as soon as auto-negotiation is done, whatever it settled on: on a
//! 10 Mbit/s link the MAC would sample the RMII lines at the wrong rate, and
//! on a half-duplex one it would send over the partner's frames without
//! deferring or seeing the collision. [`Lan8742a`] wraps `GenericPhy` (its reset, its
//! auto-negotiation, its link poll) and, when the link comes up, reads what
//! was negotiated from the PHY's register 31 and sets MACCR to match.

use core::task::Context;

use embassy_stm32::eth::{GenericPhy, Phy, Sma, StationManagement};
use embassy_stm32::pac;
use embassy_stm32::pac::eth::vals::{Dm, Fes};
use embassy_stm32::peripherals::ETH_SMA;

/// The LAN8742A's SMI address on the NUCLEO-F429ZI (UM1974).
pub const ADDRESS: u8 = 0;

/// PHY Special Control/Status Register (LAN8742A datasheet, register 31):
/// bit 12 Autodone, bits 4:2 the speed indication, valid once Autodone is set.
const SPECIAL_STATUS: u8 = 31;
const AUTODONE: u16 = 1 << 12;

/// What the link runs at.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum Mode {
    /// 10BASE-T, half duplex.
    Half10,
    /// 10BASE-T, full duplex.
    Full10,
    /// 100BASE-TX, half duplex.
    Half100,
    /// 100BASE-TX, full duplex.
    Full100,
}

impl Mode {
    /// Decodes register 31: the speed indication (bits 4:2) once
    /// auto-negotiation is done (LAN8742A datasheet: 001 10BASE-T half,
    /// 101 10BASE-T full, 010 100BASE-TX half, 110 100BASE-TX full);
    /// `None` before that or for a code the datasheet does not list.
    pub const fn decode(special_status: u16) -> Option<Self> {
        if special_status & AUTODONE == 0 {
            return None;
        }
        match (special_status >> 2) & 0b111 {
            0b001 => Some(Self::Half10),
            0b101 => Some(Self::Full10),
            0b010 => Some(Self::Half100),
            0b110 => Some(Self::Full100),
            _ => None,
        }
    }

    const fn speed(self) -> Fes {
        match self {
            Self::Half10 | Self::Full10 => Fes::FES10,
            Self::Half100 | Self::Full100 => Fes::FES100,
        }
    }

    const fn duplex(self) -> Dm {
        match self {
            Self::Half10 | Self::Half100 => Dm::HALF_DUPLEX,
            Self::Full10 | Self::Full100 => Dm::FULL_DUPLEX,
        }
    }
}

// The decoder against the datasheet's table, checked when the image builds
// (the crate has no host tests): register values as the PHY reports them.
const _: () = {
    assert!(matches!(Mode::decode(0x1000 | 0b001 << 2), Some(Mode::Half10)));
    assert!(matches!(Mode::decode(0x1000 | 0b101 << 2), Some(Mode::Full10)));
    assert!(matches!(Mode::decode(0x1000 | 0b010 << 2), Some(Mode::Half100)));
    assert!(matches!(Mode::decode(0x1000 | 0b110 << 2), Some(Mode::Full100)));
    // Every other bit set: only Autodone and bits 4:2 count.
    assert!(matches!(Mode::decode(!(0b111 << 2) | 0b010 << 2), Some(Mode::Half100)));
    // Not done yet, and codes the table does not have.
    assert!(Mode::decode(0b110 << 2).is_none());
    assert!(Mode::decode(0x1000).is_none());
    assert!(Mode::decode(0x1000 | 0b111 << 2).is_none());
};

/// The link as the MAC was last set for it.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Link {
    Down,
    /// Up, but register 31 did not say what at (logged once; retried at each poll).
    Unknown,
    Up(Mode),
}

/// The LAN8742A behind the MAC.
pub struct Lan8742a {
    phy: GenericPhy<Sma<'static, ETH_SMA>>,
    link: Link,
}

impl core::fmt::Debug for Lan8742a {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Lan8742a").finish_non_exhaustive()
    }
}

impl Lan8742a {
    /// The PHY at [`ADDRESS`] on the station management bus `sma`.
    pub fn new(sma: Sma<'static, ETH_SMA>) -> Self {
        Self { phy: GenericPhy::new(sma, ADDRESS), link: Link::Down }
    }
}

impl Phy for Lan8742a {
    fn phy_reset(&mut self) {
        self.phy.phy_reset();
    }

    fn phy_init(&mut self) {
        self.phy.phy_init();
    }

    /// `GenericPhy`'s answer (auto-negotiation done and link up, polled
    /// every 500 ms), and on the first poll that finds the link up, the MAC
    /// set to what was negotiated.
    fn poll_link(&mut self, cx: &mut Context) -> bool {
        if !self.phy.poll_link(cx) {
            self.link = Link::Down;
            return false;
        }
        if !matches!(self.link, Link::Up(_)) {
            let special_status = self.phy.station_management().smi_read(ADDRESS, SPECIAL_STATUS);
            match Mode::decode(special_status) {
                Some(mode) => {
                    set_mac(mode);
                    defmt::info!("Ethernet: link up, {}", mode);
                    self.link = Link::Up(mode);
                }
                None if self.link == Link::Down => {
                    defmt::warn!(
                        "Ethernet: link up, speed not known yet (PHY register 31 = {=u16:#06x}): the MAC stays as it was",
                        special_status
                    );
                    self.link = Link::Unknown;
                }
                None => {}
            }
        }
        true
    }
}

/// Sets MACCR's speed and duplex. ES0206's Ethernet erratum on successive
/// writes to one MAC register: a write may not be taken into account if
/// another came within four TX_CLK/RX_CLK cycles. As ST's HAL does, the
/// value is read back and written again after that time (four cycles of
/// the 2.5 MHz clock of 10 Mbit/s are 1.6 µs; 1000 core cycles are at
/// least 5.5 µs).
fn set_mac(mode: Mode) {
    let maccr = pac::ETH.ethernet_mac().maccr();
    maccr.modify(|w| {
        w.set_fes(mode.speed());
        w.set_dm(mode.duplex());
    });
    let value = maccr.read();
    cortex_m::asm::delay(1000);
    maccr.write_value(value);
}
