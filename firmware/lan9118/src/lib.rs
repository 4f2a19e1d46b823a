//! SMSC LAN9118 Ethernet controller (the MPS2 board's LAN9220; QEMU's model
//! is named `lan9118`), as an [`embassy_net_driver::Driver`].
//!
//! The chip moves frames by programmed I/O through FIFO ports (SMSC LAN9118
//! datasheet rev. 1.5, sections 3.12-3.13 and 5). Receiving: the RX status
//! FIFO holds one word per frame (its length and error flags), the RX data
//! FIFO the frame's bytes plus its CRC, little-endian, padded to whole words.
//! Transmitting: two command words, then the frame's words, into the TX data
//! FIFO; the chip sends the frame once its last word is in.
//!
//! Contract:
//! - Every status word is judged by [`RxStatus::verdict`] before any data
//!   word is read. A frame is read or drained *exactly* by its word count, so
//!   the data FIFO never goes out of step; a status that cannot be right (a
//!   zero or impossible length, more words than the FIFO holds) dumps both
//!   RX FIFOs and starts over rather than guess.
//! - A transmit token is handed out only when the TX data FIFO has room for
//!   the largest frame ([`tx_fifo_bytes`] of [`MTU`]); otherwise the "TX data
//!   available" interrupt is armed.
//! - Chip errors (RX error, TX error, TX FIFO overrun) reset the side that
//!   failed; dropped frames are counted in [`Stats`].
//! - The interrupt handler does no chip access: it masks the interrupt line
//!   and wakes the stack's task ([`Interface::arm`] unmasks it). All register
//!   access happens in the driver's calls, so it never races.
//!
//! Everything here is plain logic over an [`Interface`], so it runs on the
//! host against a model of the chip (see the tests); the board supplies the
//! memory-mapped interface.

#![cfg_attr(not(test), no_std)]
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic, clippy::indexing_slicing))]

/// Logs through defmt when the image has it; otherwise the arguments are
/// only type-checked.
macro_rules! log {
    ($level:ident, $($arg:tt)+) => {{
        #[cfg(feature = "defmt")]
        ::defmt::$level!($($arg)+);
        #[cfg(not(feature = "defmt"))]
        let _ = format_args!($($arg)+);
    }};
}

use core::task::{Context, Waker};

use embassy_net_driver::{Capabilities, HardwareAddress, LinkState};

/// The largest frame handed to or taken from the stack: Ethernet header +
/// 1500 bytes of payload, without the CRC (which the chip adds and checks).
pub const MTU: usize = 1514;
/// The largest frame kept: an 802.1Q-tagged frame without its CRC.
pub const MAX_FRAME_LEN: usize = 1518;
/// Bytes of the frame check sequence the chip appends in the RX data FIFO.
pub const CRC_LEN: usize = 4;
/// The smallest frame that can be delivered: an Ethernet header.
pub const MIN_FRAME_LEN: usize = 14;
/// An RX status length above this (CRC included) means the FIFOs are out of step.
pub const MAX_STORED_LEN: usize = 2048;
/// Frame buffers: [`MAX_FRAME_LEN`] + CRC, rounded up to whole FIFO words.
pub const FRAME_BUFFER_LEN: usize = (MAX_FRAME_LEN + CRC_LEN).div_ceil(4) * 4;
/// Frames judged per `receive` call before yielding to the other tasks.
pub const RX_BURST: usize = 16;
/// Polls of a self-clearing bit (reset, MAC CSR busy, RX dump) before giving up.
pub const BUSY_POLLS: u32 = 100_000;
/// Used when the chip's EEPROM holds no valid address: locally administered, unicast.
pub const FALLBACK_MAC: [u8; 6] = [0x02, 0x00, 0x4d, 0x42, 0x00, 0x01];

