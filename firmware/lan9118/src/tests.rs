//! The driver against a model of the chip's programmer's view (datasheet
//! sections 3.12, 3.13 and 5; QEMU's `hw/net/lan9118.c` behaves the same
//! way): FIFOs in words, write-one-to-clear interrupt status, MAC registers
//! behind `MAC_CSR_CMD`, PHY registers behind `MII_ACC`.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::task::{Context, Wake, Waker};

use embassy_net_driver::{Driver, HardwareAddress, LinkState, RxToken as _, TxToken as _};

use super::*;

/// A broadcast ARP request as slirp sends it to the guest, padded to the
/// 60-byte minimum: "who has 10.0.2.15? tell 10.0.2.2".
const ARP_REQUEST: [u8; 60] = [
    0xff, 0xff, 0xff, 0xff, 0xff, 0xff, // destination: broadcast
    0x52, 0x55, 0x0a, 0x00, 0x02, 0x02, // source: slirp's gateway
    0x08, 0x06, // EtherType: ARP
    0x00, 0x01, 0x08, 0x00, 0x06, 0x04, // Ethernet, IPv4, hlen 6, plen 4
    0x00, 0x01, // operation: request
    0x52, 0x55, 0x0a, 0x00, 0x02, 0x02, 10, 0, 2, 2, // sender MAC, IP
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 10, 0, 2, 15, // target MAC (unknown), IP
    0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, // padding
];

/// The RX status QEMU gives that frame: 64 bytes stored (CRC included), broadcast.
const ARP_REQUEST_STATUS: u32 = 0x0040_2000;

const QEMU_MAC: [u8; 6] = [0x52, 0x54, 0x00, 0x12, 0x34, 0x56];

/// The chip, as far as the driver can see it.
struct Chip {
    regs: HashMap<u8, u32>,
    mac_csr: HashMap<u32, u32>,
    phy: HashMap<u32, u16>,
    eeprom_mac: [u8; 6],
    byte_test: u32,
    int_sts: u32,
    rx_status: VecDeque<u32>,
    rx_data: VecDeque<u32>,
    tx_data: Vec<u32>,
    tx_status: VecDeque<u32>,
    tx_free: u32,
    tx_cfg_writes: Vec<u32>,
    link: bool,
    partner: u16,
    arms: usize,
    /// `INT_STS` bits an event raises while the line is being armed (the
    /// moment the board may drop a latched interrupt).
    event_on_arm: u32,
}

impl Chip {
    fn new() -> Self {
        let mut chip = Self {
            regs: HashMap::new(),
            mac_csr: HashMap::new(),
            phy: HashMap::new(),
            eeprom_mac: QEMU_MAC,
            byte_test: BYTE_TEST_VALUE,
            int_sts: 0,
            rx_status: VecDeque::new(),
            rx_data: VecDeque::new(),
            tx_data: Vec::new(),
            tx_status: VecDeque::new(),
            tx_free: 4608,
            tx_cfg_writes: Vec::new(),
            link: true,
            partner: 0x0f71,
            arms: 0,
            event_on_arm: 0,
        };
        chip.reset();
        chip
    }

    /// Soft reset: what `HW_CFG.SRST` does (the EEPROM's MAC is reloaded).
    fn reset(&mut self) {
        self.regs.clear();
        self.regs.insert(reg::PMT_CTRL, 1);
        self.mac_csr.clear();
        let [a, b, c, d, e, f] = self.eeprom_mac;
        self.mac_csr.insert(mac::ADDRL, u32::from_le_bytes([a, b, c, d]));
        self.mac_csr.insert(mac::ADDRH, u32::from_le_bytes([e, f, 0, 0]));
        self.phy.clear();
        self.phy.insert(phy::ANAR, 0x01e1);
        self.int_sts = 0;
        self.rx_status.clear();
        self.rx_data.clear();
        self.set_link(self.link);
    }

