//! Modbus/TCP Security (MB-TCP-Security v2.1, IANA port 802): Modbus over
//! TLS with mutual authentication, each client's rights from the role its
//! certificate carries (docs/tls.md).
//!
//! A connection on 802 is taken as on 502 (the connect allow-list first,
//! the same session slots, limit and eviction, the same sessions and
//! watchdog), with a TLS handshake before its first request:
//!
//! - the client must present a certificate that chains to the installed
//!   client CA, or the handshake fails (`tls_refused`);
//! - its role (the extension 1.3.6.1.4.1.50316.802.1, a UTF8String) must be
//!   one the `tls.roles` setting names, or the connection is closed after
//!   the handshake (`tls_refused`): a client the plant gave no rights gets
//!   no session;
//! - its rights are its role's, and no more than the write allow-list
//!   gives its address; a request they do not cover gets exception 01.
//!
//! One handshake runs at a time, at most [`HANDSHAKE_TIMEOUT`] from the
//! connection: the arena holds one handshake's peak beside the open
//! sessions, and a client that stalls its handshake holds no other back
//! for longer. A client that connects and sends nothing takes nothing: the
//! handshake starts at its first bytes.
//!
//! The arena holds [`MAX_TLS_SESSIONS`] sessions, on 802 and HTTPS
//! together: each takes a [`Seat`] before its session is made. Modbus
//! comes first: a client on 802 that finds no seat free says so
//! ([`modbus_waiting`]), and the HTTPS session gives its seat up after its
//! current response, or at once when it is idle; HTTPS never makes a
//! Modbus client wait for more than that.

use core::sync::atomic::{AtomicUsize, Ordering};
use embassy_net::Stack;
use embassy_net::tcp::TcpSocket;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;

use embassy_sync::mutex::{Mutex, MutexGuard};
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, with_deadline, with_timeout};

use super::listener::{KEEP_ALIVE, Peer, TCP_TIMEOUT, close, first_bytes};
use super::{Server, Service, SlotId, Stats, serve};

/// Modbus/TCP Security's port (IANA).
pub const SECURE_PORT: u16 = 802;

/// Sessions on port 802 served at once: as many as the TLS arena holds
/// ([`MAX_TLS_SESSIONS`]), when no HTTPS session holds a seat.
pub const MAX_SECURE_CONNECTIONS: usize = MAX_TLS_SESSIONS;

/// Listening sockets beyond the sessions, as on 502: a new client finds one
/// listening while another closes, and is then served or refused.
pub const SPARE_SECURE_SOCKETS: usize = 1;

/// Sockets (and listener tasks) on port 802.
pub const SECURE_POOL: usize = MAX_SECURE_CONNECTIONS + SPARE_SECURE_SOCKETS;

/// The longest a handshake may take, from the connection to its end.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// The TCP socket's buffers: the session's pipe takes 1 KiB at a time.
const SOCKET_RX_LEN: usize = 1024;
const SOCKET_TX_LEN: usize = 1024;

/// TLS sessions open at once in the program, on 802 and HTTPS together:
/// the arena (`program::TLS_ARENA_LEN`) holds this many.
pub const MAX_TLS_SESSIONS: usize = 2;

/// Seats taken, of [`MAX_TLS_SESSIONS`].
static SEATS: AtomicUsize = AtomicUsize::new(0);
/// Raised when a seat is given back.
static FREED: Signal<CriticalSectionRawMutex, ()> = Signal::new();
/// Modbus clients waiting for a seat, and the signal each raises.
static MODBUS_WAITING: AtomicUsize = AtomicUsize::new(0);
static WANTED: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// How often a client waiting for a seat looks again (a given-back seat
/// wakes one waiter; any other finds it at its next look).
const SEAT_POLL: Duration = Duration::from_millis(100);

/// Room in the arena for one TLS session, given back when dropped.
#[derive(Debug)]
pub struct Seat(());

