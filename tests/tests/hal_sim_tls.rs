//! Modbus/TCP Security on hal-sim (port 802), through independent clients:
//! pymodbus's `ModbusTlsClient` (tests/peers/pymodbus_tls.py) with a client
//! certificate of each kind, and `openssl s_client`. The certificates are
//! the tls crate's test fixtures: a plant CA (`--client-ca`), an operator's
//! and a viewer's certificate, one without a role, and one from another CA.
//!
//! Needs root (a namespace), python3 with pymodbus, and openssl; fails
//! loudly without them.

use std::process::Stdio;

use system_tests::hal_sim::HalSim;
use system_tests::netns::DEVICE_IP;
use system_tests::tls::{device_certificate, fixture, fixtures, pymodbus, require_tools};
use system_tests::update::test_dir;
use tokio_modbus::prelude::*;

#[test]
fn roles_give_rights_on_802_and_other_clients_get_no_session() {
    require_tools();
    let sim = HalSim::start(&["--robot", "idle", "--client-ca", &fixture("client-ca.pem")]);
    let dir = test_dir("hal-sim-tls");
    let server_cert = device_certificate(sim.ns(), &dir, 802);

    // An operator reads and writes, over a verified server certificate.
    let operator = pymodbus(sim.ns(), Some(("operator.pem", "operator.key")), &server_cert);
    assert_eq!(operator["connected"], true, "{operator}");
    assert_eq!(operator["read"].as_array().map(Vec::len), Some(4), "{operator}");
    assert_eq!(operator["write"], "ok", "{operator}");

    // A viewer reads; its write gets exception 01 (Illegal Function).
    let viewer = pymodbus(sim.ns(), Some(("viewer.pem", "viewer.key")), &server_cert);
    assert_eq!(viewer["read"].as_array().map(Vec::len), Some(4), "{viewer}");
    assert_eq!(viewer["write"], serde_json::json!({"exception": 1}), "{viewer}");

    // No role, another CA's certificate, no certificate: no session, no answer.
    for (client, what) in [
        (Some(("norole.pem", "norole.key")), "no role"),
        (Some(("stranger.pem", "stranger.key")), "another CA"),
        (None, "no certificate"),
    ] {
        let refused = pymodbus(sim.ns(), client, &server_cert);
        assert!(!refused["read"].is_array(), "{what}: {refused}");
        assert_ne!(refused["write"], "ok", "{what}: {refused}");
    }

    // The counters saw it: the operator's and the viewer's sessions (and
    // the handshake that fetched the certificate), the three refused.
    let status = sim.get("/api/status").json();
    let counters = &status["counters"];
    assert_eq!(counters["tls_sessions"], 3, "{counters}");
    assert_eq!(counters["tls_refused"], 3, "{counters}");
    assert_eq!(counters["refused_writes"], 1, "the viewer's write: {counters}");

    // Plain Modbus on 502 is served beside it (tls.plain_modbus on).
    let coils = sim.run(|| async {
        let mut ctx = sim.connect().await;
        ctx.read_coils(16, 4).await.unwrap().unwrap()
    });
    assert_eq!(coils.len(), 4);
}

#[test]
fn without_a_client_ca_port_802_stays_closed() {
    require_tools();
    let sim = HalSim::start(&["--robot", "idle"]);
    let output = sim
        .ns()
        .command("openssl")
        .args(["s_client", "-connect", &format!("{DEVICE_IP}:802")])
        .args(["-cert", &fixture("operator.pem"), "-key", &fixture("operator.key")])
        .stdin(Stdio::null())
        .output()
        .expect("openssl runs");
    assert!(!output.status.success(), "a handshake on 802 without a client CA");
    assert!(String::from_utf8_lossy(&output.stderr).contains("onnection refused"), "{output:?}");
    assert!(sim.log().contains("no client CA"), "{}", sim.log());
}

/// The client CA installed through the API (and removed), kept in the
/// store across a restart; the device's certificate and key kept too.
#[test]
fn a_client_ca_installed_through_the_api_opens_802_after_a_restart() {
    require_tools();
    let dir = test_dir("hal-sim-tls-api");
    let state = dir.join("hal-sim.state");
    let _ = std::fs::remove_file(&state);
    let mut sim = HalSim::start_with(Some(&state), 80, &["--robot", "idle"]);
    let password = sim.claim();

    // A new device: its own self-signed certificate, no client CA.
    let tls = sim.get("/api/tls").json();
    let device = &tls["device"];
    assert_eq!(device["origin"], "self-signed", "{tls}");
    assert_eq!(device["subject"], "mbio-53494d", "{tls}");
    assert_eq!(device["ip"], serde_json::json!([DEVICE_IP]), "{tls}");
    assert!(tls["client_ca"].is_null(), "{tls}");
    let fingerprint = device["sha256"].as_str().unwrap().to_owned();
    assert_eq!(fingerprint.len(), 64, "{tls}");
    assert!(!tls.to_string().to_lowercase().contains("private"), "no key shown: {tls}");

    // Refused whole: not a CA, another curve's CA, garbage, no password.
    let pem = |name: &str| std::fs::read_to_string(fixtures().join(name)).unwrap();
    let body = |pem: &str| serde_json::json!({ "certificate": pem }).to_string();
    for (certificate, why) in [
        (pem("operator.pem"), "not a CA"),
        ("-----BEGIN CERTIFICATE-----\nAAAA\n-----END CERTIFICATE-----\n".to_owned(), "garbage"),
    ] {
        let reply = sim.put("/api/tls/client-ca", &body(&certificate), Some(password));
        assert_eq!(reply.status, 400, "{why}: {}", reply.body);
        assert!(reply.json()["errors"]["certificate"].is_string(), "{why}: {}", reply.body);
    }
    let unauthenticated = sim.put("/api/tls/client-ca", &body(&pem("client-ca.pem")), None);
    assert_eq!(unauthenticated.status, 401, "{}", unauthenticated.body);
    assert!(sim.get("/api/tls").json()["client_ca"].is_null(), "nothing saved");

    // Installed: shown at once, in force after a restart.
    let reply = sim.put("/api/tls/client-ca", &body(&pem("client-ca.pem")), Some(password));
    assert_eq!(reply.status, 200, "{}", reply.body);
    assert_eq!(reply.json()["client_ca"]["subject"], "Plant CA", "{}", reply.body);
    sim.restart();
    let tls = sim.get("/api/tls").json();
    assert_eq!(tls["device"]["sha256"], fingerprint.as_str(), "the same certificate after a restart: {tls}");
    let server_cert = device_certificate(sim.ns(), &dir, 802);
    let operator = pymodbus(sim.ns(), Some(("operator.pem", "operator.key")), &server_cert);
    assert_eq!(operator["write"], "ok", "{operator}");

    // Removed: 802 closed again after a restart.
    let reply = sim.http(
        "/api/tls/client-ca",
        &["-X", "DELETE", "-H", "Content-Type: application/json", "-u", &format!("admin:{password}")],
    );
    assert_eq!(reply.status, 200, "{}", reply.body);
    assert!(reply.json()["client_ca"].is_null(), "{}", reply.body);
    sim.restart();
    let operator = pymodbus(sim.ns(), Some(("operator.pem", "operator.key")), &server_cert);
    assert!(!operator["read"].is_array(), "802 serves no one without a CA: {operator}");
}