    fn set_link(&mut self, up: bool) {
        self.link = up;
        let source = if up { 0x40 } else { 0x10 };
        *self.phy.entry(phy::INT_SOURCE).or_default() |= source;
        self.update_phy_int();
    }

    fn update_phy_int(&mut self) {
        let source = self.phy.get(&phy::INT_SOURCE).copied().unwrap_or(0);
        let mask = self.phy.get(&phy::INT_MASK).copied().unwrap_or(0);
        if source & mask != 0 {
            self.int_sts |= int::PHY;
        }
    }

    /// A frame arrives: its bytes and CRC into the data FIFO, its status after.
    fn arrive(&mut self, frame: &[u8], status: u32) {
        let mut bytes = frame.to_vec();
        bytes.extend_from_slice(&crc32(frame).to_le_bytes());
        for chunk in bytes.chunks(4) {
            let mut word = [0u8; 4];
            word[..chunk.len()].copy_from_slice(chunk);
            self.rx_data.push_back(u32::from_le_bytes(word));
        }
        self.rx_status.push_back(status);
        self.int_sts |= int::RSFL;
    }

    /// A frame on the wire: kept, as `arrive`, only if the MAC's address
    /// filter passes it. The filter as QEMU's `lan9118_filter` and the
    /// datasheet's "Address Filtering Modes" table have it: promiscuous
    /// (PRMS) passes all; broadcast unless BCAST disables it; multicast all
    /// with MCPAS; else multicast by the hash table with HPFILT, or by the
    /// own address without it; unicast by the own address (no HO here).
    /// Returns whether it was kept.
    fn offer(&mut self, frame: &[u8]) -> bool {
        const PRMS: u32 = 1 << 18;
        const MCPAS: u32 = 1 << 19;
        const BCAST: u32 = 1 << 11;
        let cr = self.mac_csr.get(&mac::CR).copied().unwrap_or(0);
        let dst = &frame[..6];
        let low = self.mac_csr.get(&mac::ADDRL).copied().unwrap_or(0).to_le_bytes();
        let high = self.mac_csr.get(&mac::ADDRH).copied().unwrap_or(0).to_le_bytes();
        let own = [low[0], low[1], low[2], low[3], high[0], high[1]];
        let passes = if cr & PRMS != 0 {
            true
        } else if dst == [0xff; 6] {
            cr & BCAST == 0
        } else if dst[0] & 1 != 0 && cr & MCPAS != 0 {
            true
        } else if dst[0] & 1 != 0 && cr & mac::CR_HPFILT != 0 {
            // The hash: the top 6 bits of the MSB-first Ethernet CRC of the
            // address, here from the IEEE CRC-32 (its bit mirror, uninverted).
            let hash = (!crc32(dst)).reverse_bits() >> 26;
            let table = if hash & 0x20 != 0 { mac::HASHH } else { mac::HASHL };
            self.mac_csr.get(&table).copied().unwrap_or(0) >> (hash & 0x1f) & 1 != 0
        } else {
            dst == own
        };
        if passes {
            let multicast = if dst[0] & 1 != 0 && dst != [0xff; 6] { 1 << 10 } else { 0 };
            self.arrive(frame, status_for(frame) | multicast);
        }
        passes
    }

    /// The frames written to the TX data FIFO, decoded from their command words.
    fn sent(&self) -> Vec<Vec<u8>> {
        let mut frames = Vec::new();
        let mut words = self.tx_data.iter().copied();
        while let Some(a) = words.next() {
            let b = words.next().unwrap();
            assert_eq!(a & 0x3000, 0x3000, "one buffer per frame: first and last segment");
            let len = (a & 0x7ff) as usize;
            assert_eq!(b & 0x7ff, a & 0x7ff, "command B carries the frame length");
            let mut frame: Vec<u8> = (&mut words).take(len.div_ceil(4)).flat_map(u32::to_le_bytes).collect();
            frame.truncate(len);
            frames.push(frame);
        }
        frames
    }