/// Register offsets in the chip's window (datasheet 5.3, table 5.1).
pub mod reg {
    pub const RX_DATA_FIFO: u8 = 0x00;
    pub const TX_DATA_FIFO: u8 = 0x20;
    pub const RX_STATUS_FIFO: u8 = 0x40;
    pub const TX_STATUS_FIFO: u8 = 0x48;
    pub const ID_REV: u8 = 0x50;
    pub const IRQ_CFG: u8 = 0x54;
    pub const INT_STS: u8 = 0x58;
    pub const INT_EN: u8 = 0x5c;
    pub const BYTE_TEST: u8 = 0x64;
    pub const FIFO_INT: u8 = 0x68;
    pub const RX_CFG: u8 = 0x6c;
    pub const TX_CFG: u8 = 0x70;
    pub const HW_CFG: u8 = 0x74;
    pub const RX_FIFO_INF: u8 = 0x7c;
    pub const TX_FIFO_INF: u8 = 0x80;
    pub const PMT_CTRL: u8 = 0x84;
    pub const RX_DROP: u8 = 0xa0;
    pub const MAC_CSR_CMD: u8 = 0xa4;
    pub const MAC_CSR_DATA: u8 = 0xa8;
}

/// `BYTE_TEST` always reads this: anything else means no chip, or a bus in the wrong mode.
pub const BYTE_TEST_VALUE: u32 = 0x8765_4321;

/// Bits of `INT_STS` and `INT_EN` (datasheet 5.3.3).
pub mod int {
    /// TX data FIFO overrun.
    pub const TDFO: u32 = 1 << 10;
    /// TX data FIFO has more free space than `FIFO_INT`'s level.
    pub const TDFA: u32 = 1 << 9;
    /// RX dropped-frame counter passed half way.
    pub const RXDF: u32 = 1 << 6;
    /// RX status FIFO holds more entries than `FIFO_INT`'s level.
    pub const RSFL: u32 = 1 << 3;
    /// Transmitter error.
    pub const TXE: u32 = 1 << 13;
    /// Receiver error (for example an RX data FIFO underrun).
    pub const RXE: u32 = 1 << 14;
    /// The PHY's interrupt (link change).
    pub const PHY: u32 = 1 << 18;
    /// What the driver always listens to; TDFA only while waiting for room.
    pub const ENABLED: u32 = RSFL | RXDF | TDFO | TXE | RXE | PHY;
}

/// `IRQ_CFG`: line enabled, push-pull, active high (at reset QEMU holds the line asserted).
pub const IRQ_CFG_VALUE: u32 = (1 << 8) | (1 << 4) | 1;
/// `HW_CFG`: soft reset (self-clearing).
const HW_CFG_SRST: u32 = 1;
/// `HW_CFG`: TX FIFO size 5 KiB (the reset default) and the must-be-one bit 20.
const HW_CFG_VALUE: u32 = (5 << 16) | (1 << 20);
/// `PMT_CTRL`: the chip is ready after reset.
const PMT_CTRL_READY: u32 = 1;
/// `RX_CFG`: dump both RX FIFOs (self-clearing).
const RX_CFG_RX_DUMP: u32 = 1 << 15;
/// `TX_CFG` bits (datasheet 5.3.8).
const TX_CFG_STOP_TX: u32 = 1;
const TX_CFG_TX_ON: u32 = 1 << 1;
/// TX status FIFO may overrun: the driver drains it, but never stalls on it.
const TX_CFG_TXSAO: u32 = 1 << 2;
const TX_CFG_TXD_DUMP: u32 = 1 << 14;
const TX_CFG_TXS_DUMP: u32 = 1 << 15;
/// `FIFO_INT`: TDFA fires when more than this many 64-byte blocks are free
/// (room for the largest frame); RSFL fires when more than 0 frames wait.
pub const FIFO_INT_VALUE: u32 = ((tx_fifo_bytes(MTU).div_ceil(64) as u32) << 24) & 0xff00_0000;

/// MAC control and status registers, reached through `MAC_CSR_CMD` (datasheet 5.4).
mod mac {
    pub const CR: u32 = 1;
    pub const ADDRH: u32 = 2;
    pub const ADDRL: u32 = 3;
    pub const HASHH: u32 = 4;
    pub const HASHL: u32 = 5;
    pub const MII_ACC: u32 = 6;
    pub const MII_DATA: u32 = 7;
    /// `MAC_CSR_CMD`: start (and busy while running).
    pub const CSR_BUSY: u32 = 1 << 31;
    /// `MAC_CSR_CMD`: read (clear: write).
    pub const CSR_READ: u32 = 1 << 30;
    /// `MAC_CR` bits: receive and transmit enabled, full duplex.
    pub const CR_RXEN: u32 = 1 << 2;
    pub const CR_TXEN: u32 = 1 << 3;
    pub const CR_FDPX: u32 = 1 << 20;
    /// `MAC_CR`: multicast frames pass through the hash table (unicast
    /// stays perfect-filtered; datasheet table 3.x, "Address Filtering Modes").
    pub const CR_HPFILT: u32 = 1 << 13;
    /// `MII_ACC`: busy, write.
    pub const MII_BUSY: u32 = 1;
    pub const MII_WRITE: u32 = 1 << 1;
}

