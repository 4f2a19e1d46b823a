//! Accepting HTTP clients on an embassy-net stack: one task per connection
//! ([`super::MAX_HTTP_CONNECTIONS`] of them), each with its socket and its
//! [`Buffers`] in its static storage.

use embassy_net::Stack;
use embassy_net::tcp::TcpSocket;
use embassy_time::Duration;

use embedded_storage_async::nor_flash::NorFlash;

use super::{Buffers, Http, serve};
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