impl Drop for Seat {
    fn drop(&mut self) {
        SEATS.fetch_sub(1, Ordering::AcqRel);
        FREED.signal(());
    }
}

/// A seat, if one is free.
fn try_seat() -> Option<Seat> {
    SEATS
        .fetch_update(Ordering::AcqRel, Ordering::Acquire, |taken| (taken < MAX_TLS_SESSIONS).then_some(taken + 1))
        .ok()
        .map(|_| Seat(()))
}

/// A seat for a session: at once if one is free, else once one is given
/// back. A Modbus client (`modbus`) waiting makes the HTTPS session give
/// its seat up ([`modbus_waiting`]); HTTPS just waits, and takes no seat
/// while a Modbus client waits for one. The caller bounds the wait.
pub async fn seat(modbus: bool) -> Seat {
    /// Counts a Modbus client as waiting while it lives.
    struct Waiting;
    impl Drop for Waiting {
        fn drop(&mut self) {
            MODBUS_WAITING.fetch_sub(1, Ordering::AcqRel);
        }
    }
    let mut waiting = None;
    loop {
        if let Some(seat) = (modbus || !modbus_waiting()).then(try_seat).flatten() {
            return seat;
        }
        if modbus && waiting.is_none() {
            MODBUS_WAITING.fetch_add(1, Ordering::AcqRel);
            waiting = Some(Waiting);
            WANTED.signal(());
        }
        let _ = with_timeout(SEAT_POLL, FREED.wait()).await;
    }
}

/// Whether a Modbus client waits for a seat: the HTTPS session then ends.
pub fn modbus_waiting() -> bool {
    MODBUS_WAITING.load(Ordering::Acquire) > 0
}

/// Returns once a Modbus client waits for a seat.
pub async fn modbus_wants_a_seat() {
    while !modbus_waiting() {
        WANTED.wait().await;
    }
}

/// One handshake at a time, on 802 and on HTTPS alike.
static HANDSHAKE: Mutex<CriticalSectionRawMutex, ()> = Mutex::new(());

/// The right to run a handshake: one at a time in the program, port 802's
/// and HTTPS's alike, since the TLS arena holds one handshake's peak.
pub async fn handshake_permit() -> MutexGuard<'static, CriticalSectionRawMutex, ()> {
    HANDSHAKE.lock().await
}

/// Accepts clients on port 802 for `slot` (one of the slots past the plain
/// listeners') and serves them with `tls`'s configuration, forever.
pub async fn listen_secure<S: Service>(stack: Stack<'_>, server: &Server<'_, S>, tls: &tls::Server, slot: SlotId) -> ! {
    let mut rx = [0u8; SOCKET_RX_LEN];
    let mut tx = [0u8; SOCKET_TX_LEN];
    loop {
        let mut socket = TcpSocket::new(stack, &mut rx, &mut tx);
        socket.set_nagle_enabled(false);
        socket.set_keep_alive(Some(KEEP_ALIVE));
        socket.set_timeout(Some(TCP_TIMEOUT));
        if let Err(e) = socket.accept(SECURE_PORT).await {
            warn!("secure slot {}: accept failed: {:?}", slot, e);
            continue;
        }
        let peer = Peer::of(socket.remote_endpoint());
        let Some(address) = peer.address else {
            socket.abort();
            continue;
        };
        let (may_connect, address_rights, max_connections) = server.with_config(|config| {
            (config.access.may_connect(address), config.access.rights(address), config.max_connections)
        });
        if !may_connect {
            Stats::count(&server.stats().refused_connections);
            info!("secure slot {}: refused {} (not in the connect allow-list)", slot, peer);
            socket.abort();
            let _ = with_timeout(super::CLOSE_TIMEOUT, socket.flush()).await;
            continue;
        }
        match session(&mut socket, server, tls, slot, address, address_rights, max_connections).await {
            Ok(()) => debug!("secure slot {}: {} closed the connection", slot, peer),
            Err(reason) => info!("secure slot {}: closing {}: {}", slot, peer, reason),
        }
        server.slots().close(slot);
        close(&mut socket).await;
    }
}

