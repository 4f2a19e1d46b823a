//! Helpers of the abuse tests (`tests/hal_sim_abuse.rs`): a ledger of the
//! writes hal-sim acknowledged, replayed on the library's own map; random
//! request streams; and the final check that hal-sim's map holds exactly the
//! acknowledged writes. The streams are framed, and the replies split, by
//! test-support's reference framer (`test_support::framer`).
//!
//! The ledger compares only the points a master owns: the general-purpose
//! registers 128-255 and the outputs (registers 1, 16-19, 22, the analog
//! input types 5 and 7, and their coils 16-31 and 38-43). Every other point
//! has a source (pins, robot, boot) that re-asserts it, so under the `seed`
//! policy an acknowledged write there lasts at most 100 ms. The replies of
//! Diagnostics and Read Device Identification, which answer from hal-sim's
//! counters and name rather than the map, are checked against test-support's
//! reference only.

use std::time::Duration;

use adapter::map::Image;
use adapter::server::{Identity, Outcome, Policy, Stats, handler};
use adapter::settings::Name;
use modbus::mbap::MAX_ADU_LEN;
use test_support::framer::{adu, split_replies};
use test_support::reply::{Refusals, check_reply};
use tokio::io::{AsyncRead, AsyncReadExt};
use tokio_modbus::client::Context;
use tokio_modbus::prelude::Reader;

/// The handler's context for the ledger's model, which answers only the map's functions.
fn map_only() -> handler::Context<'static> {
    static STATS: Stats = Stats::new();
    handler::Context {
        identity: Identity { model: "hal-sim", name: &Name::UNSET, previous_firmware: None },
        stats: &STATS,
    }
}

/// The writes a server acknowledged, applied in order to a model map.
#[derive(Debug, Clone)]
pub struct Ledger {
    model: Image,
    policy: Policy,
    acknowledged: usize,
}

impl Default for Ledger {
    fn default() -> Self {
        Self::new()
    }
}

impl Ledger {
    /// A fresh map under hal-sim's default policy (every unit id, `seed` writes).
    pub fn new() -> Self {
        let mut model = Image::new();
        // hal-sim's robot is the simulated one: its controller's version.
        model.set_controller_version(&sim_robot::CONTROLLER_VERSION);
        Self { model, policy: Policy::default(), acknowledged: 0 }
    }

    /// Writes acknowledged so far.
    pub fn acknowledged(&self) -> usize {
        self.acknowledged
    }

    /// Records the server's `reply` to `request` (one whole Modbus frame).
    ///
    /// The reply must be the model's: the same bytes for a write or an
    /// exception, and the same values at the master's points for a read. A
    /// write the server acknowledged is then applied to the model.
    pub fn record(&mut self, request: &[u8], reply: &[u8]) {
        assert!(reply.len() >= 9, "a reply too short: {reply:02x?} to {request:02x?}");
        assert_eq!(reply[..2], request[..2], "transaction id of the reply to {request:02x?}");
        assert_eq!(reply[2..4], [0, 0], "protocol id of the reply to {request:02x?}");
        assert_eq!(reply[6], request[6], "unit id of the reply to {request:02x?}");
        if matches!(request.get(7), Some(0x08 | 0x2b)) {
            check_reply(request, reply, &Refusals::default());
            return;
        }
        let mut expected = [0u8; MAX_ADU_LEN];
        let mut next = self.model.clone();
        let outcome = handler::respond(request, &mut expected, &mut next, &self.policy, &map_only());
        let Outcome::Reply { len, exception, .. } = outcome else {
            panic!("a reply {reply:02x?} to a frame that is not Modbus: {request:02x?}");
        };
        let expected = &expected[..len];
        let function = request[7];
        if exception.is_none() && matches!(function, 0x01 | 0x03) {
            self.check_read(request, reply, expected);
        } else {
            assert_eq!(reply, expected, "the reply to {request:02x?}");
        }
        if exception.is_none() && matches!(function, 0x05 | 0x06 | 0x0f | 0x10) {
            self.model = next;
            self.acknowledged += 1;
        }
    }

    /// Applies `request`, a write the server acknowledged through a client
    /// that does not show the raw reply (tokio-modbus).
    pub fn acknowledge(&mut self, request: &[u8]) {
        let mut reply = [0u8; MAX_ADU_LEN];
        let outcome = handler::respond(request, &mut reply, &mut self.model, &self.policy, &map_only());
        assert!(matches!(outcome, Outcome::Reply { exception: None, .. }), "the model refuses {request:02x?}");
        self.acknowledged += 1;
    }

