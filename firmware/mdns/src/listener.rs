//! The responder on an embassy-net stack: one UDP socket on port 5353 in
//! the group 224.0.0.251, its buffers in the task's static storage; the
//! name and the address looked at again every [`LOOK_EVERY`], announced
//! when they change.

use embassy_net::udp::{PacketMetadata, UdpMetadata, UdpSocket};
use embassy_net::{IpAddress, IpEndpoint, Ipv4Address, Stack};
use embassy_time::{Duration, Instant, Timer, with_deadline};

use super::responder::{self, Identity, Plan, Record, Services};
use super::{GROUP, PORT};
use crate::NameSource;

/// Receive buffer: queries of up to 512 bytes, DNS's classic message size
/// (RFC 1035 section 4.2.1). A larger datagram is dropped by the stack: a
/// long known-answer list on a busy network (the device does not read
/// known answers) or another responder's announcement.
pub const SOCKET_RX_LEN: usize = 512;
/// Transmit buffer: room for two of the largest responses. A response is
/// written straight into it (smoltcp's `send_with`), which, unlike a copy,
/// does not rewind an empty ring to its start: where the last response
/// ended, a ring of two responses' size still has one's room on one side
/// or the other; a ring of one would wait for room forever.
pub const SOCKET_TX_LEN: usize = 2 * responder::MAX_RESPONSE_LEN;
/// Datagrams waiting to be read.
pub const RX_PACKETS: usize = 4;
/// Datagrams waiting to be sent: one response, and the padding entry that
/// takes the ring round to its start.
pub const TX_PACKETS: usize = 2;
/// Unsolicited announcements at start and after a change (RFC 6762 section
/// 8.3: at least two), [`ANNOUNCE_INTERVAL`] apart.
pub const ANNOUNCEMENTS: u8 = 2;
pub const ANNOUNCE_INTERVAL: Duration = Duration::from_secs(1);
/// How often the name and the address are looked at: a new name is
/// answered for and announced at most this late.
pub const LOOK_EVERY: Duration = Duration::from_secs(1);
/// A record is multicast at most once a second (RFC 6762 section 6).
pub const MIN_REPEAT: Duration = Duration::from_secs(1);
/// Responses with a shared record wait 20 ms plus up to this much (RFC 6762 section 6).
const SHARED_DELAY_MS: (u64, u64) = (20, 100);
/// IP TTL of every packet (RFC 6762 section 11).
const HOP_LIMIT: u8 = 255;

/// What the responder remembers between packets: what it announced, how
/// many announcements are left, when each record was last multicast.
#[derive(Debug)]
pub struct State {
    announced: Option<Identity>,
    announcements_left: u8,
    next_announcement: Instant,
    /// When each record of [`Record::ALL`] was last multicast.
    sent: [Option<Instant>; Record::ALL.len()],
}

/// A packet to send: a response and where to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Send {
    pub plan: Plan,
    pub identity: Identity,
    /// `None`: the group.
    pub unicast: Option<IpEndpoint>,
}

impl Default for State {
    fn default() -> Self {
        Self::new()
    }
}

impl State {
    pub const fn new() -> Self {
        Self {
            announced: None,
            announcements_left: 0,
            next_announcement: Instant::from_ticks(0),
            sent: [None; Record::ALL.len()],
        }
    }

    /// The identity is now `identity` (`None`: no address): returns the
    /// goodbye to send first when the name changed.
    pub fn follow(&mut self, identity: Option<Identity>, now: Instant) -> Option<Send> {
        if identity == self.announced {
            return None;
        }
        let goodbye = match (self.announced, identity) {
            (Some(old), Some(new)) if old.name != new.name => {
                Some(Send { plan: Plan::goodbye(&old), identity: old, unicast: None })
            }
            _ => None,
        };
        self.announced = identity;
        self.announcements_left = if identity.is_some() { ANNOUNCEMENTS } else { 0 };
        self.next_announcement = now;
        self.sent = [None; Record::ALL.len()];
        goodbye
    }

    /// The announcement due at `now`, if one is.
    pub fn announcement(&mut self, now: Instant) -> Option<Send> {
        let identity = self.announced?;
        if self.announcements_left == 0 || now < self.next_announcement {
            return None;
        }
        self.announcements_left -= 1;
        self.next_announcement = now + ANNOUNCE_INTERVAL;
        let plan = Plan::announcement(&identity);
        self.mark_sent(&plan, now);
        Some(Send { plan, identity, unicast: None })
    }

    /// When to wake up at the latest.
    pub fn deadline(&self, now: Instant) -> Instant {
        let look = now + LOOK_EVERY;
        if self.announced.is_some() && self.announcements_left > 0 { look.min(self.next_announcement) } else { look }
    }