    fn mac_command(&mut self, command: u32) {
        if command & mac::CSR_BUSY == 0 {
            return;
        }
        let index = command & 0xf;
        if command & mac::CSR_READ != 0 {
            let value = self.mac_csr.get(&index).copied().unwrap_or(0);
            self.regs.insert(reg::MAC_CSR_DATA, value);
            return;
        }
        let value = self.regs.get(&reg::MAC_CSR_DATA).copied().unwrap_or(0);
        self.mac_csr.insert(index, value);
        if index == mac::MII_ACC {
            assert_eq!((value >> 11) & 0x1f, phy::ADDRESS, "the internal PHY is at address 1");
            let phy_reg = (value >> 6) & 0x1f;
            if value & mac::MII_WRITE != 0 {
                let data = self.mac_csr.get(&mac::MII_DATA).copied().unwrap_or(0) as u16;
                self.phy.insert(phy_reg, data);
                self.update_phy_int();
            } else {
                let data = match phy_reg {
                    phy::BMSR => 0x7809 | if self.link { 0x0024 } else { 0 },
                    phy::ANLPAR => self.partner,
                    phy::INT_SOURCE => self.phy.remove(&phy::INT_SOURCE).unwrap_or(0),
                    other => self.phy.get(&other).copied().unwrap_or(0),
                };
                self.mac_csr.insert(mac::MII_DATA, u32::from(data));
            }
            self.mac_csr.insert(mac::MII_ACC, value & !mac::MII_BUSY);
        }
    }
}

impl Interface for Chip {
    fn read(&mut self, offset: u8) -> u32 {
        match offset {
            0x00..=0x1c => self.rx_data.pop_front().unwrap_or_else(|| {
                self.int_sts |= int::RXE;
                0
            }),
            reg::RX_STATUS_FIFO => self.rx_status.pop_front().unwrap_or(0),
            reg::TX_STATUS_FIFO => self.tx_status.pop_front().unwrap_or(0),
            reg::BYTE_TEST => self.byte_test,
            reg::INT_STS => self.int_sts,
            reg::RX_FIFO_INF => ((self.rx_status.len() as u32) << 16) | (self.rx_data.len() as u32 * 4),
            reg::TX_FIFO_INF => ((self.tx_status.len() as u32) << 16) | self.tx_free,
            reg::RX_DROP => self.regs.remove(&reg::RX_DROP).unwrap_or(0),
            other => self.regs.get(&other).copied().unwrap_or(0),
        }
    }

    fn write(&mut self, offset: u8, value: u32) {
        match offset {
            0x20..=0x3c => self.tx_data.push(value),
            reg::INT_STS => self.int_sts &= !value,
            reg::HW_CFG if value & HW_CFG_SRST != 0 => self.reset(),
            reg::RX_CFG => {
                if value & RX_CFG_RX_DUMP != 0 {
                    self.rx_status.clear();
                    self.rx_data.clear();
                }
                self.regs.insert(offset, value & !RX_CFG_RX_DUMP);
            }
            reg::TX_CFG => {
                self.tx_cfg_writes.push(value);
                if value & TX_CFG_TXS_DUMP != 0 {
                    self.tx_status.clear();
                }
                self.regs.insert(offset, value & (TX_CFG_TX_ON | TX_CFG_TXSAO));
            }
            reg::MAC_CSR_CMD => {
                self.regs.insert(offset, value & !mac::CSR_BUSY);
                self.mac_command(value);
            }
            other => {
                self.regs.insert(other, value);
            }
        }
    }

    fn arm(&mut self, _waker: &Waker) {
        self.arms += 1;
        self.int_sts |= std::mem::take(&mut self.event_on_arm);
    }
}

/// CRC-32 (IEEE 802.3), as the chip appends it.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = u32::MAX;
    for &byte in bytes {
        crc ^= u32::from(byte);
        for _ in 0..8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xedb8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

fn status_for(frame: &[u8]) -> u32 {
    let broadcast = if frame[..6] == [0xff; 6] { 1 << 13 } else { 0 };
    (((frame.len() + CRC_LEN) as u32) << 16) | broadcast
}

fn driver() -> Lan9118<Chip> {
    Lan9118::new(Chip::new()).unwrap()
}

fn cx() -> Context<'static> {
    Context::from_waker(Waker::noop())
}