/// The internal PHY (address 1) and its registers (datasheet 5.5).
mod phy {
    pub const ADDRESS: u32 = 1;
    pub const BMSR: u32 = 1;
    pub const ANAR: u32 = 4;
    pub const ANLPAR: u32 = 5;
    pub const INT_SOURCE: u32 = 29;
    pub const INT_MASK: u32 = 30;
    /// BMSR: link up (latched low: read twice for the current state).
    pub const BMSR_LINK: u16 = 1 << 2;
    /// ANAR/ANLPAR: 100BASE-TX and 10BASE-T full duplex.
    pub const FULL_DUPLEX: u16 = (1 << 8) | (1 << 6);
    /// Interrupt sources: link down, auto-negotiation complete.
    pub const INT_LINK: u16 = (1 << 4) | (1 << 6);
}

/// The Ethernet address of an IPv4 multicast group (RFC 1112 section 6.4):
/// `01:00:5e` and the group's low 23 bits.
pub const fn ipv4_multicast_mac(group: [u8; 4]) -> [u8; 6] {
    let [_, b, c, d] = group;
    [0x01, 0x00, 0x5e, b & 0x7f, c, d]
}

/// The bit of the 64-bit multicast hash table that `mac` falls on: the top
/// 6 bits of the Ethernet CRC of the address (datasheet 3.x, "Hash Only
/// Filtering"), computed as the MAC does: bits in wire order (each byte
/// from its lowest bit), register preset to all ones, no final inversion.
pub const fn multicast_hash(mac: [u8; 6]) -> u8 {
    const POLYNOMIAL: u32 = 0x04c1_1db7;
    let mut crc = u32::MAX;
    let mut rest = mac.as_slice();
    while let [byte, tail @ ..] = rest {
        let mut bits = *byte;
        let mut i = 0;
        while i < 8 {
            let feedback = (crc >> 31) ^ (bits as u32 & 1);
            crc <<= 1;
            if feedback != 0 {
                crc ^= POLYNOMIAL;
            }
            bits >>= 1;
            i += 1;
        }
        rest = tail;
    }
    (crc >> 26) as u8
}

/// `HASHH` and `HASHL` with the bits of `groups` set.
pub const fn hash_table(groups: &[[u8; 6]]) -> (u32, u32) {
    let (mut high, mut low) = (0u32, 0u32);
    let mut rest = groups;
    while let [group, tail @ ..] = rest {
        let bit = multicast_hash(*group);
        if bit & 0x20 != 0 {
            high |= 1 << (bit & 0x1f);
        } else {
            low |= 1 << (bit & 0x1f);
        }
        rest = tail;
    }
    (high, low)
}

/// Access to one chip: its 32-bit registers and its interrupt line.
pub trait Interface {
    /// Reads the register at `offset`.
    fn read(&mut self, offset: u8) -> u32;
    /// Writes the register at `offset`.
    fn write(&mut self, offset: u8, value: u32);
    /// Registers `waker` to be woken by the next interrupt, and unmasks the
    /// line. An interrupt latched while the line was masked, for events the
    /// driver has handled since, may be dropped first (the driver reads
    /// `INT_STS` again after arming, so an event that came meanwhile is not
    /// lost).
    fn arm(&mut self, waker: &Waker);
}

/// Why the chip could not be brought up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// `BYTE_TEST` read this instead of [`BYTE_TEST_VALUE`].
    NotFound(u32),
    /// A self-clearing bit (reset, MAC or PHY access) never cleared.
    Timeout,
}

impl core::fmt::Display for Error {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::NotFound(value) => write!(f, "no LAN9118: BYTE_TEST read {value:#010x}"),
            Self::Timeout => f.write_str("LAN9118 did not finish a reset or register access"),
        }
    }
}

impl core::error::Error for Error {}

/// What to do with the frame an RX status word announces.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RxVerdict {
    /// A good frame of `len` bytes (CRC excluded): read it.
    Deliver { len: usize },
    /// A frame with errors, or one too short or too long: drain its words.
    Discard,
    /// The status cannot be right: the FIFOs are out of step; dump them.
    Resync,
}

