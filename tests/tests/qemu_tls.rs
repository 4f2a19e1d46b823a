//! Modbus/TCP Security on the mps2-an386 image (docs/tls.md), in QEMU on a
//! TAP inside a network namespace: a client CA installed through the API,
//! then after a reboot pymodbus's `ModbusTlsClient` with an operator's
//! certificate reads and writes on port 802, a viewer's write gets
//! exception 01, and a certificate from another CA gets no session; and
//! HTTPS on 443 serves the API to curl trusting the device's certificate,
//! two requests on one connection.
//! Needs root, QEMU, python3 with pymodbus and openssl.

use std::process::Stdio;
use std::time::Duration;

use serde_json::Value;
use system_tests::OWNER_PASSWORD;
use system_tests::netns::DEVICE_IP;
use system_tests::qemu::{self, Qemu};
use system_tests::tls::{device_certificate, fixture, pymodbus, require_tools};
use system_tests::update::test_dir;

/// The most stack the image may use: the NUCLEO's 192 KiB of SRAM, less
/// its static RAM at its ceiling (136 KiB, size-budget.toml), less the 16
/// KiB kept spare. The image runs the same code (the boards' drivers and
/// start-up aside), so its high-water mark in QEMU stands for the NUCLEO's
/// until a board's own log line (`stack: high-water`) gives it.
const STACK_LIMIT: usize = (192 - 136 - 16) * 1024;

/// curl in the namespace: body and status.
fn curl(qemu: &Qemu, args: &[&str]) -> (u16, String) {
    let output = qemu
        .ns()
        .unwrap()
        .command("curl")
        .args(["-sS", "-m", "10", "-w", "\n%{http_code}", "-H", "Content-Type: application/json"])
        .args(args)
        .stdin(Stdio::null())
        .output()
        .expect("curl runs");
    let text = String::from_utf8_lossy(&output.stdout).into_owned();
    let (body, status) = text.rsplit_once('\n').unwrap_or(("", "0"));
    (status.trim().parse().unwrap_or(0), body.to_owned())
}

#[test]
fn an_operator_reads_and_writes_on_802_and_a_viewer_only_reads() {
    require_tools();
    let dir = test_dir("qemu-tls");
    let state = dir.join("psram.state");
    qemu::erased_state(&state).unwrap();
    let url = |path: &str| format!("http://{DEVICE_IP}{path}");
    let credentials = format!("admin:{OWNER_PASSWORD}");

    // First boot: the device makes its key; the plant installs its CA.
    let qemu = Qemu::tap_with_state(&state);
    qemu.wait_for_log(&format!("Modbus TCP server at {DEVICE_IP}:502"), Duration::from_secs(60));
    let (status, body) = curl(
        &qemu,
        &["-X", "PUT", "--data-binary", &format!(r#"{{"password": "{OWNER_PASSWORD}"}}"#), &url("/api/password")],
    );
    assert_eq!(status, 200, "{body}");
    let ca = std::fs::read_to_string(fixture("client-ca.pem")).unwrap();
    let body = serde_json::json!({ "certificate": ca }).to_string();
    let (status, reply) =
        curl(&qemu, &["-X", "PUT", "-u", &credentials, "--data-binary", &body, &url("/api/tls/client-ca")]);
    assert_eq!(status, 200, "{reply}");
    let log = qemu.finish();
    assert!(log.contains("tls: a new device key"), "{log}");

    // Second boot: 802 serves the plant's clients.
    let qemu = Qemu::tap_with_state(&state);
    qemu.wait_for_log(&format!("Modbus TCP server at {DEVICE_IP}:502"), Duration::from_secs(60));
    let server_cert = device_certificate(qemu.ns().unwrap(), &dir, 802);
    let operator = pymodbus(qemu.ns().unwrap(), Some(("operator.pem", "operator.key")), &server_cert);
    assert_eq!(operator["read"].as_array().map(Vec::len), Some(4), "{operator}");
    assert_eq!(operator["write"], "ok", "{operator}");
    let viewer = pymodbus(qemu.ns().unwrap(), Some(("viewer.pem", "viewer.key")), &server_cert);
    assert_eq!(viewer["read"].as_array().map(Vec::len), Some(4), "{viewer}");
    assert_eq!(viewer["write"], serde_json::json!({"exception": 1}), "{viewer}");
    let stranger = pymodbus(qemu.ns().unwrap(), Some(("stranger.pem", "stranger.key")), &server_cert);
    assert!(!stranger["read"].is_array(), "{stranger}");
    // HTTPS, with the same certificate: two requests, one connection.
    let https_cert = device_certificate(qemu.ns().unwrap(), &dir, 443);
    assert_eq!(std::fs::read(&https_cert).unwrap(), std::fs::read(&server_cert).unwrap(), "one certificate");
    let https = format!("https://{DEVICE_IP}/api/status");
    let cacert = https_cert.to_str().unwrap();
    let output = qemu
        .ns()
        .unwrap()
        .command("curl")
        .args(["-sS", "-m", "20", "--cacert", cacert, "-w", "%{http_code}/%{num_connects} "])
        .args(["-o", "/dev/null", &https, "-o", "/dev/null", &https])
        .stdin(Stdio::null())
        .output()
        .expect("curl runs");
    let codes = String::from_utf8_lossy(&output.stdout);
    assert_eq!(codes.trim(), "200/1 200/0", "both answered over HTTPS, on one connection");
    let (_, status) = curl(&qemu, &[&url("/api/status")]);
    let status: Value = serde_json::from_str(&status).unwrap();
    assert!(status["counters"]["tls_sessions"].as_u64().unwrap() >= 3, "{status}");
    assert!(status["counters"]["tls_refused"].as_u64().unwrap() >= 1, "{status}");
    // The stack's high-water mark, start-up and handshakes on 802 (TLS 1.3 and 1.2
    // with client certificates) and on HTTPS: the image reports it within
    // a second of its rising.
    std::thread::sleep(Duration::from_millis(1500));
    let log = qemu.finish();
    assert!(!log.contains("tls: a new device key"), "the key kept across the reboot: {log}");
    let high_water = log
        .lines()
        .filter_map(|line| line.split("stack: high-water ").nth(1)?.split(' ').next()?.parse::<usize>().ok())
        .max()
        .unwrap_or_else(|| panic!("the image reports its stack: {log}"));
    println!("stack high-water, start-up and the handshakes: {high_water} B");
    assert!(high_water <= STACK_LIMIT, "{high_water} B of stack: the NUCLEO would keep less than 16 KiB spare");
    std::fs::remove_dir_all(&dir).unwrap();
}