fn receive(driver: &mut Lan9118<Chip>) -> Option<Vec<u8>> {
    driver.receive(&mut cx()).map(|(rx, _tx)| rx.consume(|frame| frame.to_vec()))
}

#[test]
fn crc32_matches_the_ieee_check_value() {
    assert_eq!(crc32(b"123456789"), 0xcbf4_3926);
}

#[test]
fn status_of_a_broadcast_arp_request() {
    let status = RxStatus(ARP_REQUEST_STATUS);
    assert_eq!(status_for(&ARP_REQUEST), ARP_REQUEST_STATUS);
    assert_eq!(status.stored_len(), 64);
    assert_eq!(status.words(), 16);
    assert!(status.broadcast() && !status.multicast() && !status.error());
    assert_eq!(status.verdict(64), RxVerdict::Deliver { len: 60 });
    // The data FIFO holds fewer bytes than announced: out of step.
    assert_eq!(status.verdict(60), RxVerdict::Resync);
}

#[test]
fn status_lengths_round_up_to_whole_words() {
    // 61-byte frame + CRC = 65 bytes = 17 words.
    let status = RxStatus(65 << 16);
    assert_eq!(status.words(), 17);
    assert_eq!(status.verdict(68), RxVerdict::Deliver { len: 61 });
}

#[test]
fn statuses_with_errors_or_odd_sizes_are_discarded() {
    // Error summary + CRC error.
    assert_eq!(RxStatus(0x0040_8002).verdict(64), RxVerdict::Discard);
    // Error summary + runt frame, 20 bytes stored.
    assert_eq!(RxStatus(0x0014_8800).verdict(20), RxVerdict::Discard);
    // Length error alone.
    assert_eq!(RxStatus(0x0040_1000).verdict(64), RxVerdict::Discard);
    // Filtering failed (only stored in receive-all mode).
    assert_eq!(RxStatus(0x4040_0000).verdict(64), RxVerdict::Discard);
    // Shorter than an Ethernet header, no error flagged.
    assert_eq!(RxStatus(0x0011_0000).verdict(20), RxVerdict::Discard);
    // Longest kept: 1518 + CRC; one byte more is discarded.
    assert_eq!(RxStatus(1522 << 16).verdict(1524), RxVerdict::Deliver { len: MAX_FRAME_LEN });
    assert_eq!(RxStatus(1523 << 16).verdict(1524), RxVerdict::Discard);
}

#[test]
fn impossible_statuses_mean_resync() {
    assert_eq!(RxStatus(0).verdict(4096), RxVerdict::Resync);
    assert_eq!(RxStatus(((MAX_STORED_LEN + 1) as u32) << 16).verdict(8192), RxVerdict::Resync);
    assert_eq!(RxStatus(0x3fff << 16).verdict(65535), RxVerdict::Resync);
}

#[test]
fn tx_commands_and_fifo_space() {
    assert_eq!(tx_commands(60, 7), [0x0000_303c, 0x0007_003c]);
    assert_eq!(tx_commands(MTU, 0xffff), [0x0000_35ea, 0xffff_05ea]);
    assert_eq!(tx_fifo_bytes(60), 68);
    assert_eq!(tx_fifo_bytes(61), 72);
    assert_eq!(tx_fifo_bytes(MTU), 1524);
    // TDFA fires above 24 free 64-byte blocks: room for the largest frame.
    assert_eq!(FIFO_INT_VALUE, 24 << 24);
    assert!(24 * 64 >= tx_fifo_bytes(MTU));
    assert_eq!(tx_fifo_info(0x0003_1200), (3, 4608));
    assert_eq!(rx_fifo_info(0x0002_0080), (2, 128));
    assert_eq!(FRAME_BUFFER_LEN, 1524);
}