    /// A write whose reply never came back (the client reset first): it
    /// may or may not have been applied, but all or nothing. Reads back the
    /// registers `request` (an FC 06 or FC 10 to registers 128-255) writes
    /// and applies it to the model if they show it.
    pub async fn settle(&mut self, ctx: &mut Context, request: &[u8]) {
        let start = u16::from_be_bytes([request[8], request[9]]);
        let values: Vec<u16> = match request[7] {
            0x06 => vec![u16::from_be_bytes([request[10], request[11]])],
            0x10 => request[13..].chunks(2).map(|c| u16::from_be_bytes([c[0], c[1]])).collect(),
            other => panic!("settle takes FC 06 or FC 10, not {other:#04x}"),
        };
        assert!(start >= 128 && usize::from(start) + values.len() <= 256, "settle writes general-purpose registers");
        let now = ctx.read_holding_registers(start, values.len() as u16).await.unwrap().unwrap();
        let before: Vec<u16> = (start..).take(values.len()).map(|a| self.model.register(a)).collect();
        if now == values {
            let mut reply = [0u8; MAX_ADU_LEN];
            let outcome = handler::respond(request, &mut reply, &mut self.model, &self.policy, &map_only());
            assert!(matches!(outcome, Outcome::Reply { exception: None, .. }), "{request:02x?} applies");
            self.acknowledged += 1;
        } else {
            assert_eq!(now, before, "an unacknowledged write {request:02x?} landed in part");
        }
    }

    /// A read's reply: the same length, and the model's values at every
    /// point a master owns.
    fn check_read(&self, request: &[u8], reply: &[u8], expected: &[u8]) {
        assert_eq!(reply.len(), expected.len(), "the reply to {request:02x?}: {reply:02x?}");
        assert_eq!(reply[..9], expected[..9], "the reply to {request:02x?}");
        let start = u16::from_be_bytes([request[8], request[9]]);
        let quantity = u16::from_be_bytes([request[10], request[11]]);
        let (got, want) = (&reply[9..], &expected[9..]);
        for i in 0..quantity {
            let address = start + i;
            let i = usize::from(i);
            if request[7] == 0x03 && owned_register(address) {
                assert_eq!(got[2 * i..2 * i + 2], want[2 * i..2 * i + 2], "register {address} read by {request:02x?}");
            }
            if request[7] == 0x01 && owned_coil(address) {
                let bit = |bytes: &[u8]| bytes[i / 8] >> (i % 8) & 1;
                assert_eq!(bit(got), bit(want), "coil {address} read by {request:02x?}");
            }
        }
    }

    /// Reads every point a master owns from the server through `ctx` and
    /// compares it with the model: the map holds exactly the acknowledged writes.
    pub async fn verify(&self, ctx: &mut Context) {
        let mut registers = ctx.read_holding_registers(128, 125).await.unwrap().unwrap();
        registers.extend(ctx.read_holding_registers(253, 3).await.unwrap().unwrap());
        for (address, value) in (128u16..).zip(&registers) {
            assert_eq!(*value, self.model.register(address), "register {address}");
        }
        for (start, count) in [(1u16, 1u16), (5, 1), (7, 1), (16, 4), (22, 1)] {
            let values = ctx.read_holding_registers(start, count).await.unwrap().unwrap();
            for (address, value) in (start..).zip(values) {
                assert_eq!(value, self.model.register(address), "output register {address}");
            }
        }
        for (start, count) in [(16u16, 16u16), (38, 6)] {
            let values = ctx.read_coils(start, count).await.unwrap().unwrap();
            for (address, value) in (start..).zip(values) {
                assert_eq!(value, self.model.coil(address), "output coil {address}");
            }
        }
    }
}

/// Registers a master owns: the outputs, the analog input types, 128-255.
pub fn owned_register(address: u16) -> bool {
    matches!(address, 1 | 5 | 7 | 16..=19 | 22 | 128..=255)
}

/// Coils a master owns: digital outputs 16-31 and tool outputs 38-43.
pub fn owned_coil(address: u16) -> bool {
    matches!(address, 16..=31 | 38..=43)
}

