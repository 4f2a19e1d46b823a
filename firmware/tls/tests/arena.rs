//! The arena filled: with room for one handshake and not two, a second
//! client's handshake fails (out of memory, as any other failure: an error,
//! not a panic), the first session goes on, and once it ends a new client
//! is served again. And a client certificate chain larger than a record
//! fails its handshake alone. Its own test binary: its own arena.
//!
//! Needs `openssl` on the PATH (scripts/setup installs it).

#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::indexing_slicing,
    clippy::panic,
    reason = "a failed step is a failed test"
)]

mod common;

use std::io::Write as _;
use std::process::Command;

use common::{Blocking, fixture, fixtures, listener, s_client};
use embedded_io_async::{Read, Write};
use tls::{Credentials, Server, Session};

/// The configuration (4 KiB) and one TLS 1.3 handshake with a client
/// certificate (33 KiB at its peak: the 16 KiB and 4 KiB record buffers
/// and the key exchange), with little to spare: a second session's record
/// buffers do not fit beside the first.
const ARENA_LEN: usize = 44 * 1024;

fn server() -> Server {
    let (certificate, key, ca) = (fixture("device.der"), fixture("device.key.der"), fixture("client-ca.der"));
    Server::new(&Credentials { certificate: &certificate, key: &key, client_ca: Some(&ca) }).unwrap()
}

#[test]
fn a_full_arena_fails_a_handshake_and_the_device_goes_on() {
    let _serial = common::init(ARENA_LEN);
    let server = server();
    let operator = ["-tls1_3", "-cert", "operator.pem", "-key", "operator.key"];
    let (listener, port) = listener();

    // The first client: served, and kept open.
    let mut first_client = s_client(port, &operator);
    let (socket, _) = listener.accept().unwrap();
    let mut first = Session::new(&server, Blocking(socket)).unwrap();
    embassy_futures::block_on(first.handshake()).unwrap();
    let held = tls::arena::usage();

    // The second: no room for its record buffers, or for its handshake.
    let mut second_client = s_client(port, &operator);
    let (socket, _) = listener.accept().unwrap();
    let refused_before = tls::arena::usage().refused;
    let second = match Session::new(&server, Blocking(socket)) {
        Err(error) => Err(error),
        Ok(mut session) => embassy_futures::block_on(session.handshake()),
    };
    assert_eq!(second, Err(tls::Error::OutOfMemory), "the arena: {:?}", tls::arena::usage());
    assert!(tls::arena::usage().refused > refused_before);
    assert_eq!(tls::arena::usage().used, held.used, "the failed session gave back all it took");
    let _ = second_client.kill();
    let _ = second_client.wait();

    // The first session carries on.
    let stdin = first_client.stdin.as_mut().unwrap();
    stdin.write_all(b"still here\n").unwrap();
    let mut buf = [0u8; 32];
    let n = embassy_futures::block_on(first.read(&mut buf)).unwrap();
    assert_eq!(&buf[..n], b"still here\n");
    embassy_futures::block_on(first.write(b"ok\n")).unwrap();
    drop(first);
    drop(first_client.stdin.take());
    let _ = first_client.wait();

    // Room again: a new client is served.
    let mut third_client = s_client(port, &operator);
    let (socket, _) = listener.accept().unwrap();
    let mut third = Session::new(&server, Blocking(socket)).unwrap();
    embassy_futures::block_on(third.handshake()).unwrap();
    drop(third);
    drop(third_client.stdin.take());
    let _ = third_client.wait();
}

/// A chain of `count` intermediate CAs under the client CA, the last one
/// issuing `leaf`, written to a temporary directory: (leaf.pem, leaf.key,
/// chain.pem with the intermediates).
fn long_chain(count: usize) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let openssl = |args: &[&str]| {
        let status = Command::new("openssl").args(args).current_dir(dir.path()).output().unwrap();
        assert!(status.status.success(), "openssl {args:?}: {}", String::from_utf8_lossy(&status.stderr));
    };
    let ca = fixtures().join("client-ca.pem");
    let ca_key = fixtures().join("client-ca.key");
    let (mut issuer, mut issuer_key) = (ca.to_str().unwrap().to_string(), ca_key.to_str().unwrap().to_string());
    std::fs::write(dir.path().join("ca.ext"), "basicConstraints=critical,CA:TRUE\n").unwrap();
    let mut chain = String::new();
    for i in 0..count {
        let (key, csr, cert) = (format!("i{i}.key"), format!("i{i}.csr"), format!("i{i}.pem"));
        openssl(&["ecparam", "-name", "prime256v1", "-genkey", "-noout", "-out", &key]);
        // A long subject makes each certificate about 1 KiB.
        let subject = format!("/CN=intermediate {i}/O={}", "x".repeat(60));
        openssl(&["req", "-new", "-key", &key, "-subj", &subject, "-out", &csr]);
        openssl(&[
            "x509",
            "-req",
            "-in",
            &csr,
            "-CA",
            &issuer,
            "-CAkey",
            &issuer_key,
            "-set_serial",
            &(100 + i).to_string(),
            "-days",
            "3650",
            "-extfile",
            "ca.ext",
            "-out",
            &cert,
        ]);
        chain = std::fs::read_to_string(dir.path().join(&cert)).unwrap() + &chain;
        issuer = cert;
        issuer_key = key;
    }
    std::fs::write(dir.path().join("chain.pem"), chain).unwrap();
    std::fs::write(dir.path().join("leaf.ext"), "1.3.6.1.4.1.50316.802.1=ASN1:UTF8String:operator\n").unwrap();
    openssl(&["ecparam", "-name", "prime256v1", "-genkey", "-noout", "-out", "leaf.key"]);
    openssl(&["req", "-new", "-key", "leaf.key", "-subj", "/CN=leaf", "-out", "leaf.csr"]);
    openssl(&[
        "x509",
        "-req",
        "-in",
        "leaf.csr",
        "-CA",
        &issuer,
        "-CAkey",
        &issuer_key,
        "-set_serial",
        "99",
        "-days",
        "3650",
        "-extfile",
        "leaf.ext",
        "-out",
        "leaf.pem",
    ]);
    dir
}

#[test]
fn a_client_chain_larger_than_a_record_fails_its_handshake_alone() {
    let _serial = common::init(ARENA_LEN);
    let server = server();
    let (listener, port) = listener();
    let before = tls::arena::usage().used;
    // About 24 KiB of intermediates: more than the 16 KiB a record holds.
    let dir = long_chain(24);
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let args = ["-tls1_3", "-cert", &path("leaf.pem"), "-key", &path("leaf.key"), "-cert_chain", &path("chain.pem")];
    let mut client = s_client(port, &args);
    let (socket, _) = listener.accept().unwrap();
    let mut session = Session::new(&server, Blocking(socket)).unwrap();
    let result = embassy_futures::block_on(session.handshake());
    assert!(result.is_err(), "a chain larger than a record is refused");
    drop(session);
    let _ = client.kill();
    let _ = client.wait();
    assert_eq!(tls::arena::usage().used, before, "nothing left behind");

    // The next client, with its usual certificate, is served.
    let operator = ["-tls1_3", "-cert", "operator.pem", "-key", "operator.key"];
    let mut client = s_client(port, &operator);
    let (socket, _) = listener.accept().unwrap();
    let mut session = Session::new(&server, Blocking(socket)).unwrap();
    embassy_futures::block_on(session.handshake()).unwrap();
    drop(session);
    drop(client.stdin.take());
    let _ = client.wait();
}