#[test]
fn init_configures_the_chip() {
    let driver = driver();
    assert_eq!(driver.mac(), QEMU_MAC);
    assert_eq!(driver.hardware_address(), HardwareAddress::Ethernet(QEMU_MAC));
    assert!(driver.link_up());
    let chip = &driver.io;
    assert_eq!(chip.regs[&reg::IRQ_CFG], 0x111);
    assert_eq!(chip.regs[&reg::INT_EN], int::ENABLED);
    assert_eq!(chip.regs[&reg::FIFO_INT], FIFO_INT_VALUE);
    assert_eq!(chip.regs[&reg::TX_CFG], TX_CFG_TX_ON | TX_CFG_TXSAO);
    // Receive and transmit on, full duplex (both ends advertise 100BASE-TX FD),
    // filtering on: not promiscuous, broadcast accepted.
    assert_eq!(chip.mac_csr[&mac::CR], mac::CR_RXEN | mac::CR_TXEN | mac::CR_FDPX);
    assert_eq!(chip.phy[&phy::INT_MASK], phy::INT_LINK);
    assert_eq!(driver.capabilities().max_transmission_unit, 1514);
}

#[test]
fn half_duplex_partner_leaves_the_mac_half_duplex() {
    let mut chip = Chip::new();
    chip.partner = 0x00a1; // 100BASE-TX and 10BASE-T, half duplex only
    let driver = Lan9118::new(chip).unwrap();
    assert_eq!(driver.io.mac_csr[&mac::CR], mac::CR_RXEN | mac::CR_TXEN);
}

#[test]
fn init_fails_without_a_chip() {
    let mut chip = Chip::new();
    chip.byte_test = 0xffff_ffff;
    assert_eq!(Lan9118::new(chip).unwrap_err(), Error::NotFound(0xffff_ffff));
}

#[test]
fn blank_eeprom_gets_the_fallback_address() {
    let mut chip = Chip::new();
    chip.eeprom_mac = [0; 6];
    let driver = Lan9118::new(chip).unwrap();
    assert_eq!(driver.mac(), FALLBACK_MAC);
    assert_eq!(driver.io.mac_csr[&mac::ADDRL], 0x424d_0002);
    assert_eq!(driver.io.mac_csr[&mac::ADDRH], 0x0000_0100);
}

#[test]
fn frames_come_out_whole_and_in_order() {
    let mut driver = driver();
    let odd: Vec<u8> = (0..61).map(|i| i as u8 ^ 0xa5).collect();
    driver.io.arrive(&ARP_REQUEST, ARP_REQUEST_STATUS);
    driver.io.arrive(&odd, status_for(&odd));
    assert_eq!(receive(&mut driver).unwrap(), ARP_REQUEST);
    assert_eq!(receive(&mut driver).unwrap(), odd);
    assert_eq!(receive(&mut driver), None);
    assert!(driver.io.rx_data.is_empty(), "every word of both frames was read, CRC included");
    assert_eq!(driver.io.int_sts & int::RXE, 0, "no read past the data");
    assert_eq!(driver.stats().rx_frames, 2);
}

#[test]
fn a_bad_frame_is_drained_and_the_next_one_delivered() {
    let mut driver = driver();
    driver.io.arrive(&ARP_REQUEST, ARP_REQUEST_STATUS | 0x8002); // CRC error
    let long = vec![0x5a; 1600];
    driver.io.arrive(&long, status_for(&long)); // too long for the stack
    driver.io.arrive(&ARP_REQUEST, ARP_REQUEST_STATUS);
    assert_eq!(receive(&mut driver).unwrap(), ARP_REQUEST);
    assert!(driver.io.rx_data.is_empty());
    let stats = driver.stats();
    assert_eq!((stats.rx_frames, stats.rx_discarded, stats.rx_resyncs), (1, 2, 0));
}