/// Why a connection on 802 ended.
#[derive(Clone, Copy, Debug)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum Ended {
    Handshake(tls::Error),
    HandshakeTimeout,
    NoRole,
    UnknownRole,
    Session(super::Error<tls::Error>),
}

impl core::fmt::Display for Ended {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Handshake(e) => write!(f, "handshake failed: {e}"),
            Self::HandshakeTimeout => f.write_str("handshake not done in time"),
            Self::NoRole => f.write_str("its certificate carries no role"),
            Self::UnknownRole => f.write_str("its role is not in tls.roles"),
            Self::Session(e) => write!(f, "{e}"),
        }
    }
}

async fn session<S: Service>(
    socket: &mut TcpSocket<'_>,
    server: &Server<'_, S>,
    tls: &tls::Server,
    slot: SlotId,
    address: [u8; 4],
    address_rights: super::Rights,
    max_connections: usize,
) -> Result<(), Ended> {
    let stats = server.stats();
    let started = Instant::now();
    // The client's first bytes before anything is taken for it: a client
    // that connects and sends nothing holds no seat, and no other client's
    // handshake waits on it.
    let deadline = started + HANDSHAKE_TIMEOUT;
    if with_deadline(deadline, first_bytes(socket)).await.is_err() {
        Stats::count(&stats.tls_failed);
        return Err(Ended::HandshakeTimeout);
    }
    let Ok(_seat) = with_deadline(deadline, seat(true)).await else {
        Stats::count(&stats.tls_failed);
        return Err(Ended::HandshakeTimeout);
    };
    let mut session = tls::Session::new(tls, socket).map_err(|e| {
        Stats::count(&stats.tls_failed);
        Ended::Handshake(e)
    })?;
    let handshake = async {
        let _permit = handshake_permit().await;
        session.handshake().await
    };
    match with_deadline(deadline, handshake).await {
        Ok(Ok(())) => {}
        Ok(Err(e)) => {
            Stats::count(if e.is_certificate() { &stats.tls_refused } else { &stats.tls_failed });
            return Err(Ended::Handshake(e));
        }
        Err(_) => {
            Stats::count(&stats.tls_failed);
            return Err(Ended::HandshakeTimeout);
        }
    }
    let role_rights = match role(session.peer_certificate()) {
        Some(role) => server.with_config(|config| config.roles.rights(role.as_bytes())).ok_or(Ended::UnknownRole),
        None => Err(Ended::NoRole),
    };
    let role_rights = match role_rights {
        Ok(rights) => rights,
        Err(ended) => {
            Stats::count(&stats.tls_refused);
            let _ = with_timeout(super::CLOSE_TIMEOUT, session.close()).await;
            return Err(ended);
        }
    };
    Stats::count(&stats.tls_sessions);
    let rights = role_rights.and(address_rights);
    debug!(
        "secure slot {}: {} ({}) after a {} ms handshake",
        slot,
        session.version(),
        rights.name(),
        started.elapsed().as_millis()
    );
    if let Some(victim) = server.slots().open(slot, max_connections, Instant::now(), address, rights) {
        Stats::count(&stats.evictions);
        info!("secure slot {}: all sessions busy, closing the idlest (slot {})", slot, victim);
    }
    let result = serve(&mut session, server, slot).await.map_err(Ended::Session);
    let _ = with_timeout(super::CLOSE_TIMEOUT, session.close()).await;
    result
}

/// The role the verified client certificate carries, if it carries one
/// that is a UTF8String (anything else is no role).
fn role(der: Option<&[u8]>) -> Option<&str> {
    certificate::Certificate::parse(der?).ok()?.role().ok().flatten()
}
