//! HTTPS on hal-sim (port 443): the API with the device's own certificate,
//! through curl (`--cacert`) and python's ssl; connections kept alive and
//! given up to a waiting client; port 80 redirecting once `tls.plain_http`
//! is off. The page in chromium over HTTPS is in hal_sim_page.
//!
//! Needs root (a namespace), curl, python3 and openssl; fails loudly
//! without them.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use system_tests::hal_sim::{HalSim, Reply};
use system_tests::netns::DEVICE_IP;
use system_tests::tls::{device_certificate, fixture, plant_certificates, pymodbus, require_tools};
use system_tests::update::test_dir;

/// curl inside hal-sim's namespace to `https://DEVICE_IP{path}`, trusting
/// `cert`, with `args`: the reply (body, then the status code).
fn https(sim: &HalSim, cert: &Path, path: &str, args: &[&str]) -> Reply {
    let output = curl_https(sim, cert, args).arg(format!("https://{DEVICE_IP}{path}")).output().expect("curl runs");
    Reply::parse(&output.stdout)
        .unwrap_or_else(|| panic!("curl https {path} {args:?} failed: {}", String::from_utf8_lossy(&output.stderr)))
}

fn curl_https(sim: &HalSim, cert: &Path, args: &[&str]) -> Command {
    let mut command = sim.ns().command("curl");
    command.args(["-sS", "-m", "10", "-w", "\n%{http_code}", "--cacert"]).arg(cert).args(args).stdin(Stdio::null());
    command
}

