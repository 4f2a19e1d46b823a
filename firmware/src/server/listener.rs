//! Accepting Modbus TCP clients on an embassy-net stack: one task per socket,
//! one more socket than sessions so a new client is never refused.

use embassy_executor::{SpawnError, Spawner};
use embassy_net::Stack;
use embassy_net::tcp::TcpSocket;
use embassy_time::{Duration, Instant, with_timeout};

use super::{SOCKET_POOL, Shared, SlotId, serve};

/// Receive buffer of each TCP socket: room for several pipelined requests.
pub const SOCKET_RX_LEN: usize = 1024;
/// Transmit buffer of each TCP socket: room for several replies.
pub const SOCKET_TX_LEN: usize = 1024;
/// Keep-alive probes find a peer that vanished (cable pulled) on an idle connection.
const KEEP_ALIVE: Duration = Duration::from_secs(20);
/// A connection whose peer stops acknowledging for this long is dropped by the stack.
const TCP_TIMEOUT: Duration = Duration::from_secs(60);
/// How long a closing connection may take to deliver its last bytes.
const CLOSE_TIMEOUT: Duration = Duration::from_secs(1);

/// Accepts clients on `slot`'s socket and serves them, one at a time, forever.
pub async fn listen(stack: Stack<'_>, shared: &Shared<'_>, slot: SlotId) -> ! {
    let mut rx = [0u8; SOCKET_RX_LEN];
    let mut tx = [0u8; SOCKET_TX_LEN];
    let config = shared.config();
    loop {
        let mut socket = TcpSocket::new(stack, &mut rx, &mut tx);
        socket.set_nagle_enabled(false);
        socket.set_keep_alive(Some(KEEP_ALIVE));
        socket.set_timeout(Some(TCP_TIMEOUT));
        if let Err(e) = socket.accept(config.port).await {
            warn!("slot {}: accept failed: {:?}", slot, e);
            continue;
        }
        if let Some(peer) = socket.remote_endpoint() {
            info!("slot {}: connection from {}", slot, peer);
        }
        if let Some(victim) = shared.slots().open(slot, config.max_connections, Instant::now()) {
            info!("slot {}: all sessions busy, closing the idlest (slot {})", slot, victim);
        }
        match serve(&mut socket, shared, slot).await {
            Ok(()) => info!("slot {}: closed by the client", slot),
            Err(e) => info!("slot {}: closing: {}", slot, e),
        }
        shared.slots().close(slot);
        socket.close();
        let _ = with_timeout(CLOSE_TIMEOUT, socket.flush()).await;
        socket.abort();
        let _ = with_timeout(CLOSE_TIMEOUT, socket.flush()).await;
    }
}

/// One listener task per socket. Socket buffers live in the task's static storage.
#[embassy_executor::task(pool_size = SOCKET_POOL)]
pub async fn listener_task(stack: Stack<'static>, shared: &'static Shared<'static>, slot: SlotId) -> ! {
    listen(stack, shared, slot).await
}

/// Spawns `max_connections + 1` listener tasks.
pub fn spawn_listeners(
    spawner: Spawner,
    stack: Stack<'static>,
    shared: &'static Shared<'static>,
) -> Result<(), SpawnError> {
    for slot in 0..=shared.config().max_connections {
        spawner.spawn(listener_task(stack, shared, slot)?);
    }
    Ok(())
}
