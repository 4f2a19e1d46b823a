//! Mbed TLS spike on the host: the device's engine configuration serving
//! TLS on 127.0.0.1 for `openssl s_client`, every Mbed TLS allocation in
//! the fixed arena (mbedtls_platform_set_calloc_free).
//!
//!   cargo run --release --bin mbedtls-host -- [PORT] [ARENA_LIMIT_BYTES] [CONNECTIONS]
//!   openssl s_client -connect 127.0.0.1:PORT -tls1_3 -cert certs/operator.pem \
//!       -key certs/operator.key -CAfile certs/server.pem
//!
//! Each connection: the handshake (client certificate required), the role
//! copied out of the client's certificate by the verify callback, one line
//! back, close_notify; then the arena's peak for that connection.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::Ordering;

use mbedtls_spike::sys::*;
use mbedtls_spike::*;

unsafe extern "C" fn send(p: *mut std::ffi::c_void, buf: *const u8, len: usize) -> i32 {
    let s = unsafe { &mut *p.cast::<TcpStream>() };
    match s.write(unsafe { std::slice::from_raw_parts(buf, len) }) {
        Ok(n) => n as i32,
        Err(_) => -0x4e, // MBEDTLS_ERR_NET_SEND_FAILED
    }
}

unsafe extern "C" fn recv(p: *mut std::ffi::c_void, buf: *mut u8, len: usize) -> i32 {
    let s = unsafe { &mut *p.cast::<TcpStream>() };
    match s.read(unsafe { std::slice::from_raw_parts_mut(buf, len) }) {
        Ok(n) => n as i32,
        Err(_) => -0x4c, // MBEDTLS_ERR_NET_RECV_FAILED
    }
}

fn os_random(buf: &mut [u8]) {
    std::fs::File::open("/dev/urandom").and_then(|mut f| f.read_exact(buf)).expect("urandom");
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let port: u16 = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(4433);
    let limit: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(ARENA_SIZE);
    let count: usize = args.get(3).and_then(|a| a.parse().ok()).unwrap_or(1);
    unsafe {
        RANDOM = os_random;
        init().expect("init");
    }
    let config: &'static mut Config = Box::leak(Box::new(Config::zeroed()));
    unsafe { config.setup(true, SERVER_CERT, SERVER_KEY, CA_CERT, true) }.expect("config");
    println!("config: arena in use {} B", ARENA.used.load(Ordering::Relaxed));
    let listener = TcpListener::bind(("127.0.0.1", port)).expect("bind");
    println!("listening on 127.0.0.1:{port}, arena limit {limit} B");
    for _ in 0..count {
        let (sock, _) = listener.accept().expect("accept");
        let sock: &'static mut TcpStream = Box::leak(Box::new(sock));
        let before = ARENA.used.load(Ordering::Relaxed);
        ARENA.reset_peak(limit);
        let conn: &'static mut Conn = Box::leak(Box::new(Conn::zeroed()));
        let outcome = unsafe {
            conn.setup(config, (sock as *mut TcpStream).cast(), send, recv, None).and_then(|()| loop {
                match conn.handshake() {
                    Ok(true) => break Ok(()),
                    Ok(false) => continue,
                    Err(e) => break Err(e),
                }
            })
        };
        match outcome {
            Ok(()) => unsafe {
                let version = std::ffi::CStr::from_ptr(mbedtls_ssl_get_version(&conn.ssl));
                let suite = std::ffi::CStr::from_ptr(mbedtls_ssl_get_ciphersuite(&conn.ssl));
                println!("established: {version:?} {suite:?} role {:?} (malformed: {})", conn.role.get(), conn.role.malformed);
                println!("arena in use once established: {} B above the config", ARENA.used.load(Ordering::Relaxed) - before);
                let line = format!("hello, your role is {:?}\n", conn.role.get());
                mbedtls_ssl_write(&mut conn.ssl, line.as_ptr(), line.len());
                mbedtls_ssl_close_notify(&mut conn.ssl);
            },
            Err(e) => println!("handshake failed: -0x{:04x}", -e),
        }
        println!(
            "arena: peak {} B above the {} B in use before, {} allocations, {} refused",
            ARENA.peak.load(Ordering::Relaxed) - before,
            before,
            ARENA.allocs.load(Ordering::Relaxed),
            ARENA.refused.load(Ordering::Relaxed),
        );
        unsafe { conn.free() };
        println!("after the connection: arena in use {} B", ARENA.used.load(Ordering::Relaxed));
    }
}
