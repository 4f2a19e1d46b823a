//! The server side against an independent client, OpenSSL's `s_client`,
//! over real TCP on 127.0.0.1: TLS 1.2 and 1.3, client certificates that
//! chain to the CA (their role read back from the peer's DER), and those
//! refused: none, or one from another CA. One process, one arena (this
//! file is its own test binary), so the arena's figures are this file's.
//!
//! Needs `openssl` on the PATH (scripts/setup installs it); fails without it.

#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::indexing_slicing,
    clippy::panic,
    reason = "a failed step is a failed test"
)]

mod common;

use std::io::Write as _;
use std::thread;

use common::{Blocking, fixture, listener, s_client};
use embedded_io_async::{Read, Write};
use tls::{Credentials, Server, Session};

/// Large enough for the configuration and a session.
const ARENA_LEN: usize = 96 * 1024;

fn init() -> std::sync::MutexGuard<'static, ()> {
    common::init(ARENA_LEN)
}

struct Outcome {
    /// The handshake's result, the version, the client's role.
    handshake: Result<(), tls::Error>,
    version: &'static str,
    role: Option<String>,
    /// What the client sent, echoed.
    echoed: Vec<u8>,
    /// s_client's output.
    client: String,
}

/// Serves one connection from `s_client` run with `args`; echoes one line.
fn exchange(server: &Server, args: &[&str]) -> Outcome {
    let (listener, port) = listener();
    let mut client = s_client(port, args);
    let mut stdin = client.stdin.take().unwrap();
    let writer = thread::spawn(move || {
        // The line goes once the handshake is done: s_client sends stdin then.
        let _ = stdin.write_all(b"read coils\n");
        thread::sleep(std::time::Duration::from_millis(500));
        drop(stdin);
    });
    let (socket, _) = listener.accept().unwrap();
    socket.set_read_timeout(Some(std::time::Duration::from_secs(10))).unwrap();
    let mut session = Session::new(server, Blocking(socket)).unwrap();
    let handshake = embassy_futures::block_on(session.handshake());
    let mut echoed = Vec::new();
    let (mut version, mut role) = ("none", None);
    if handshake.is_ok() {
        version = session.version();
        role = session.peer_certificate().map(|der| {
            let certificate = certificate::Certificate::parse(der).unwrap();
            certificate.role().unwrap().unwrap_or("(none)").to_string()
        });
        let mut buf = [0u8; 64];
        let n = embassy_futures::block_on(session.read(&mut buf)).unwrap();
        echoed.extend_from_slice(&buf[..n]);
        embassy_futures::block_on(session.write(&buf[..n])).unwrap();
        let _ = embassy_futures::block_on(session.close());
    }
    drop(session);
    writer.join().unwrap();
    let output = client.wait_with_output().unwrap();
    let client = String::from_utf8_lossy(&output.stdout).into_owned() + &String::from_utf8_lossy(&output.stderr);
    Outcome { handshake, version, role, echoed, client }
}

fn modbus_security() -> Server {
    let (certificate, key, ca) = (fixture("device.der"), fixture("device.key.der"), fixture("client-ca.der"));
    Server::new(&Credentials { certificate: &certificate, key: &key, client_ca: Some(&ca) }).unwrap()
}

#[test]
fn an_operator_certificate_completes_tls_1_3_and_its_role_is_read() {
    let _serial = init();
    let server = modbus_security();
    let outcome = exchange(&server, &["-tls1_3", "-cert", "operator.pem", "-key", "operator.key"]);
    assert_eq!(outcome.handshake, Ok(()), "{}", outcome.client);
    assert_eq!(outcome.version, "TLSv1.3");
    assert_eq!(outcome.role.as_deref(), Some("operator"));
    assert_eq!(outcome.echoed, b"read coils\n");
    assert!(outcome.client.contains("read coils"), "the echo came back: {}", outcome.client);
    assert!(outcome.client.contains("Verify return code: 0 (ok)"), "{}", outcome.client);
}

#[test]
fn a_viewer_certificate_completes_tls_1_2() {
    let _serial = init();
    let server = modbus_security();
    let outcome = exchange(&server, &["-tls1_2", "-cert", "viewer.pem", "-key", "viewer.key"]);
    assert_eq!(outcome.handshake, Ok(()), "{}", outcome.client);
    assert_eq!(outcome.version, "TLSv1.2");
    assert_eq!(outcome.role.as_deref(), Some("viewer"));
    assert!(outcome.client.contains("ECDHE-ECDSA-AES128-GCM-SHA256"), "{}", outcome.client);
}

#[test]
fn a_certificate_without_a_role_still_authenticates() {
    let _serial = init();
    let server = modbus_security();
    let outcome = exchange(&server, &["-cert", "norole.pem", "-key", "norole.key"]);
    assert_eq!(outcome.handshake, Ok(()), "{}", outcome.client);
    assert_eq!(outcome.role.as_deref(), Some("(none)"));
}

