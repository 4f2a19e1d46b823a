//! Accepting HTTP clients on an embassy-net stack: one task per connection
//! ([`super::MAX_HTTP_CONNECTIONS`] of them), each with its socket and its
//! [`Buffers`] in its static storage; with `tls`, HTTPS's the same way
//! ([`HTTPS_SOCKETS`] tasks, [`listen_secure`]).

use embassy_net::Stack;
use embassy_net::tcp::TcpSocket;
use embassy_time::Duration;

use embedded_storage_async::nor_flash::NorFlash;

use super::{Buffers, Http, serve};
#[cfg(feature = "tls")]
use super::{Scheme, serve_kept};
use crate::control::Platform;
use crate::server::{Peer, close};

/// Receive buffer of each HTTP socket (a request is read as it comes).
pub const SOCKET_RX_LEN: usize = 512;
/// Transmit buffer of each HTTP socket (a response is written as it is taken).
pub const SOCKET_TX_LEN: usize = 512;
/// A connection whose peer stops acknowledging for this long is dropped by the stack.
const TCP_TIMEOUT: Duration = Duration::from_secs(10);

/// Accepts clients on the API's port and serves them, one connection at a
/// time, forever. Run [`super::MAX_HTTP_CONNECTIONS`] of these.
pub async fn listen<F: NorFlash, P: Platform>(stack: Stack<'_>, http: &Http<'_, F, P>) -> ! {
    let port = http.port();
    let mut rx = [0u8; SOCKET_RX_LEN];
    let mut tx = [0u8; SOCKET_TX_LEN];
    let mut buffers = Buffers::new();
    loop {
        let mut socket = TcpSocket::new(stack, &mut rx, &mut tx);
        socket.set_timeout(Some(TCP_TIMEOUT));
        if let Err(e) = socket.accept(port).await {
            warn!("http: accept failed: {:?}", e);
            continue;
        }
        let endpoint = socket.remote_endpoint();
        if endpoint.is_none() {
            // Reset by the client before this task ran.
            continue;
        }
        let peer = Peer::of(endpoint);
        let served = {
            let (reader, writer) = socket.split();
            serve(http, peer.address, reader, writer, &mut buffers).await
        };
        if let Err(e) = served {
            debug!("http: {}: {}", peer, e);
        }
        close(&mut socket).await;
        drop(socket);
        if let Ok(Some(action)) = served {
            info!("http: {:?} requested by {}", action, peer);
            http.perform(action).await;
        }
    }
}

/// HTTPS sessions at once. Each also takes one of the TLS arena's seats
/// (`server::secure::MAX_TLS_SESSIONS`), which port 802 may take back.
#[cfg(feature = "tls")]
pub const MAX_HTTPS_SESSIONS: usize = 1;

/// Sockets (and tasks) on the HTTPS port: the session's, and one more, so
/// that a second client (a browser's second connection, `mbio` beside the
/// page) is accepted and waits for the session rather than being reset.
/// The session's connection yields to it after its current response.
#[cfg(feature = "tls")]
pub const HTTPS_SOCKETS: usize = MAX_HTTPS_SESSIONS + 1;

/// A connection waits this long for the HTTPS session before it is closed.
#[cfg(feature = "tls")]
const SESSION_WAIT: Duration = Duration::from_secs(10);

/// HTTPS sockets' buffers: the TLS session's pipe takes 1 KiB at a time.
#[cfg(feature = "tls")]
const SECURE_SOCKET_LEN: usize = 1024;

/// Accepts HTTPS clients on `port` and serves them with `tls`'s
/// configuration (the device's certificate; no client certificate asked
/// for), forever. Run [`HTTPS_SOCKETS`] of these.
///
/// A connection waits for the one session ([`MAX_HTTPS_SESSIONS`]) and a
/// seat in the TLS arena, at most [`SESSION_WAIT`], then for the handshake
/// (one at a time with port 802's, as the arena holds one handshake's
/// peak), at most [`crate::server::secure::HANDSHAKE_TIMEOUT`]; then it is
/// served request after request ([`super::serve_kept`]) until it ends or
/// another client (HTTPS, or a Modbus/TCP Security one) wants its place.
#[cfg(feature = "tls")]
pub async fn listen_secure<F: NorFlash, P: Platform>(
    stack: Stack<'_>,
    http: &Http<'_, F, P>,
    tls: &tls::Server,
    port: u16,
) -> ! {
    use core::sync::atomic::Ordering::Relaxed;

    use embassy_time::with_timeout;

    use crate::server::secure::{HANDSHAKE_TIMEOUT, seat};

    let mut rx = [0u8; SECURE_SOCKET_LEN];
    let mut tx = [0u8; SECURE_SOCKET_LEN];
    let mut buffers = Buffers::new();
    loop {
        let mut socket = TcpSocket::new(stack, &mut rx, &mut tx);
        socket.set_timeout(Some(TCP_TIMEOUT));
        if let Err(e) = socket.accept(port).await {
            warn!("https: accept failed: {:?}", e);
            continue;
        }
        let peer = Peer::of(socket.remote_endpoint());
        if peer.address.is_none() {
            socket.abort();
            continue;
        }
        // The client's first bytes before it waits for the session: a
        // connection that sends nothing makes no other give its place up.
        if with_timeout(HANDSHAKE_TIMEOUT, crate::server::first_bytes(&socket)).await.is_err() {
            debug!("https: {}: closed, nothing sent", peer);
            close(&mut socket).await;
            continue;
        }
        http.waiting.fetch_add(1, Relaxed);
        http.arrival.signal(());
        let place = with_timeout(SESSION_WAIT, async { (http.session.lock().await, seat(false).await) }).await;
        http.waiting.fetch_sub(1, Relaxed);
        let Ok(_place) = place else {
            debug!("https: {}: closed, the session stayed busy", peer);
            close(&mut socket).await;
            continue;
        };
        let served = serve_secure(http, tls, &mut socket, peer, &mut buffers).await;
        close(&mut socket).await;
        drop(socket);
        match served {
            Err(e) => debug!("https: {}: handshake failed: {}", peer, e),
            Ok(Err(e)) => debug!("https: {}: {}", peer, e),
            Ok(Ok(None)) => {}
            Ok(Ok(Some(action))) => {
                info!("https: {:?} requested by {}", action, peer);
                http.perform(action).await;
            }
        }
    }
}

/// One HTTPS connection that has its place: the handshake (one at a time,
/// at most `HANDSHAKE_TIMEOUT`), then its requests, then close_notify.
/// `Err`: the handshake failed; `Ok`: what serving gave.
#[cfg(feature = "tls")]
async fn serve_secure<F: NorFlash, P: Platform>(
    http: &Http<'_, F, P>,
    tls: &tls::Server,
    socket: &mut TcpSocket<'_>,
    peer: Peer,
    buffers: &mut Buffers,
) -> Result<Result<Option<super::Action>, super::Error>, tls::Error> {
    use embassy_time::with_timeout;

    use crate::server::secure::{HANDSHAKE_TIMEOUT, handshake_permit};

    let mut session = tls::Session::new(tls, socket)?;
    let handshake = async {
        let _permit = handshake_permit().await;
        session.handshake().await
    };
    match with_timeout(HANDSHAKE_TIMEOUT, handshake).await {
        Ok(shaken) => shaken?,
        Err(_) => return Err(tls::Error::Io(embedded_io_async::ErrorKind::TimedOut)),
    }
    let served = serve_kept(http, peer.address, Scheme::Https, &mut session, buffers).await;
    let _ = with_timeout(crate::server::CLOSE_TIMEOUT, session.close()).await;
    Ok(served)
}