#[test]
fn https_serves_the_api_with_the_device_certificate_on_one_connection() {
    require_tools();
    let sim = HalSim::start(&["--robot", "idle"]);
    let dir = test_dir("hal-sim-https");
    let cert = device_certificate(sim.ns(), &dir, 443);

    // curl trusts the device's certificate for its address: the page and
    // the API are served, with the same security fields as in plain HTTP.
    let status = https(&sim, &cert, "/api/status", &["-D", "-"]);
    assert_eq!(status.status, 200, "{}", status.body);
    let head = status.body.to_ascii_lowercase();
    assert!(head.contains("x-frame-options: deny"), "{head}");
    assert!(!head.contains("connection: close"), "an HTTPS response keeps its connection: {head}");
    let page = https(&sim, &cert, "/", &["--compressed"]);
    assert_eq!(page.status, 200);
    assert!(page.body.starts_with("<!DOCTYPE html>"), "{}", page.body);

    // Without the certificate trusted, curl refuses the device (exit 60).
    let untrusted =
        sim.ns().command("curl").args(["-sS", "-m", "10"]).arg(format!("https://{DEVICE_IP}/api/status")).output();
    assert_eq!(untrusted.expect("curl runs").status.code(), Some(60), "an unknown certificate is not trusted");

    // Three requests in one curl: one connection, one handshake.
    let url = format!("https://{DEVICE_IP}/api/status");
    let output = curl_https(&sim, &cert, &["-w", "%{http_code}/%{num_connects} "])
        .args((0..3).flat_map(|_| ["-o", "/dev/null", &url]))
        .output()
        .expect("curl runs");
    assert_eq!(String::from_utf8_lossy(&output.stdout).trim(), "200/1 200/0 200/0", "{output:?}");

    // A change over HTTPS: the first password, then a setting, with the
    // browser's Origin of the HTTPS page; plain HTTP's Origin is another site.
    let json = ["-H", "Content-Type: application/json", "-X", "PUT"];
    let claimed = https(
        &sim,
        &cert,
        "/api/password",
        &[&json[..], &["--data-binary", r#"{"password":"owner-pass-1"}"#]].concat(),
    );
    assert_eq!(claimed.status, 200, "{}", claimed.body);
    let change = r#"{"modbus":{"unit_id":"9"}}"#;
    let from = |origin: &str| {
        let args = [&json[..], &["-u", "admin:owner-pass-1", "-H", origin, "--data-binary", change]].concat();
        https(&sim, &cert, "/api/settings", &args)
    };
    assert_eq!(from(&format!("Origin: http://{DEVICE_IP}")).status, 403, "plain HTTP's origin is not this one");
    let changed = from(&format!("Origin: https://{DEVICE_IP}"));
    assert_eq!(changed.status, 200, "{}", changed.body);
    assert_eq!(changed.json()["modbus"]["unit_id"], "9");
}

#[test]
fn with_plain_http_off_port_80_only_redirects_to_https() {
    require_tools();
    let sim = HalSim::start(&["--robot", "idle"]);
    let dir = test_dir("hal-sim-https-redirect");
    let cert = device_certificate(sim.ns(), &dir, 443);
    let password = sim.claim();
    assert_eq!(sim.get("/api/settings").json()["tls"]["plain_http"], "on", "plain HTTP is on from the factory");

    let off = sim.put("/api/settings", r#"{"tls":{"plain_http":"off"}}"#, Some(password));
    assert_eq!(off.status, 200, "{}", off.body);
    assert_eq!(off.json()["reboot_required"], false, "it applies at once: {}", off.body);

    // Every request on port 80 is now a 308 to the same path in HTTPS, at
    // the host it named; none is answered in plain.
    for (path, method) in [("/api/status", "GET"), ("/api/settings", "PUT"), ("/", "GET")] {
        let reply = sim.http(path, &["-X", method, "-D", "-", "-o", "/dev/null"]);
        assert_eq!(reply.status, 308, "{method} {path}: {}", reply.body);
        let location = format!("location: https://{DEVICE_IP}{path}\r\n");
        assert!(reply.body.to_ascii_lowercase().contains(&location), "{method} {path}: {}", reply.body);
    }
    let named = sim.http("/api/status", &["-H", "Host: mbio-53494d.local", "-D", "-", "-o", "/dev/null"]);
    assert!(named.body.contains("https://mbio-53494d.local/api/status"), "{}", named.body);
    // A host that is not the device gets no redirect (no open redirect).
    let other = sim.http("/api/status", &["-H", "Host: evil.example"]);
    assert_eq!(other.status, 421, "{}", other.body);

    // curl following the redirect reads the status over HTTPS.
    let followed = curl_https(&sim, &cert, &["-L"]).arg(format!("http://{DEVICE_IP}/api/status")).output().unwrap();
    let followed = Reply::parse(&followed.stdout).expect("a reply");
    assert_eq!(followed.status, 200, "{}", followed.body);
    assert!(followed.json()["device"]["uptime_s"].is_number(), "{}", followed.body);

    // And back: plain HTTP on again, over HTTPS.
    let args = ["-X", "PUT", "-H", "Content-Type: application/json", "-u", &format!("admin:{password}")];
    let on = https(
        &sim,
        &cert,
        "/api/settings",
        &[&args[..], &["--data-binary", r#"{"tls":{"plain_http":"on"}}"#]].concat(),
    );
    assert_eq!(on.status, 200, "{}", on.body);
    assert_eq!(sim.get("/api/status").status, 200, "port 80 serves in plain again");
}

#[test]
fn a_client_waiting_for_the_session_takes_it_from_an_idle_connection() {
    require_tools();
    let sim = HalSim::start(&["--robot", "idle"]);
    let dir = test_dir("hal-sim-https-wait");
    let cert = device_certificate(sim.ns(), &dir, 443);

    // A keeps its connection after one request, as a browser does.
    let holder = hold_https(&sim, &cert);
    std::thread::sleep(Duration::from_millis(1500));

    // B asks while A idles: it is served well before A's idle timeout (5 s).
    let asked = Instant::now();
    let b = https(&sim, &cert, "/api/status", &[]);
    let waited = asked.elapsed();
    assert_eq!(b.status, 200, "{}", b.body);
    assert!(waited < Duration::from_secs(2), "B waited {waited:?}: A did not yield");

    let closed = closed_after(holder);
    assert!(closed < 4.0, "A's idle connection was closed for B, not at its timeout: {closed} s");
}

/// An HTTPS client that sends one request, reads its response, and keeps
/// the connection idle until the device closes it (it prints how long that
/// took: [`closed_after`]).
fn hold_https(sim: &HalSim, cert: &Path) -> std::process::Child {
    let script = format!(
        r#"
import socket, ssl, sys, time
context = ssl.create_default_context(cafile="{cert}")
with socket.create_connection(("{DEVICE_IP}", 443), timeout=30) as raw:
    with context.wrap_socket(raw, server_hostname="{DEVICE_IP}") as tls:
        tls.sendall(b"GET /api/status HTTP/1.1\r\nHost: {DEVICE_IP}\r\n\r\n")
        first = b""
        while b"\r\n\r\n" not in first:
            first += tls.recv(4096)
        head, body = first.split(b"\r\n\r\n", 1)
        length = int([l.split(b":")[1] for l in head.split(b"\r\n") if l.lower().startswith(b"content-length:")][0])
        while len(body) < length:
            body += tls.recv(4096)
        print("first", head.split(b"\r\n")[0].decode(), flush=True)
        start = time.monotonic()
        rest = b""
        while True:
            chunk = tls.recv(4096)
            if not chunk:
                break
            rest += chunk
        print("closed_after_s", round(time.monotonic() - start, 2), len(rest), flush=True)
"#,
        cert = cert.display()
    );
    let mut holder = sim.ns().command("python3");
    holder.args(["-c", &script]).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap()
}

/// How long after its first response [`hold_https`]'s connection was
/// closed by the device, in seconds, once it got no byte more.
fn closed_after(holder: std::process::Child) -> f64 {
    let output = holder.wait_with_output().unwrap();
    let text = String::from_utf8_lossy(&output.stdout);
    assert!(text.contains("first HTTP/1.1 200 OK"), "{text}\n{}", String::from_utf8_lossy(&output.stderr));
    assert!(text.trim_end().ends_with(" 0"), "no bytes after its response: {text}");
    text.lines()
        .find_map(|line| line.strip_prefix("closed_after_s "))
        .and_then(|rest| rest.split(' ').next()?.parse().ok())
        .unwrap_or_else(|| panic!("the held connection closed: {text}"))
}

/// Modbus first: with one session on 802 and HTTPS holding the arena's
/// other seat, a second Modbus/TCP Security client gets a session, and the
/// HTTPS connection is closed for it.
#[test]
fn a_modbus_security_client_takes_the_seat_https_holds() {
    require_tools();
    let sim = HalSim::start(&["--robot", "idle", "--client-ca", &fixture("client-ca.pem")]);
    let dir = test_dir("hal-sim-https-seat");
    let modbus_cert = device_certificate(sim.ns(), &dir, 802);
    let cert = device_certificate(sim.ns(), &dir, 443);
    let sessions = || sim.get("/api/status").json()["counters"]["tls_sessions"].as_u64().unwrap_or(0);
    let before = sessions();

    // Seat one: an operator's session on 802, held open.
    let mut first = sim
        .ns()
        .command("openssl")
        .args(["s_client", "-quiet", "-connect", &format!("{DEVICE_IP}:802")])
        .args(["-cert", &fixture("operator.pem"), "-key", &fixture("operator.key")])
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(10);
    while sessions() == before {
        assert!(Instant::now() < deadline, "the first 802 session opens");
        std::thread::sleep(Duration::from_millis(100));
    }
    // Seat two: an HTTPS connection kept idle.
    let holder = hold_https(&sim, &cert);
    std::thread::sleep(Duration::from_millis(1500));

    // A second operator on 802: served, the HTTPS connection closed for it.
    let second = pymodbus(sim.ns(), Some(("operator.pem", "operator.key")), &modbus_cert);
    assert_eq!(second["read"].as_array().map(Vec::len), Some(4), "{second}");
    assert_eq!(second["write"], "ok", "{second}");
    let closed = closed_after(holder);
    assert!(closed < 4.0, "the HTTPS connection gave its seat up, not at its idle timeout: {closed} s");
    let _ = first.kill();
    let _ = first.wait();
}

#[test]
fn a_plant_installs_its_own_certificate_and_key_for_https() {
    require_tools();
    let dir = test_dir("hal-sim-https-installed");
    plant_certificates(&dir);
    let state = dir.join("state.bin");
    let mut sim = HalSim::start_with(Some(&state), 80, &["--robot", "idle"]);
    let password = sim.claim();
    let read = |name: &str| std::fs::read_to_string(dir.join(name)).unwrap();
    let install = |certificate: &str, key: &str| {
        let body = serde_json::json!({"certificate": certificate, "key": key}).to_string();
        sim.put("/api/tls/certificate", &body, Some(password))
    };

    // Refused whole, each with its reason: another pair's key, no key, a
    // key that is not PEM, no credentials.
    let mismatched = install(&read("device.pem"), &read("other.key"));
    assert_eq!(mismatched.status, 400, "{}", mismatched.body);
    assert_eq!(mismatched.json()["errors"]["key"], "not the certificate's key");
    let missing = sim.put(
        "/api/tls/certificate",
        &serde_json::json!({"certificate": read("device.pem")}).to_string(),
        Some(password),
    );
    assert_eq!(missing.json()["errors"]["key"], "required", "{}", missing.body);
    assert_eq!(install(&read("device.pem"), "not a key").json()["errors"]["key"], "not one PEM key");
    let body = serde_json::json!({"certificate": read("device.pem"), "key": read("device.p8")}).to_string();
    assert_eq!(sim.put("/api/tls/certificate", &body, None).status, 401);
    assert_eq!(sim.get("/api/tls").json()["device"]["origin"], "self-signed", "nothing changed");

    // The plant's pair, its key in PKCS#8: saved, shown without its key,
    // and served after the restart, chaining to the plant's CA.
    let installed = install(&read("device.pem"), &read("device.p8"));
    assert_eq!(installed.status, 200, "{}", installed.body);
    assert_eq!(installed.json()["device"]["origin"], "installed", "{}", installed.body);
    assert_eq!(installed.json()["device"]["issuer"], "Plant CA", "{}", installed.body);
    assert!(!installed.body.contains("PRIVATE"), "never a key: {}", installed.body);
    sim.restart();
    let plant_ca = dir.join("ca.pem");
    let status = https(&sim, &plant_ca, "/api/status", &[]);
    assert_eq!(status.status, 200, "the plant's CA verifies the device: {}", status.body);

    // Removed: the device's own self-signed certificate again.
    let credentials = format!("admin:{password}");
    let removed = https(
        &sim,
        &plant_ca,
        "/api/tls/certificate",
        &["-X", "DELETE", "-u", &credentials, "-H", "Content-Type: application/json"],
    );
    assert_eq!(removed.status, 200, "{}", removed.body);
    sim.restart();
    assert_eq!(sim.get("/api/tls").json()["device"]["origin"], "self-signed");
    let refused = curl_https(&sim, &plant_ca, &[]).arg(format!("https://{DEVICE_IP}/api/status")).output().unwrap();
    assert_eq!(refused.status.code(), Some(60), "the plant's CA no longer verifies the device");
}
