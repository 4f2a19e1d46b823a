//! testssl.sh against hal-sim's port 802 (Modbus/TCP Security) and 443
//! (HTTPS), inside the test's namespace (system_tests::testssl): with a
//! certificate the plant's CA signed, no finding of severity HIGH or
//! CRITICAL at all, on both ports; with the device's own self-signed one,
//! none but the two its design makes (listed below, each with why). TLS
//! 1.2 and 1.3 offered and nothing older, the two suites.
//!
//! testssl 3.0.8 presents no client certificate, so it sees 802 as any
//! client without one: a handshake up to the server's certificate request.
//! That covers the protocols, the ciphers, the key exchange, the
//! certificate and the vulnerability checks done on the handshake's first
//! flight; what needs a finished handshake it cannot check (docs/tls.md,
//! "Tests").
//!
//! Needs root (a namespace), testssl, python3 with pymodbus and openssl;
//! fails loudly without them.

use system_tests::hal_sim::HalSim;
use system_tests::netns::DEVICE_IP;
use system_tests::testssl::{self, Accepted, Report};
use system_tests::tls::{device_certificate, fixture, plant_certificates, require_tools};
use system_tests::update::test_dir;

/// The HIGH and CRITICAL findings the device's design makes.
const ACCEPTED: &[Accepted] = &[
    Accepted {
        id: "cert_validityPeriod",
        finding: "",
        why: "the device has no clock: its self-signed certificate runs to 9999-12-31 23:59:59, RFC 5280's \
              \"no well-defined expiration date\" (checked below), since it can neither check dates nor renew \
              on a schedule; testssl's limit (10 years) is for certificates a public CA issues",
    },
    Accepted {
        id: "cert_revocation",
        finding: "Neither CRL nor OCSP URI provided",
        why: "the certificate is self-signed and trusted by pinning it (no CA stands behind it that could \
              revoke it), and the device's network has no CRL or OCSP server: a plant retires it by \
              removing the pin",
    },
];

/// What testssl must see on either port whatever the certificate: TLS 1.2
/// and 1.3 and nothing older, the two suites, the certificate trusted.
fn check_protocols(report: &Report) {
    let finding = |id: &str| report.get(id).map(|f| f.finding.as_str()).unwrap_or_else(|| panic!("no {id} finding"));
    for id in ["SSLv2", "SSLv3", "TLS1", "TLS1_1"] {
        assert_eq!(finding(id), "not offered", "{id}");
    }
    assert_eq!(finding("TLS1_2"), "offered");
    assert_eq!(finding("TLS1_3"), "offered with final");
    let suites: Vec<&str> =
        report.findings.iter().filter(|f| f.id.starts_with("cipher_x")).map(|f| f.id.as_str()).collect();
    assert_eq!(suites, ["cipher_x1301", "cipher_xc02b"], "TLS_AES_128_GCM_SHA256, ECDHE-ECDSA-AES128-GCM-SHA256");
    assert_eq!(finding("cert_chain_of_trust"), "passed.");
}

#[test]
fn testssl_finds_nothing_high_or_critical_with_the_plants_certificate_on_802_and_443() {
    require_tools();
    testssl::require();
    let dir = test_dir("hal-sim-testssl-plant");
    plant_certificates(&dir);
    let state = dir.join("state.bin");
    let mut sim = HalSim::start_with(Some(&state), 80, &["--robot", "idle", "--client-ca", &fixture("client-ca.pem")]);
    let read = |name: &str| std::fs::read_to_string(dir.join(name)).unwrap();
    let body = serde_json::json!({"certificate": read("device.pem"), "key": read("device.p8")}).to_string();
    let password = sim.claim();
    let installed = sim.put("/api/tls/certificate", &body, Some(password));
    assert_eq!(installed.status, 200, "{}", installed.body);
    sim.restart();
    let ca = dir.join("ca.pem");
    for port in [802, 443] {
        let report = testssl::run(sim.ns(), &format!("{DEVICE_IP}:{port}"), &["--add-ca", ca.to_str().unwrap()], &dir);
        eprintln!("{}", report.output);
        report.assert_no_high_or_critical(&[]);
        check_protocols(&report);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn testssl_finds_only_what_the_missing_clock_makes_with_the_devices_own_certificate() {
    require_tools();
    testssl::require();
    let sim = HalSim::start(&["--robot", "idle", "--client-ca", &fixture("client-ca.pem")]);
    let dir = test_dir("hal-sim-testssl");
    // The device's own certificate, as its operators trust it (pinned).
    let device = device_certificate(sim.ns(), &dir, 802);
    let device = device.to_str().unwrap();
    let report = testssl::run(sim.ns(), &format!("{DEVICE_IP}:802"), &["--add-ca", device], &dir);
    eprintln!("{}", report.output);
    report.assert_no_high_or_critical(ACCEPTED);
    check_protocols(&report);
    let not_after = report.get("cert_notAfter").map(|f| f.finding.as_str());
    assert_eq!(not_after, Some("9999-12-31 23:59"), "the no-expiry date the first accepted finding is about");
    std::fs::remove_dir_all(&dir).unwrap();
}