#[test]
fn no_certificate_or_another_cas_gets_no_session() {
    let _serial = init();
    let server = modbus_security();
    for (args, what) in [
        (&["-tls1_3"][..], "no certificate, 1.3"),
        (&["-tls1_2"][..], "no certificate, 1.2"),
        (&["-cert", "stranger.pem", "-key", "stranger.key"][..], "another CA's"),
    ] {
        let outcome = exchange(&server, args);
        let error = outcome.handshake.expect_err(what);
        assert!(error.is_certificate(), "{what}: {error}");
        assert!(outcome.echoed.is_empty(), "{what}");
    }
}

#[test]
fn without_a_client_ca_no_certificate_is_asked_for() {
    let _serial = init();
    let (certificate, key) = (fixture("device.der"), fixture("device.key.der"));
    let server = Server::new(&Credentials { certificate: &certificate, key: &key, client_ca: None }).unwrap();
    assert!(!server.verifies_clients());
    let outcome = exchange(&server, &[]);
    assert_eq!(outcome.handshake, Ok(()), "{}", outcome.client);
    assert_eq!(outcome.role, None, "no client certificate");
}

#[test]
fn bad_credentials_are_refused_and_leave_the_arena_as_it_was() {
    let _serial = init();
    let before = tls::arena::usage().used;
    let (certificate, key, other) = (fixture("device.der"), fixture("device.key.der"), fixture("client-ca.der"));
    let made = |certificate: &[u8], key: &[u8]| {
        Server::new(&Credentials { certificate, key, client_ca: None }).map(|_| ()).unwrap_err()
    };
    assert_eq!(made(&certificate[..100], &key), tls::Error::BadCertificate);
    assert_eq!(made(&certificate, &key[..40]), tls::Error::BadKey);
    assert_eq!(made(&other, &key), tls::Error::KeyMismatch, "the CA's certificate with the device's key");
    assert_eq!(tls::arena::usage().used, before);
}

#[test]
fn a_generated_key_and_self_signed_certificate_serve_and_name_the_device() {
    let _serial = init();
    let key = tls::identity::generate_key().unwrap();
    assert_ne!(key, tls::identity::generate_key().unwrap(), "two keys, two draws");
    let names = tls::identity::Names { name: "cell-4", address: Some([198, 18, 0, 2]) };
    let mut buf = [0u8; tls::identity::MAX_SELF_SIGNED_LEN];
    let der = tls::identity::self_signed(&key, &names, &[0x01, 0x02], &mut buf).unwrap().to_vec();

    let parsed = certificate::Certificate::parse(&der).unwrap();
    assert_eq!(certificate::common_name(parsed.subject), Some("cell-4"));
    assert_eq!(parsed.subject, parsed.issuer, "self-signed");
    let mut dns: Vec<_> = parsed.dns_names().collect();
    dns.sort_unstable();
    assert_eq!(dns, ["cell-4", "cell-4.local"]);
    assert_eq!(parsed.not_after.to_string(), "9999-12-31T23:59:59Z");

    // openssl reads it, finds the address among its names, and trusts it
    // as its own anchor in a handshake with the device's key.
    let dir = tempfile::tempdir().unwrap();
    let pem = dir.path().join("device.pem");
    let der_path = dir.path().join("device.der");
    std::fs::write(&der_path, &der).unwrap();
    let converted = std::process::Command::new("openssl")
        .args(["x509", "-inform", "der", "-noout", "-text", "-in"])
        .arg(&der_path)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&converted.stdout);
    assert!(text.contains("IP Address:198.18.0.2") && text.contains("DNS:cell-4.local"), "{text}");
    std::process::Command::new("openssl")
        .args(["x509", "-inform", "der", "-in"])
        .arg(&der_path)
        .arg("-out")
        .arg(&pem)
        .status()
        .unwrap();

    let key_der = tls::identity::key_der(&key);
    let server = Server::new(&Credentials { certificate: &der, key: &key_der, client_ca: None }).unwrap();
    let (listener, port) = listener();
    let mut client = std::process::Command::new("openssl")
        .args(["s_client", "-connect", &format!("127.0.0.1:{port}"), "-verify_return_error", "-verify_ip"])
        .arg("198.18.0.2")
        .arg("-CAfile")
        .arg(&pem)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let (socket, _) = listener.accept().unwrap();
    let mut session = Session::new(&server, Blocking(socket)).unwrap();
    embassy_futures::block_on(session.handshake()).unwrap();
    drop(session);
    drop(client.stdin.take());
    let output = client.wait_with_output().unwrap();
    assert!(String::from_utf8_lossy(&output.stdout).contains("Verify return code: 0 (ok)"));
}
