//! Accepting Modbus TCP clients on an embassy-net stack: one task per socket,
//! [`super::SPARE_SOCKETS`] more sockets than sessions so a new client is never refused.

use core::fmt;
use core::future::{Future, poll_fn};
use core::pin::pin;
use core::task::Poll;

use embassy_net::tcp::TcpSocket;
use embassy_net::{IpAddress, IpEndpoint, Stack};
use embassy_time::{Duration, Instant, with_timeout};

use super::{Rights, Server, Service, SlotId, Stats, serve};
use crate::fmt::Ip;

/// Receive buffer of each TCP socket: the largest request (260 bytes) and
/// a pipelined one beginning behind it; a client that pipelines more is held
/// back by TCP's flow control. (It was 1024; 512 saves 5 KiB of the boards'
/// RAM over the 10 sockets, once `close` below kept the window open.)
pub const SOCKET_RX_LEN: usize = 512;
/// Transmit buffer of each TCP socket: the largest reply (260 bytes) and
/// some behind it; a client that pipelines faster than it reads is held
/// back by TCP's flow control.
pub const SOCKET_TX_LEN: usize = 512;
/// Keep-alive probes find a peer that vanished (cable pulled) on an idle connection.
pub(crate) const KEEP_ALIVE: Duration = Duration::from_secs(20);
/// A connection whose peer stops acknowledging for this long is dropped by the stack.
pub(crate) const TCP_TIMEOUT: Duration = Duration::from_secs(60);
/// How long a closing connection may take to deliver its last bytes and
/// its FIN, then its RST; a LAN answers in well under a millisecond, so
/// running out of it means lost packets or a peer gone quiet.
pub const CLOSE_TIMEOUT: Duration = Duration::from_millis(250);
/// Bytes a closing connection drops per read of what the client still sends.
const DRAIN_LEN: usize = 64;

/// Accepts clients on `slot`'s socket and serves them, one at a time, forever.
///
/// A client outside the connect allow-list is reset at once; one outside
/// the write allow-list is served read-only.
pub async fn listen<S: Service>(stack: Stack<'_>, server: &Server<'_, S>, slot: SlotId) -> ! {
    let mut rx = [0u8; SOCKET_RX_LEN];
    let mut tx = [0u8; SOCKET_TX_LEN];
    // The port is fixed at start-up; the rest of the configuration is read per client.
    let port = server.with_config(|config| config.port);
    loop {
        let mut socket = TcpSocket::new(stack, &mut rx, &mut tx);
        socket.set_nagle_enabled(false);
        socket.set_keep_alive(Some(KEEP_ALIVE));
        socket.set_timeout(Some(TCP_TIMEOUT));
        if let Err(e) = socket.accept(port).await {
            warn!("slot {}: accept failed: {:?}", slot, e);
            continue;
        }
        let endpoint = socket.remote_endpoint();
        if endpoint.is_none() {
            // Reset by the client before this task ran: nobody to refuse or serve.
            debug!("slot {}: the client left before it was served", slot);
            continue;
        }
        let peer = Peer::of(endpoint);
        let (may_connect, rights, max_connections) = server.with_config(|config| match peer.address {
            Some(address) => {
                (config.access.may_connect(address), config.access.rights(address), config.max_connections)
            }
            None => (false, Rights::Read, config.max_connections),
        });
        if !may_connect {
            Stats::count(&server.stats().refused_connections);
            info!("slot {}: refused {} (not in the connect allow-list)", slot, peer);
            socket.abort();
            let _ = with_timeout(CLOSE_TIMEOUT, socket.flush()).await;
            continue;
        }
        debug!("slot {}: connection from {} ({})", slot, peer, rights.name());
        if let Some(victim) =
            server.slots().open(slot, max_connections, Instant::now(), peer.address.unwrap_or_default(), rights)
        {
            Stats::count(&server.stats().evictions);
            info!("slot {}: all sessions busy, closing the idlest (slot {})", slot, victim);
        }
        match serve(&mut socket, server, slot).await {
            Ok(()) => debug!("slot {}: {} closed the connection", slot, peer),
            Err(e) => info!("slot {}: closing {}: {}", slot, peer, e),
        }
        server.slots().close(slot);
        close(&mut socket).await;
    }
}

/// Returns once the client has sent its first bytes, or closed its side:
/// what a TLS listener waits for before it takes anything for the client.
/// (embassy-net's `wait_read_ready` waits for data only: a client that
/// closes without sending would hold the socket until the caller's limit.)
#[cfg(feature = "tls")]
pub(crate) async fn first_bytes(socket: &TcpSocket<'_>) {
    const LOOK_AGAIN: Duration = Duration::from_millis(50);
    while !socket.can_recv() && socket.may_recv() {
        let _ = with_timeout(LOOK_AGAIN, socket.wait_read_ready()).await;
    }
}

/// Ends a connection and frees its socket: the replies written so far and a
/// FIN delivered (at most [`CLOSE_TIMEOUT`]), then a reset, sent at once, so
/// that the socket listens again without waiting out TIME-WAIT.
///
/// Until the FIN is acknowledged, what the client still sends is read and
/// dropped. A session that ends on a bad length stops reading; a client with
/// more bytes queued than the receive window then sends no FIN of its own,
/// and its only acknowledgement of ours may ride on a retransmitted segment
/// (Linux's tail loss probe comes before smoltcp's delayed ACK), which
/// smoltcp, as RFC 9293 3.10.7.4 says, drops unread as out of window. Our
/// FIN is then sent again only after smoltcp's retransmission timeout (1 s
/// at least), so the socket sat out all of `CLOSE_TIMEOUT` closing: with
/// clients coming faster than that, every socket was closing at once and a
/// new client was refused (hal_sim_abuse's random streams). Read, the
/// window stays open, and the client's data and then its FIN, which
/// acknowledges ours, come at once.
pub(crate) async fn close(socket: &mut TcpSocket<'_>) {
    socket.close();
    // Twice: the FIN, then the reset (after `abort` a read fails at once).
    for _ in 0..2 {
        let delivered = poll_fn(|cx| {
            // On the stack, not in the task: dropped bytes need no room.
            let mut sink = [0u8; DRAIN_LEN];
            while let Poll::Ready(Ok(1..)) = pin!(socket.read(&mut sink)).poll(cx) {}
            pin!(socket.flush()).poll(cx)
        });
        let _ = with_timeout(CLOSE_TIMEOUT, delivered).await;
        socket.abort();
    }
}

/// A client's IPv4 address (`None`: not IPv4, never allowed) and port, as
/// logs show it (through [`Ip`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Peer {
    pub(crate) address: Option<[u8; 4]>,
    pub(crate) port: u16,
}

impl Peer {
    pub(crate) fn of(endpoint: Option<IpEndpoint>) -> Self {
        #[allow(unreachable_patterns, reason = "IPv6 exists only when another crate enables it")]
        let address = endpoint.and_then(|endpoint| match endpoint.addr {
            IpAddress::Ipv4(address) => Some(address.octets()),
            _ => None,
        });
        Self { address, port: endpoint.map_or(0, |endpoint| endpoint.port) }
    }
}

impl fmt::Display for Peer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.address {
            Some(address) => write!(f, "{}:{}", Ip(address), self.port),
            None => write!(f, "a non-IPv4 client"),
        }
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for Peer {
    fn format(&self, f: defmt::Formatter<'_>) {
        match self.address {
            Some(address) => defmt::write!(f, "{}:{}", Ip(address), self.port),
            None => defmt::write!(f, "a non-IPv4 client"),
        }
    }
}