/// Reads until the stream ends (end, reset, or nothing for `wait`) and
/// splits what came into whole reply frames (test-support's reference
/// framer: a partial frame at the end fails the test).
pub async fn read_frames_until_close<R: AsyncRead + Unpin>(reader: &mut R, wait: Duration) -> Vec<Vec<u8>> {
    let mut bytes = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        match tokio::time::timeout(wait, reader.read(&mut buf)).await {
            Ok(Ok(n)) if n > 0 => bytes.extend_from_slice(&buf[..n]),
            _ => break,
        }
    }
    split_replies(&bytes)
}

/// A small deterministic generator (SplitMix64): the same seed, the same test.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// A number in `0..n` (`n` > 0).
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n
    }

    pub fn u16(&mut self) -> u16 {
        self.next_u64() as u16
    }

    pub fn u8(&mut self) -> u8 {
        self.next_u64() as u8
    }

    /// True `percent` times in 100.
    pub fn chance(&mut self, percent: u64) -> bool {
        self.below(100) < percent
    }

    pub fn bytes(&mut self, n: usize) -> Vec<u8> {
        (0..n).map(|_| self.u8()).collect()
    }

    /// An address: mostly the general-purpose registers and the map.
    fn address(&mut self) -> u16 {
        match self.below(10) {
            0..=3 => 128 + self.below(128) as u16,
            4..=6 => self.below(440) as u16,
            7..=8 => self.below(50) as u16,
            _ => self.u16(),
        }
    }

    fn quantity(&mut self) -> u16 {
        match self.below(10) {
            0..=6 => self.below(131) as u16,
            7..=8 => self.below(2101) as u16,
            _ => self.u16(),
        }
    }

    /// A request PDU: mostly the six functions with plausible fields, some
    /// with byte counts off by a little, some arbitrary bytes.
    pub fn pdu(&mut self) -> Vec<u8> {
        let head = |code: u8, a: u16, b: u16| {
            let mut pdu = vec![code];
            pdu.extend(a.to_be_bytes());
            pdu.extend(b.to_be_bytes());
            pdu
        };
        match self.below(6) {
            0 => {
                let code = if self.chance(50) { 0x01 } else { 0x03 };
                let (a, q) = (self.address(), self.quantity());
                head(code, a, q)
            }
            1 => {
                let address = self.address();
                let value = match self.below(3) {
                    0 => 0xff00,
                    1 => 0,
                    _ => self.u16(),
                };
                head(0x05, address, value)
            }
            2 => {
                let address = self.address();
                let value = match self.below(3) {
                    0 => self.below(4) as u16,
                    1 => self.below(25_001) as u16,
                    _ => self.u16(),
                };
                head(0x06, address, value)
            }
            3 | 4 => {
                let coils = self.chance(50);
                let (start, quantity) = (self.address(), self.quantity());
                let exact = if coils { usize::from(quantity).div_ceil(8) } else { 2 * usize::from(quantity) };
                let skew = if self.chance(80) { 0 } else { self.below(5) as isize - 2 };
                let count = exact.saturating_add_signed(skew).min(255);
                let mut pdu = head(if coils { 0x0f } else { 0x10 }, start, quantity);
                pdu.push(count as u8);
                let fill = if self.chance(50) { self.bytes(count) } else { vec![self.u8() & 1; count] };
                pdu.extend(fill);
                pdu
            }
            _ => {
                let n = 1 + self.below(11) as usize;
                self.bytes(n)
            }
        }
    }

    /// One MBAP frame around a random PDU; now and then another protocol id
    /// or unit id.
    pub fn request(&mut self) -> Vec<u8> {
        let pdu = self.pdu();
        let protocol = if self.chance(90) { 0 } else { self.u16() };
        let unit = if self.chance(75) { 1 } else { self.u8() };
        let transaction = self.u16();
        adu(transaction, protocol, unit, &pdu)
    }

    /// A client's byte stream: mostly requests, some junk, now and then a
    /// header with an arbitrary length field (usually out of range: the
    /// server must close).
    pub fn stream(&mut self, items: usize) -> Vec<u8> {
        let mut out = Vec::new();
        for _ in 0..items {
            match self.below(22) {
                0 => {
                    let n = self.below(16) as usize;
                    out.extend(self.bytes(n));
                }
                1 => out.extend([0, 1, 0, 0, self.u8(), self.u8()]),
                _ => out.extend(self.request()),
            }
        }
        out
    }
}
