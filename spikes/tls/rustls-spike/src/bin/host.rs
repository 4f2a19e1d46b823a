//! rustls spike on the host: the device's engine configuration serving
//! TLS on 127.0.0.1 for `openssl s_client`, its allocations in a fixed arena.
//!
//!   cargo run --release --bin rustls-host -- [PORT] [ARENA_LIMIT_BYTES] [CONNECTIONS]
//!   openssl s_client -connect 127.0.0.1:PORT -tls1_3 -cert certs/operator.pem \
//!       -key certs/operator.key -CAfile certs/server.pem
//!
//! Each connection: the handshake (client certificate required), the role
//! read from the client's certificate, one line back, close_notify; then
//! the arena's peak for that connection. The incoming record buffer is
//! 16 KiB + 325 bytes: a client message larger than that fails the
//! handshake (InFull). Allocations go to the arena only while rustls runs.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::io::{Read, Write};
use std::net::TcpListener;
use std::sync::atomic::Ordering;

use rustls::server::UnbufferedServerConnection;
use rustls_spike::arena::Arena;
use rustls_spike::{Buffers, Step, StepError, provider, role, send_server, server_config, step_server};

const ARENA: usize = 256 * 1024;
static TLS_ARENA: Arena<ARENA> = Arena::new();

thread_local! { static IN_TLS: Cell<bool> = const { Cell::new(false) }; }

struct Dispatch;
unsafe impl GlobalAlloc for Dispatch {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if IN_TLS.with(|f| f.get()) {
            unsafe { TLS_ARENA.alloc(layout) }
        } else {
            unsafe { System.alloc(layout) }
        }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        if TLS_ARENA.contains(ptr) {
            unsafe { TLS_ARENA.dealloc(ptr, layout) }
        } else {
            unsafe { System.dealloc(ptr, layout) }
        }
    }
}
#[global_allocator]
static GLOBAL: Dispatch = Dispatch;

fn in_tls<R>(f: impl FnOnce() -> R) -> R {
    IN_TLS.with(|t| t.set(true));
    let r = f();
    IN_TLS.with(|t| t.set(false));
    r
}

const IN: usize = 16 * 1024 + 325;
const OUT: usize = 4096;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let port: u16 = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(4433);
    let limit: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(ARENA);
    let count: usize = args.get(3).and_then(|a| a.parse().ok()).unwrap_or(1);
    let config = in_tls(|| server_config(provider())).expect("config");
    println!("config: arena in use {} B", TLS_ARENA.used.load(Ordering::Relaxed));
    let listener = TcpListener::bind(("127.0.0.1", port)).expect("bind");
    println!("listening on 127.0.0.1:{port}, arena limit {limit} B");
    let mut b: Box<Buffers<IN, OUT>> = Box::new(Buffers::new());
    for _ in 0..count {
        let (mut sock, _) = listener.accept().expect("accept");
        b.in_len = 0;
        b.out_len = 0;
        TLS_ARENA.reset_peak(limit);
        let before = TLS_ARENA.used.load(Ordering::Relaxed);
        let mut conn = in_tls(|| UnbufferedServerConnection::new(config.clone())).expect("conn");
        let outcome: Result<(), StepError> = loop {
            let r = in_tls(|| step_server(&mut conn, &mut b, &mut |d| println!("app data: {d:?}")));
            match r {
                Ok(Step::WantRead) => {
                    let n = sock.read(&mut b.inb[b.in_len..]).unwrap_or(0);
                    if n == 0 {
                        break Err(StepError::Unexpected);
                    }
                    b.in_len += n;
                }
                Ok(Step::Wrote) => {
                    let _ = sock.write_all(&b.out[..b.out_len]);
                    b.out_len = 0;
                }
                Ok(Step::Established) => {
                    let _ = sock.write_all(&b.out[..b.out_len]);
                    b.out_len = 0;
                    let peer = conn.peer_certificates().and_then(|c| c.first()).map(|c| c.to_vec());
                    let role = peer.as_deref().map(role::role);
                    let version = conn.protocol_version();
                    let suite = conn.negotiated_cipher_suite().map(|s| s.suite());
                    println!("established: {version:?} {suite:?} role {role:?}");
                    println!("arena in use once established: {} B above the config", TLS_ARENA.used.load(Ordering::Relaxed) - before);
                    let line = format!("hello, your role is {role:?}\n");
                    let r = in_tls(|| send_server(&mut conn, &mut b, line.as_bytes(), true));
                    let _ = sock.write_all(&b.out[..b.out_len]);
                    b.out_len = 0;
                    break r;
                }
                Ok(Step::Closed) => break Err(StepError::Unexpected),
                Err(e) => {
                    // Send what rustls queued (its fatal alert), if anything.
                    let _ = in_tls(|| step_server(&mut conn, &mut b, &mut |_| {}));
                    let _ = sock.write_all(&b.out[..b.out_len]);
                    b.out_len = 0;
                    break Err(e);
                }
            }
        };
        println!(
            "outcome {outcome:?}; arena: peak {} B above the {} B in use before, {} allocations, {} refused",
            TLS_ARENA.peak.load(Ordering::Relaxed) - before,
            before,
            TLS_ARENA.allocs.load(Ordering::Relaxed),
            TLS_ARENA.refused.load(Ordering::Relaxed),
        );
        in_tls(|| drop(conn));
        println!("after the connection: arena in use {} B", TLS_ARENA.used.load(Ordering::Relaxed));
    }
}
