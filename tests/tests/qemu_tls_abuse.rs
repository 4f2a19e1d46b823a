//! Abuse of port 802 on the mps2-an386 image in QEMU while plain Modbus is
//! polled on 502 (system_tests::tls_abuse): half-open and stalled
//! handshakes, handshakes sent a byte at a time, 100 handshakes a second,
//! garbage. This single-core M4 image runs a handshake's crypto on the one
//! executor that also serves 502, so this is where a handshake could hold
//! Modbus up; QEMU runs it at about the NUCLEO's speed ([`BOARD_SPEED`]),
//! not as fast as the host can, which would hide most of that. Every request on 502 is answered on the one connection within
//! 2 s, the firmware does not restart (its uptime grows, it boots once,
//! QEMU runs on, nothing in its log is an error), the TLS counters move,
//! and an operator still gets a session on 802 afterwards.
//!
//! Needs root, QEMU, python3 with pymodbus and openssl; fails loudly
//! without them.

use std::process::Stdio;
use std::time::{Duration, Instant};

use system_tests::OWNER_PASSWORD;
use system_tests::netns::DEVICE_IP;
use system_tests::qemu::{self, Qemu};
use system_tests::tls::{device_certificate, fixture, pymodbus, require_tools};
use system_tests::tls_abuse::{self, LIMIT, abuse_802, assert_counters_moved, assert_not_restarted};
use system_tests::update::test_dir;

/// QEMU at about the NUCLEO's speed rather than as fast as the host can:
/// one instruction every 2^3 ns of guest time (125 million a second), and
/// guest time kept to real time (`align`).
const BOARD_SPEED: [&str; 2] = ["-icount", "shift=3,align=on,sleep=on"];

/// A PUT through curl in the namespace: the status.
fn put(qemu: &Qemu, path: &str, body: &str, credentials: Option<&str>) -> u16 {
    let mut command = qemu.ns().unwrap().command("curl");
    command.args(["-sS", "-m", "10", "-o", "/dev/null", "-w", "%{http_code}", "-X", "PUT"]);
    command.args(["-H", "Content-Type: application/json", "--data-binary", body]);
    if let Some(credentials) = credentials {
        command.args(["-u", credentials]);
    }
    let output = command.arg(format!("http://{DEVICE_IP}{path}")).stdin(Stdio::null()).output().expect("curl runs");
    String::from_utf8_lossy(&output.stdout).trim().parse().unwrap_or(0)
}

#[test]
fn abuse_on_802_never_delays_502_beyond_2_s_nor_restarts_the_m4() {
    require_tools();
    let dir = test_dir("qemu-tls-abuse");
    let state = dir.join("psram.state");
    qemu::erased_state(&state).unwrap();
    let ready = format!("Modbus TCP server at {DEVICE_IP}:502");

    // First boot: the plant's CA installed through the API.
    let qemu = Qemu::tap_with_state(&state);
    qemu.wait_for_log(&ready, Duration::from_secs(60));
    let password = format!(r#"{{"password": "{OWNER_PASSWORD}"}}"#);
    assert_eq!(put(&qemu, "/api/password", &password, None), 200);
    let ca = std::fs::read_to_string(fixture("client-ca.pem")).unwrap();
    let body = serde_json::json!({ "certificate": ca }).to_string();
    let credentials = format!("admin:{OWNER_PASSWORD}");
    assert_eq!(put(&qemu, "/api/tls/client-ca", &body, Some(&credentials)), 200);
    qemu.finish();

    // Second boot: 802 serves the plant's clients; the abuse.
    let qemu = Qemu::tap_with_state_and_args(&state, &BOARD_SPEED);
    qemu.wait_for_log(&ready, Duration::from_secs(60));
    let ns = qemu.ns().unwrap();
    let before = tls_abuse::status(ns);
    let looked = Instant::now();

    let summary = abuse_802(ns, qemu.addr(), 2);
    summary.print();
    summary.watch.assert_within(LIMIT);
    summary.assert_device_coped();

    // The firmware ran on: QEMU did not exit, the uptime grew, one boot.
    assert!(qemu.exit_status().is_none(), "QEMU exited: {:?}\n{}", qemu.exit_status(), qemu.log());
    let after = tls_abuse::status(ns);
    assert_not_restarted(&before, &after, looked.elapsed());
    let log = qemu.log();
    assert_eq!(log.matches("on mps2-an386").count(), 1, "the firmware started again:\n{log}");

    // An operator still gets a session on 802, and the counters moved.
    let server_cert = device_certificate(ns, &dir, 802);
    let operator = pymodbus(ns, Some(("operator.pem", "operator.key")), &server_cert);
    assert_eq!(operator["write"], "ok", "an operator after the abuse: {operator}");
    let after = tls_abuse::status(ns);
    assert_counters_moved(&before, &after);
    qemu.finish();
    std::fs::remove_dir_all(&dir).unwrap();
}