/// One word of the RX status FIFO (datasheet 3.13.3, table 3.19).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RxStatus(pub u32);

impl RxStatus {
    const FILTER_FAIL: u32 = 1 << 30;
    const ERROR_SUMMARY: u32 = 1 << 15;
    const BROADCAST: u32 = 1 << 13;
    const LENGTH_ERROR: u32 = 1 << 12;
    const MULTICAST: u32 = 1 << 10;

    /// Bytes in the data FIFO: the frame and its CRC (bits 29:16).
    pub const fn stored_len(self) -> usize {
        ((self.0 >> 16) & 0x3fff) as usize
    }

    /// Data FIFO words the frame takes (4-byte end alignment, no offset).
    pub const fn words(self) -> usize {
        self.stored_len().div_ceil(4)
    }

    /// The chip flagged an error (CRC, runt, too long, collision, MII error).
    pub const fn error(self) -> bool {
        self.0 & (Self::ERROR_SUMMARY | Self::LENGTH_ERROR) != 0
    }

    /// Broadcast destination.
    pub const fn broadcast(self) -> bool {
        self.0 & Self::BROADCAST != 0
    }

    /// Multicast destination.
    pub const fn multicast(self) -> bool {
        self.0 & Self::MULTICAST != 0
    }

    /// Judges the frame, given how many bytes the data FIFO holds (`RXDUSED`).
    pub const fn verdict(self, data_used: usize) -> RxVerdict {
        let stored = self.stored_len();
        if stored == 0 || stored > MAX_STORED_LEN || self.words() * 4 > data_used {
            return RxVerdict::Resync;
        }
        if self.error() || self.0 & Self::FILTER_FAIL != 0 {
            return RxVerdict::Discard;
        }
        match stored.checked_sub(CRC_LEN) {
            Some(len) if len >= MIN_FRAME_LEN && len <= MAX_FRAME_LEN => RxVerdict::Deliver { len },
            _ => RxVerdict::Discard,
        }
    }
}

/// `RX_FIFO_INF`: frames waiting (status entries) and data bytes used.
pub const fn rx_fifo_info(value: u32) -> (usize, usize) {
    (((value >> 16) & 0xff) as usize, (value & 0xffff) as usize)
}

/// `TX_FIFO_INF`: TX status entries waiting and free data FIFO bytes.
pub const fn tx_fifo_info(value: u32) -> (usize, usize) {
    (((value >> 16) & 0xff) as usize, (value & 0xffff) as usize)
}

/// TX data FIFO bytes a frame of `len` bytes takes: two command words and its data words.
pub const fn tx_fifo_bytes(len: usize) -> usize {
    8 + len.div_ceil(4) * 4
}

/// TX command A and B for a frame of `len` bytes sent as one buffer
/// (datasheet 3.12.2): first and last segment, 4-byte end alignment, no
/// offset; B carries `tag` (echoed in the TX status) and the frame length.
pub const fn tx_commands(len: usize, tag: u16) -> [u32; 2] {
    const FIRST_SEGMENT: u32 = 1 << 13;
    const LAST_SEGMENT: u32 = 1 << 12;
    let len = (len & 0x7ff) as u32;
    [FIRST_SEGMENT | LAST_SEGMENT | len, ((tag as u32) << 16) | len]
}

/// A TX status word (datasheet 3.12.4): the error summary bit.
pub const fn tx_status_error(status: u32) -> bool {
    status & (1 << 15) != 0
}

/// What the driver has seen since start-up.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Stats {
    pub rx_frames: u32,
    /// Frames with errors or of a size the stack cannot take.
    pub rx_discarded: u32,
    /// Frames the chip dropped (RX FIFO full), from `RX_DROP`.
    pub rx_dropped: u32,
    /// RX FIFO dumps after an RX error or an impossible status.
    pub rx_resyncs: u32,
    pub tx_frames: u32,
    /// TX statuses with errors, TX errors and overruns.
    pub tx_errors: u32,
    pub link_changes: u32,
}