#[test]
fn an_impossible_status_dumps_the_rx_fifos_and_reception_goes_on() {
    let mut driver = driver();
    driver.io.arrive(&ARP_REQUEST, 0x0000_2000); // zero length
    driver.io.arrive(&ARP_REQUEST, ARP_REQUEST_STATUS);
    assert_eq!(receive(&mut driver), None);
    assert!(driver.io.rx_status.is_empty() && driver.io.rx_data.is_empty());
    assert_eq!(driver.stats().rx_resyncs, 1);
    driver.io.arrive(&ARP_REQUEST, ARP_REQUEST_STATUS);
    assert_eq!(receive(&mut driver).unwrap(), ARP_REQUEST);
}

#[test]
fn a_status_announcing_more_data_than_stored_dumps_the_fifos() {
    let mut driver = driver();
    driver.io.arrive(&ARP_REQUEST, 0x0100_0000); // 256 bytes announced, 64 stored
    assert_eq!(receive(&mut driver), None);
    assert!(driver.io.rx_data.is_empty());
    assert_eq!(driver.io.int_sts & int::RXE, 0, "never read past the data");
    assert_eq!(driver.stats().rx_resyncs, 1);
}

#[test]
fn an_rx_error_interrupt_dumps_the_rx_fifos() {
    let mut driver = driver();
    driver.io.arrive(&ARP_REQUEST, ARP_REQUEST_STATUS);
    driver.io.int_sts |= int::RXE;
    assert_eq!(receive(&mut driver), None);
    assert_eq!(driver.stats().rx_resyncs, 1);
    assert_eq!(driver.io.int_sts & int::RXE, 0, "acknowledged");
}

#[test]
fn a_burst_of_bad_frames_yields_after_rx_burst() {
    let mut driver = driver();
    for _ in 0..RX_BURST + 1 {
        driver.io.arrive(&ARP_REQUEST, ARP_REQUEST_STATUS | 0x8002);
    }
    driver.io.arrive(&ARP_REQUEST, ARP_REQUEST_STATUS);
    assert_eq!(receive(&mut driver), None, "yields after RX_BURST statuses");
    assert_eq!(receive(&mut driver).unwrap(), ARP_REQUEST);
    assert_eq!(driver.stats().rx_discarded, RX_BURST as u32 + 1);
}

#[test]
fn transmit_writes_two_commands_then_the_frame() {
    let mut driver = driver();
    let odd: Vec<u8> = (0..61).map(|i| i as u8).collect();
    let token = driver.transmit(&mut cx()).unwrap();
    token.consume(odd.len(), |buffer| buffer.copy_from_slice(&odd));
    let token = driver.transmit(&mut cx()).unwrap();
    token.consume(ARP_REQUEST.len(), |buffer| buffer.copy_from_slice(&ARP_REQUEST));
    assert_eq!(driver.io.tx_data.len(), 2 + 16 + 2 + 15);
    assert_eq!(driver.io.tx_data[0], 0x0000_303d);
    assert_eq!(driver.io.tx_data[1] & 0xffff, 61);
    assert_eq!(driver.io.tx_data[17], 0x0000_003c, "the last word is zero-padded");
    assert_eq!(driver.io.sent(), vec![odd, ARP_REQUEST.to_vec()]);
    assert_eq!(driver.stats().tx_frames, 2);
}

#[test]
fn the_reply_token_of_receive_transmits() {
    let mut driver = driver();
    driver.io.arrive(&ARP_REQUEST, ARP_REQUEST_STATUS);
    let (rx, tx) = driver.receive(&mut cx()).unwrap();
    let request = rx.consume(|frame| frame.to_vec());
    tx.consume(request.len(), |buffer| buffer.copy_from_slice(&request));
    assert_eq!(driver.io.sent(), vec![ARP_REQUEST.to_vec()]);
}

