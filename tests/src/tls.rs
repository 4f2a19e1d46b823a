//! What the TLS tests share (hal_sim_tls, hal_sim_https, qemu_tls): the
//! tls crate's test certificates, the device's certificate as a handshake
//! shows it, and pymodbus's TLS client (tests/peers/pymodbus_tls.py), all
//! run inside the device's namespace.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use serde_json::Value;

use crate::netns::{DEVICE_IP, Namespace};

/// The tls crate's certificates and keys.
pub fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware/tls/tests/fixtures")
}

/// One of them, as a path for a command line.
pub fn fixture(name: &str) -> String {
    fixtures().join(name).to_str().expect("a UTF-8 path").to_owned()
}

/// Fails loudly unless python3 with pymodbus and openssl are there.
pub fn require_tools() {
    let probe = Command::new("python3").args(["-c", "import pymodbus"]).output();
    assert!(
        probe.as_ref().is_ok_and(|o| o.status.success()),
        "this test needs python3 with pymodbus: `pip install pymodbus` ({probe:?})"
    );
    let openssl = Command::new("openssl").arg("version").output();
    assert!(openssl.is_ok_and(|o| o.status.success()), "this test needs openssl (scripts/setup installs it)");
}

/// The device's certificate, as a handshake on `port` shows it (on 802 an
/// operator's), in a file in `dir` for the clients to trust.
pub fn device_certificate(ns: &Namespace, dir: &Path, port: u16) -> PathBuf {
    let mut openssl = ns.command("openssl");
    openssl.args(["s_client", "-connect", &format!("{DEVICE_IP}:{port}"), "-showcerts"]);
    if port == 802 {
        openssl.args(["-cert", &fixture("operator.pem"), "-key", &fixture("operator.key")]);
    }
    let output = openssl.stdin(Stdio::null()).output().expect("openssl runs");
    let text = String::from_utf8_lossy(&output.stdout);
    let begin = text.find("-----BEGIN CERTIFICATE-----").unwrap_or_else(|| panic!("no certificate shown:\n{text}"));
    let end = text[begin..].find("-----END CERTIFICATE-----").expect("a whole PEM block") + begin + 25;
    let path = dir.join("device.pem");
    std::fs::write(&path, format!("{}\n", &text[begin..end])).unwrap();
    path
}

/// pymodbus's TLS client on 802 with `client`'s certificate and key
/// (`None`: none), trusting `server_cert`: what it read and wrote.
pub fn pymodbus(ns: &Namespace, client: Option<(&str, &str)>, server_cert: &Path) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("peers/pymodbus_tls.py");
    let (cert, key) = client.map_or(("-".to_owned(), "-".to_owned()), |(c, k)| (fixture(c), fixture(k)));
    let output = ns
        .command("python3")
        .arg(&script)
        .args([DEVICE_IP, "802", &cert, &key])
        .arg(server_cert)
        .output()
        .expect("python3 runs");
    let stdout = String::from_utf8_lossy(&output.stdout);
    serde_json::from_str(stdout.trim()).unwrap_or_else(|e| {
        panic!("pymodbus_tls.py printed no JSON ({e}):\n{stdout}\n{}", String::from_utf8_lossy(&output.stderr))
    })
}

/// A plant's CA and a certificate it signed for the device at
/// [`DEVICE_IP`] (P-256; `mbio-53494d.local`; valid for a year; a CRL
/// distribution point on the test network, which nothing fetches), made
/// with openssl in `dir`: ca.pem, device.pem, device.p8 (its key, PKCS#8),
/// other.key (another pair's key, SEC1).
pub fn plant_certificates(dir: &Path) {
    let ext = dir.join("ext.cnf");
    let crl = "crlDistributionPoints=URI:http://198.18.0.1/plant.crl";
    std::fs::write(&ext, format!("subjectAltName=IP:{DEVICE_IP},DNS:mbio-53494d.local\n{crl}\n")).unwrap();
    let steps: [&[&str]; 7] = [
        &["ecparam", "-name", "prime256v1", "-genkey", "-noout", "-out", "ca.key"],
        &["req", "-x509", "-new", "-key", "ca.key", "-subj", "/CN=Plant CA", "-days", "3650", "-out", "ca.pem"],
        &["ecparam", "-name", "prime256v1", "-genkey", "-noout", "-out", "device.key"],
        &["req", "-new", "-key", "device.key", "-subj", "/CN=mbio-53494d", "-out", "device.csr"],
        &[
            "x509",
            "-req",
            "-in",
            "device.csr",
            "-CA",
            "ca.pem",
            "-CAkey",
            "ca.key",
            "-CAcreateserial",
            "-days",
            "365",
            "-extfile",
            "ext.cnf",
            "-out",
            "device.pem",
        ],
        &["pkcs8", "-topk8", "-nocrypt", "-in", "device.key", "-out", "device.p8"],
        &["ecparam", "-name", "prime256v1", "-genkey", "-noout", "-out", "other.key"],
    ];
    for args in steps {
        let status = Command::new("openssl").args(args).current_dir(dir).stderr(Stdio::null()).status();
        assert!(status.is_ok_and(|s| s.success()), "openssl {args:?}");
    }
}