/// The driver: owns the chip through `I`, and one frame buffer each way.
pub struct Lan9118<I> {
    io: I,
    mac: [u8; 6],
    link_up: bool,
    /// What `INT_EN` holds (only the driver writes it).
    int_en: u32,
    tag: u16,
    stats: Stats,
    rx: [u8; FRAME_BUFFER_LEN],
    tx: [u8; FRAME_BUFFER_LEN],
}

impl<I> core::fmt::Debug for Lan9118<I> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Lan9118")
            .field("mac", &self.mac)
            .field("link_up", &self.link_up)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl<I: Interface> Lan9118<I> {
    /// Resets and configures the chip: MAC address from its EEPROM (else
    /// [`FALLBACK_MAC`]), filtering on (own address and broadcast), RX and TX
    /// on, interrupts for RX, errors and link changes.
    pub fn new(mut io: I) -> Result<Self, Error> {
        let byte_test = io.read(reg::BYTE_TEST);
        if byte_test != BYTE_TEST_VALUE {
            return Err(Error::NotFound(byte_test));
        }
        io.write(reg::HW_CFG, HW_CFG_SRST);
        wait_clear(&mut io, reg::HW_CFG, HW_CFG_SRST)?;
        wait_set(&mut io, reg::PMT_CTRL, PMT_CTRL_READY)?;
        io.write(reg::HW_CFG, HW_CFG_VALUE);
        io.write(reg::INT_EN, 0);
        io.write(reg::INT_STS, u32::MAX);
        io.write(reg::IRQ_CFG, IRQ_CFG_VALUE);
        io.write(reg::FIFO_INT, FIFO_INT_VALUE);
        io.write(reg::RX_CFG, 0);

        let mut driver = Self {
            io,
            mac: [0; 6],
            link_up: false,
            int_en: 0,
            tag: 0,
            stats: Stats::default(),
            rx: [0; FRAME_BUFFER_LEN],
            tx: [0; FRAME_BUFFER_LEN],
        };
        driver.mac = driver.load_mac()?;
        driver.mac_write(mac::CR, mac::CR_RXEN | mac::CR_TXEN)?;
        driver.io.write(reg::TX_CFG, TX_CFG_TX_ON | TX_CFG_TXSAO);
        driver.phy_write(phy::INT_MASK, phy::INT_LINK)?;
        driver.update_link()?;
        driver.set_int_en(int::ENABLED);
        Ok(driver)
    }

    /// The MAC address in use.
    pub fn mac(&self) -> [u8; 6] {
        self.mac
    }

    /// Lets in the multicast frames to `groups` (Ethernet addresses, see
    /// [`ipv4_multicast_mac`]) through the hash filter, beside the own
    /// address and broadcast: an mDNS group, say. Other multicast stays out
    /// unless it shares a hash bit (1 in 64 for a random group). An empty
    /// list lets no multicast in, as after [`Lan9118::new`].
    pub fn accept_multicast(&mut self, groups: &[[u8; 6]]) -> Result<(), Error> {
        let (high, low) = hash_table(groups);
        self.mac_write(mac::HASHH, high)?;
        self.mac_write(mac::HASHL, low)?;
        let cr = self.mac_read(mac::CR)?;
        let cr = if groups.is_empty() { cr & !mac::CR_HPFILT } else { cr | mac::CR_HPFILT };
        self.mac_write(mac::CR, cr)
    }

    /// Counters since start-up.
    pub fn stats(&self) -> Stats {
        self.stats
    }

    /// Whether the PHY reported a link at the last look.
    pub fn link_up(&self) -> bool {
        self.link_up
    }

    fn load_mac(&mut self) -> Result<[u8; 6], Error> {
        let low = self.mac_read(mac::ADDRL)?.to_le_bytes();
        let high = self.mac_read(mac::ADDRH)?.to_le_bytes();
        let address = [low[0], low[1], low[2], low[3], high[0], high[1]];
        let valid = address != [0; 6] && address[0] & 1 == 0;
        if valid {
            return Ok(address);
        }
        let [a, b, c, d, e, f] = FALLBACK_MAC;
        self.mac_write(mac::ADDRL, u32::from_le_bytes([a, b, c, d]))?;
        self.mac_write(mac::ADDRH, u32::from_le_bytes([e, f, 0, 0]))?;
        Ok(FALLBACK_MAC)
    }

    fn set_int_en(&mut self, value: u32) {
        if value != self.int_en {
            self.int_en = value;
            self.io.write(reg::INT_EN, value);
        }
    }

    /// Handles the chip's interrupt causes, then re-arms the line for `waker`.
    fn service(&mut self, waker: &Waker) {
        let events = self.io.read(reg::INT_STS) & self.int_en;
        if events != 0 {
            self.io.write(reg::INT_STS, events);
        }
        if events & int::PHY != 0 && self.update_link().is_err() {
            log!(warn, "lan9118: PHY access timed out");
        }
        if events & (int::TXE | int::TDFO) != 0 {
            self.stats.tx_errors = self.stats.tx_errors.wrapping_add(1);
            self.reset_tx();
        }
        if events & int::RXE != 0 {
            self.resync_rx();
        }
        if events & int::RXDF != 0 {
            self.count_dropped();
        }
        if events & int::TDFA != 0 {
            self.set_int_en(self.int_en & !int::TDFA);
        }
        self.drain_tx_status();
        self.io.arm(waker);
        // An event after the read above raised the line anew, and `arm` may
        // have dropped that interrupt with the stale one: look once more.
        if self.io.read(reg::INT_STS) & self.int_en != 0 {
            waker.wake_by_ref();
        }
    }

    fn count_dropped(&mut self) {
        let dropped = self.io.read(reg::RX_DROP);
        self.stats.rx_dropped = self.stats.rx_dropped.wrapping_add(dropped);
    }

    fn drain_tx_status(&mut self) {
        let (waiting, _) = tx_fifo_info(self.io.read(reg::TX_FIFO_INF));
        for _ in 0..waiting {
            if tx_status_error(self.io.read(reg::TX_STATUS_FIFO)) {
                self.stats.tx_errors = self.stats.tx_errors.wrapping_add(1);
            }
        }
    }

    /// Room for the largest frame in the TX data FIFO; if there is none,
    /// arms the "TX data available" interrupt (and looks once more, in case
    /// the room appeared meanwhile).
    fn tx_ready(&mut self) -> bool {
        let room = |io: &mut I| tx_fifo_info(io.read(reg::TX_FIFO_INF)).1 >= tx_fifo_bytes(MTU);
        if room(&mut self.io) {
            return true;
        }
        self.io.write(reg::INT_STS, int::TDFA);
        self.set_int_en(self.int_en | int::TDFA);
        room(&mut self.io)
    }

    /// Pops RX statuses until a good frame is in `self.rx`; returns its length.
    fn next_frame(&mut self, waker: &Waker) -> Option<usize> {
        for _ in 0..RX_BURST {
            let (frames, data_used) = rx_fifo_info(self.io.read(reg::RX_FIFO_INF));
            if frames == 0 {
                return None;
            }
            let status = RxStatus(self.io.read(reg::RX_STATUS_FIFO));
            match status.verdict(data_used) {
                RxVerdict::Deliver { len } => {
                    self.read_words(status.words());
                    self.stats.rx_frames = self.stats.rx_frames.wrapping_add(1);
                    return Some(len);
                }
                RxVerdict::Discard => {
                    log!(debug, "lan9118: discarding frame, status {:#010x}", status.0);
                    for _ in 0..status.words() {
                        self.io.read(reg::RX_DATA_FIFO);
                    }
                    self.stats.rx_discarded = self.stats.rx_discarded.wrapping_add(1);
                }
                RxVerdict::Resync => {
                    log!(warn, "lan9118: impossible RX status {:#010x}, dumping the RX FIFOs", status.0);
                    self.resync_rx();
                    return None;
                }
            }
        }
        // More frames wait: come back after the other tasks had a turn.
        waker.wake_by_ref();
        None
    }

    /// Reads `words` data words into `self.rx` (the CRC lands past the
    /// frame); words the buffer cannot hold are read and dropped, so the
    /// FIFO stays in step.
    fn read_words(&mut self, words: usize) {
        let kept = words.min(FRAME_BUFFER_LEN / 4);
        let io = &mut self.io;
        for chunk in self.rx.chunks_exact_mut(4).take(kept) {
            chunk.copy_from_slice(&io.read(reg::RX_DATA_FIFO).to_le_bytes());
        }
        for _ in kept..words {
            io.read(reg::RX_DATA_FIFO);
        }
    }

    /// Dumps both RX FIFOs: after an RX error, or a status that cannot be right.
    fn resync_rx(&mut self) {
        self.stats.rx_resyncs = self.stats.rx_resyncs.wrapping_add(1);
        self.io.write(reg::RX_CFG, RX_CFG_RX_DUMP);
        if wait_clear(&mut self.io, reg::RX_CFG, RX_CFG_RX_DUMP).is_err() {
            log!(warn, "lan9118: RX dump did not finish");
        }
    }

    /// Stops the transmitter, dumps the TX FIFOs and starts it again.
    fn reset_tx(&mut self) {
        log!(warn, "lan9118: TX error, resetting the transmitter");
        self.io.write(reg::TX_CFG, TX_CFG_STOP_TX | TX_CFG_TXSAO);
        if wait_clear(&mut self.io, reg::TX_CFG, TX_CFG_TX_ON).is_err() {
            log!(warn, "lan9118: transmitter did not stop");
        }
        self.io.write(reg::TX_CFG, TX_CFG_TXD_DUMP | TX_CFG_TXS_DUMP | TX_CFG_TXSAO);
        self.io.write(reg::TX_CFG, TX_CFG_TX_ON | TX_CFG_TXSAO);
    }

    /// Reads the PHY's link state (and clears its interrupt); on a link with
    /// a full-duplex partner, sets the MAC to full duplex.
    fn update_link(&mut self) -> Result<(), Error> {
        self.phy_read(phy::INT_SOURCE)?;
        self.phy_read(phy::BMSR)?;
        let up = self.phy_read(phy::BMSR)? & phy::BMSR_LINK != 0;
        if up {
            let common = self.phy_read(phy::ANAR)? & self.phy_read(phy::ANLPAR)?;
            let mut cr = self.mac_read(mac::CR)?;
            cr = if common & phy::FULL_DUPLEX != 0 { cr | mac::CR_FDPX } else { cr & !mac::CR_FDPX };
            self.mac_write(mac::CR, cr)?;
        }
        if up != self.link_up {
            log!(info, "lan9118: link {}", if up { "up" } else { "down" });
            self.stats.link_changes = self.stats.link_changes.wrapping_add(1);
            self.link_up = up;
        }
        Ok(())
    }

    fn mac_read(&mut self, index: u32) -> Result<u32, Error> {
        wait_clear(&mut self.io, reg::MAC_CSR_CMD, mac::CSR_BUSY)?;
        self.io.write(reg::MAC_CSR_CMD, mac::CSR_BUSY | mac::CSR_READ | index);
        wait_clear(&mut self.io, reg::MAC_CSR_CMD, mac::CSR_BUSY)?;
        Ok(self.io.read(reg::MAC_CSR_DATA))
    }

    fn mac_write(&mut self, index: u32, value: u32) -> Result<(), Error> {
        wait_clear(&mut self.io, reg::MAC_CSR_CMD, mac::CSR_BUSY)?;
        self.io.write(reg::MAC_CSR_DATA, value);
        self.io.write(reg::MAC_CSR_CMD, mac::CSR_BUSY | index);
        wait_clear(&mut self.io, reg::MAC_CSR_CMD, mac::CSR_BUSY)
    }

    fn mii_wait(&mut self) -> Result<(), Error> {
        for _ in 0..BUSY_POLLS {
            if self.mac_read(mac::MII_ACC)? & mac::MII_BUSY == 0 {
                return Ok(());
            }
        }
        Err(Error::Timeout)
    }

    fn phy_read(&mut self, index: u32) -> Result<u16, Error> {
        self.mii_wait()?;
        self.mac_write(mac::MII_ACC, (phy::ADDRESS << 11) | (index << 6) | mac::MII_BUSY)?;
        self.mii_wait()?;
        Ok(self.mac_read(mac::MII_DATA)? as u16)
    }

    fn phy_write(&mut self, index: u32, value: u16) -> Result<(), Error> {
        self.mii_wait()?;
        self.mac_write(mac::MII_DATA, u32::from(value))?;
        self.mac_write(mac::MII_ACC, (phy::ADDRESS << 11) | (index << 6) | mac::MII_WRITE | mac::MII_BUSY)?;
        self.mii_wait()
    }

    fn tx_token(&mut self) -> TxToken<'_, I> {
        self.tag = self.tag.wrapping_add(1);
        TxToken { io: &mut self.io, buffer: &mut self.tx, tag: self.tag, stats: &mut self.stats }
    }
}