#[test]
fn without_room_for_a_frame_transmit_waits_for_tdfa() {
    let mut driver = driver();
    driver.io.tx_free = (tx_fifo_bytes(MTU) - 4) as u32;
    assert!(driver.transmit(&mut cx()).is_none());
    assert_eq!(driver.io.regs[&reg::INT_EN], int::ENABLED | int::TDFA);
    driver.io.arrive(&ARP_REQUEST, ARP_REQUEST_STATUS);
    assert!(driver.receive(&mut cx()).is_none(), "no reply token, no frame taken");
    assert_eq!(driver.io.rx_status.len(), 1);
    driver.io.tx_free = 4608;
    driver.io.int_sts |= int::TDFA;
    assert!(driver.transmit(&mut cx()).is_some());
    assert_eq!(driver.io.regs[&reg::INT_EN], int::ENABLED, "TDFA off again");
    assert_eq!(receive(&mut driver).unwrap(), ARP_REQUEST);
}

#[test]
fn tx_errors_restart_the_transmitter_and_are_counted() {
    let mut driver = driver();
    driver.io.tx_status.push_back(0x0001_0000);
    driver.io.tx_status.push_back(0x0002_8800); // error summary, excessive collisions
    driver.io.int_sts |= int::TXE;
    driver.io.tx_cfg_writes.clear();
    assert!(driver.transmit(&mut cx()).is_some());
    assert_eq!(
        driver.io.tx_cfg_writes,
        vec![
            TX_CFG_STOP_TX | TX_CFG_TXSAO,
            TX_CFG_TXD_DUMP | TX_CFG_TXS_DUMP | TX_CFG_TXSAO,
            TX_CFG_TX_ON | TX_CFG_TXSAO,
        ]
    );
    // One for the TXE interrupt; the TX statuses were dumped with the FIFO.
    assert_eq!(driver.stats().tx_errors, 1);
    driver.io.tx_status.push_back(0x0003_8800);
    driver.io.tx_status.push_back(0x0004_0000);
    let _ = driver.link_state(&mut cx());
    assert!(driver.io.tx_status.is_empty(), "TX statuses are drained");
    assert_eq!(driver.stats().tx_errors, 2);
}

#[test]
fn dropped_frames_are_counted() {
    let mut driver = driver();
    driver.io.regs.insert(reg::RX_DROP, 9);
    driver.io.int_sts |= int::RXDF;
    let _ = driver.link_state(&mut cx());
    assert_eq!(driver.stats().rx_dropped, 9);
}

#[test]
fn link_follows_the_phy_interrupt() {
    let mut driver = driver();
    assert!(driver.link_state(&mut cx()) == LinkState::Up);
    driver.io.set_link(false);
    assert!(driver.link_state(&mut cx()) == LinkState::Down);
    driver.io.set_link(true);
    assert!(driver.link_state(&mut cx()) == LinkState::Up);
    assert_eq!(driver.stats().link_changes, 3, "up at start, down, up");
    assert_eq!(driver.io.int_sts & int::PHY, 0);
}

#[test]
fn every_call_rearms_the_interrupt_line() {
    let mut driver = driver();
    let before = driver.io.arms;
    let _ = driver.link_state(&mut cx());
    let _ = driver.transmit(&mut cx());
    let _ = driver.receive(&mut cx());
    assert_eq!(driver.io.arms, before + 3);
}

/// A frame to `dst` (IPv4 EtherType, padded to the minimum).
fn frame_to(dst: [u8; 6]) -> Vec<u8> {
    let mut frame = vec![0u8; 60];
    frame[..6].copy_from_slice(&dst);
    frame[6..12].copy_from_slice(&[0x52, 0x55, 0x0a, 0x00, 0x02, 0x02]);
    frame[12..14].copy_from_slice(&[0x08, 0x00]);
    frame
}

/// mDNS's group 224.0.0.251, SSDP's 239.255.255.250, IPv6 MLDv2's ff02::16.
const MDNS: [u8; 6] = [0x01, 0x00, 0x5e, 0x00, 0x00, 0xfb];
const SSDP: [u8; 6] = [0x01, 0x00, 0x5e, 0x7f, 0xff, 0xfa];
const MLD: [u8; 6] = [0x33, 0x33, 0x00, 0x00, 0x00, 0x16];