    /// The answer to `query` from `from`, if there is one to send: legacy
    /// queries by unicast, the others to the group, without the records
    /// multicast less than [`MIN_REPEAT`] ago.
    pub fn answer(&mut self, query: &[u8], from: IpEndpoint, now: Instant) -> Option<Send> {
        let identity = self.announced?;
        let legacy = from.port != PORT;
        let mut plan = responder::plan(query, legacy, &identity)?;
        if legacy {
            return Some(Send { plan, identity, unicast: Some(from) });
        }
        let recent =
            Record::ALL.iter().zip(self.sent).fold(responder::Records::NONE, |set, (record, sent)| match sent {
                Some(at) if now < at + MIN_REPEAT => set.with(*record),
                _ => set,
            });
        plan.answers = plan.answers.minus(recent);
        plan.additionals = plan.additionals.minus(recent);
        if plan.answers.is_empty() {
            return None;
        }
        self.mark_sent(&plan, now);
        Some(Send { plan, identity, unicast: None })
    }

    fn mark_sent(&mut self, plan: &Plan, now: Instant) {
        for (record, sent) in Record::ALL.iter().zip(self.sent.iter_mut()) {
            if plan.answers.contains(*record) || plan.additionals.contains(*record) {
                *sent = Some(now);
            }
        }
    }
}

/// The identity now: `None` without an address or a name.
fn identity<N: NameSource + ?Sized>(stack: Stack<'_>, names: &N, services: Services) -> Option<Identity> {
    let address = stack.config_v4()?.address.address().octets();
    let name = names.host_name();
    (!name.as_bytes().is_empty()).then_some(Identity { name, address, services })
}

/// Answers queries for the device's name and services on `stack`, and
/// announces them, forever.
pub async fn run<N: NameSource + ?Sized>(stack: Stack<'_>, names: &N, services: Services) -> ! {
    let mut rx_meta = [PacketMetadata::EMPTY; RX_PACKETS];
    let mut rx = [0u8; SOCKET_RX_LEN];
    let mut tx_meta = [PacketMetadata::EMPTY; TX_PACKETS];
    let mut tx = [0u8; SOCKET_TX_LEN];
    let mut socket = UdpSocket::new(stack, &mut rx_meta, &mut rx, &mut tx_meta, &mut tx);
    socket.set_hop_limit(Some(HOP_LIMIT));
    if let Err(e) = socket.bind(PORT) {
        warn!("mdns: cannot bind port {}: {:?}", PORT, e);
        core::future::pending::<()>().await;
    }
    let [a, b, c, d] = GROUP;
    if let Err(e) = stack.join_multicast_group(Ipv4Address::new(a, b, c, d)) {
        warn!("mdns: cannot join the group: {:?}", e);
    }
    let mut state = State::new();
    loop {
        let now = Instant::now();
        let current = identity(stack, names, services);
        if let Some(goodbye) = state.follow(current, now) {
            send(&mut socket, &goodbye).await;
        }
        if let Some(announcement) = state.announcement(now) {
            info!("mdns: announcing {}.local", announcement.identity.name);
            send(&mut socket, &announcement).await;
        }
        let deadline = state.deadline(Instant::now());
        let received = with_deadline(
            deadline,
            socket.recv_from_with(|query, meta: UdpMetadata| state.answer(query, meta.endpoint, Instant::now())),
        )
        .await;
        if let Ok(Some(answer)) = received {
            if answer.unicast.is_none() && answer.plan.answers.has_shared() {
                let (least, spread) = SHARED_DELAY_MS;
                Timer::after_millis(least + Instant::now().as_ticks() % spread).await;
            }
            send(&mut socket, &answer).await;
        }
    }
}

/// Writes `packet`'s response straight into the socket's transmit buffer.
async fn send(socket: &mut UdpSocket<'_>, packet: &Send) {
    let len = responder::response_len(&packet.plan, &packet.identity);
    let to = packet.unicast.unwrap_or_else(|| {
        let [a, b, c, d] = GROUP;
        IpEndpoint::new(IpAddress::v4(a, b, c, d), PORT)
    });
    let sent = socket
        .send_to_with(len, to, |buffer| match responder::emit(&packet.plan, &packet.identity, buffer) {
            Ok(written) => (written, Ok(())),
            Err(full) => (0, Err(full)),
        })
        .await;
    match sent {
        Ok(Ok(())) => {}
        Ok(Err(full)) => warn!("mdns: a response of {} bytes did not fit", full.needed),
        Err(e) => warn!("mdns: send failed: {:?}", e),
    }
}