fn wait_clear(io: &mut impl Interface, offset: u8, bit: u32) -> Result<(), Error> {
    for _ in 0..BUSY_POLLS {
        if io.read(offset) & bit == 0 {
            return Ok(());
        }
    }
    Err(Error::Timeout)
}

fn wait_set(io: &mut impl Interface, offset: u8, bit: u32) -> Result<(), Error> {
    for _ in 0..BUSY_POLLS {
        if io.read(offset) & bit != 0 {
            return Ok(());
        }
    }
    Err(Error::Timeout)
}

impl<I: Interface> embassy_net_driver::Driver for Lan9118<I> {
    type RxToken<'a>
        = RxToken<'a>
    where
        Self: 'a;
    type TxToken<'a>
        = TxToken<'a, I>
    where
        Self: 'a;

    fn receive(&mut self, cx: &mut Context) -> Option<(Self::RxToken<'_>, Self::TxToken<'_>)> {
        self.service(cx.waker());
        if !self.tx_ready() {
            return None;
        }
        let len = self.next_frame(cx.waker())?;
        self.tag = self.tag.wrapping_add(1);
        let (frame, _) = self.rx.split_at_mut(len.min(FRAME_BUFFER_LEN));
        let tx = TxToken { io: &mut self.io, buffer: &mut self.tx, tag: self.tag, stats: &mut self.stats };
        Some((RxToken { frame }, tx))
    }