#[test]
fn multicast_addresses_and_their_hash_bits() {
    assert_eq!(ipv4_multicast_mac([224, 0, 0, 251]), MDNS);
    assert_eq!(ipv4_multicast_mac([239, 255, 255, 250]), SSDP, "the group's top bit of 23 is dropped");
    // The driver's bitwise CRC against the model's (from the IEEE CRC-32).
    for mac in [MDNS, SSDP, MLD, QEMU_MAC, [0xff; 6], [0; 6]] {
        assert_eq!(u32::from(multicast_hash(mac)), (!crc32(&mac)).reverse_bits() >> 26, "{mac:02x?}");
    }
    assert_eq!(multicast_hash(MDNS), 15);
    assert_eq!(hash_table(&[MDNS]), (0, 1 << 15));
    assert_eq!(hash_table(&[MDNS, SSDP]), (1 << (43 - 32), 1 << 15));
}

#[test]
fn only_the_accepted_multicast_group_passes_the_filter() {
    let mut driver = driver();
    // After init: own address and broadcast only.
    assert!(!driver.io.offer(&frame_to(MDNS)), "no multicast before it is asked for");
    assert!(driver.io.offer(&frame_to([0xff; 6])));
    assert!(driver.io.offer(&frame_to(QEMU_MAC)));
    assert!(!driver.io.offer(&frame_to([0x52, 0x54, 0x00, 0x12, 0x34, 0x57])), "another station's");
    assert_eq!(receive(&mut driver).map(|f| f[..6].to_vec()), Some(vec![0xff; 6]));
    assert_eq!(receive(&mut driver).map(|f| f[..6].to_vec()), Some(QEMU_MAC.to_vec()));
    assert_eq!(receive(&mut driver), None);

    driver.accept_multicast(&[MDNS]).unwrap();
    let cr = driver.io.mac_csr[&mac::CR];
    assert_eq!(cr, mac::CR_RXEN | mac::CR_TXEN | mac::CR_FDPX | mac::CR_HPFILT, "the rest of MAC_CR kept");
    assert!(driver.io.offer(&frame_to(MDNS)));
    let frame = receive(&mut driver).unwrap();
    assert_eq!(frame[..6], MDNS);
    for other in [SSDP, MLD] {
        assert!(!driver.io.offer(&frame_to(other)), "{other:02x?} stays out");
    }
    // Unicast is still perfect-filtered, broadcast still passes.
    assert!(!driver.io.offer(&frame_to([0x52, 0x54, 0x00, 0x12, 0x34, 0x57])));
    assert!(driver.io.offer(&frame_to([0xff; 6])));
    assert!(driver.io.offer(&frame_to(QEMU_MAC)));

    driver.accept_multicast(&[]).unwrap();
    assert!(!driver.io.offer(&frame_to(MDNS)), "an empty list: no multicast again");
    assert_eq!(driver.io.mac_csr[&mac::CR] & mac::CR_HPFILT, 0);
}

/// Counts its wakes.
#[derive(Default)]
struct Wakes(AtomicUsize);

impl Wake for Wakes {
    fn wake(self: Arc<Self>) {
        self.0.fetch_add(1, Ordering::Relaxed);
    }
}

#[test]
fn an_event_while_the_line_is_armed_again_wakes_the_task() {
    let mut driver = driver();
    let wakes = Arc::new(Wakes::default());
    let waker = Waker::from(wakes.clone());
    let _ = driver.link_state(&mut Context::from_waker(&waker));
    assert_eq!(wakes.0.load(Ordering::Relaxed), 0, "nothing pending, nothing to wake for");
    // A frame arrives after INT_STS was read and acknowledged, as the line
    // is armed: the board may have dropped its interrupt with the stale one.
    driver.io.rx_status.push_back(ARP_REQUEST_STATUS);
    driver.io.event_on_arm = int::RSFL;
    let _ = driver.link_state(&mut Context::from_waker(&waker));
    assert_eq!(wakes.0.load(Ordering::Relaxed), 1, "the driver looks again and wakes its task");
}