    fn transmit(&mut self, cx: &mut Context) -> Option<Self::TxToken<'_>> {
        self.service(cx.waker());
        if self.tx_ready() { Some(self.tx_token()) } else { None }
    }

    fn link_state(&mut self, cx: &mut Context) -> LinkState {
        self.service(cx.waker());
        if self.link_up { LinkState::Up } else { LinkState::Down }
    }

    fn capabilities(&self) -> Capabilities {
        let mut capabilities = Capabilities::default();
        capabilities.max_transmission_unit = MTU;
        capabilities.max_burst_size = Some(1);
        capabilities
    }

    fn hardware_address(&self) -> HardwareAddress {
        HardwareAddress::Ethernet(self.mac)
    }
}

/// A received frame, already copied out of the chip.
#[derive(Debug)]
pub struct RxToken<'a> {
    frame: &'a mut [u8],
}

impl embassy_net_driver::RxToken for RxToken<'_> {
    fn consume<R, F: FnOnce(&mut [u8]) -> R>(self, f: F) -> R {
        f(self.frame)
    }
}

/// Room for one frame in the TX data FIFO (checked when the token was made).
pub struct TxToken<'a, I> {
    io: &'a mut I,
    buffer: &'a mut [u8; FRAME_BUFFER_LEN],
    tag: u16,
    stats: &'a mut Stats,
}

impl<I> core::fmt::Debug for TxToken<'_, I> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("TxToken").field("tag", &self.tag).finish_non_exhaustive()
    }
}

impl<I: Interface> embassy_net_driver::TxToken for TxToken<'_, I> {
    fn consume<R, F: FnOnce(&mut [u8]) -> R>(self, len: usize, f: F) -> R {
        let (frame, _) = self.buffer.split_at_mut(len.min(MTU));
        let result = f(frame);
        // The two commands written as two stores (an array's iterator here
        // was not inlined at opt-level "z": 40 instructions a frame).
        let [command_a, command_b] = tx_commands(frame.len(), self.tag);
        self.io.write(reg::TX_DATA_FIFO, command_a);
        self.io.write(reg::TX_DATA_FIFO, command_b);
        // Whole words as one load each (a byte-by-byte loop here cost 40
        // instructions a word on the Cortex-M4: scripts/bench-mcu), then the
        // tail, zero-padded.
        let mut words = frame.chunks_exact(4);
        for word in &mut words {
            let word: [u8; 4] = word.try_into().unwrap_or_default();
            self.io.write(reg::TX_DATA_FIFO, u32::from_le_bytes(word));
        }
        let tail = words.remainder();
        if !tail.is_empty() {
            let mut word = [0u8; 4];
            word.iter_mut().zip(tail).for_each(|(to, from)| *to = *from);
            self.io.write(reg::TX_DATA_FIFO, u32::from_le_bytes(word));
        }
        self.stats.tx_frames = self.stats.tx_frames.wrapping_add(1);
        result
    }
}

#[cfg(test)]
mod tests;
