//! hal-sim's HTTP API as a user reaches it: curl inside the test's network
//! namespace (docs/http-api.md), with tokio-modbus on the Modbus side; the
//! settings kept in a state file across restarts, reboots and power cuts
//! (SIGKILL at a random moment of a save).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use system_tests::hal_sim::{HalSim, Reply};
use system_tests::{OWNER_AUTHORIZATION, OWNER_PASSWORD as PASSWORD};
use tokio::io::AsyncWriteExt;
use tokio_modbus::prelude::*;

/// A fresh state file path in the temp dir, removed when dropped.
struct StateFile(PathBuf);

impl StateFile {
    fn new(name: &str) -> Self {
        let path = std::env::temp_dir().join(format!("hal-sim-http-{}-{name}.state", std::process::id()));
        let _ = std::fs::remove_file(&path);
        Self(path)
    }
}

impl Drop for StateFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

fn ok(reply: Reply) -> Value {
    assert_eq!(reply.status, 200, "{}", reply.body);
    reply.json()
}

/// What every change sends: the device refuses any other type (docs/http-api.md).
const JSON: &str = "Content-Type: application/json";
#[test]
fn status_and_settings_have_their_shape() {
    let sim = HalSim::start(&["--robot", "idle"]);
    let status = ok(sim.get("/api/status"));
    let device = &status["device"];
    assert_eq!(device["model"], "hal-sim");
    assert_eq!(device["name"], "mbio-53494d");
    assert_eq!(device["mac"], "02:4d:42:53:49:4d");
    assert!(device["uptime_s"].is_u64(), "{status}");
    assert_eq!(status["network"], json!({"mode": "static", "address": "198.18.0.2/24", "gateway": null, "link": true}));
    assert_eq!(status["robot"]["source"], "sim");
    assert!(status["connections"].as_array().is_some_and(Vec::is_empty), "{status}");
    assert!(status["counters"]["requests"].is_u64(), "{status}");
    assert_eq!(status["watchdog"], json!({"timeout_ms": 0, "tripped": false}));
    // The device's TLS key and self-signed certificate, made at its first start (docs/tls.md).
    assert_eq!(status["storage"], json!({"ok": true, "records": 2, "erases": 0}));
    assert_eq!(status["admin"], json!({"password_set": false, "first_password_open": true}));

    let settings = ok(sim.get("/api/settings"));
    let groups: Vec<&str> = settings.as_object().unwrap().keys().map(String::as_str).collect();
    for group in ["device", "network", "modbus", "watchdog", "robot", "admin"] {
        assert!(groups.contains(&group), "{group} in {settings}");
    }
    assert_eq!(settings["network"]["address"], "198.18.0.2/24");
    assert_eq!(settings["modbus"]["port"], 502);
    assert_eq!(settings["modbus"]["unit_id"], "any");
    assert_eq!(settings["modbus"]["allow_write"], "any");
    assert_eq!(settings["admin"], json!({"password_set": false}));
    // Without --state the settings are in memory, and the log says so.
    assert!(sim.log().contains("kept in memory"), "{}", sim.log());

    // The CPU load, measured by hal-sim's executor loop once a whole second has passed.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
    let load = loop {
        let status = ok(sim.get("/api/status"));
        let load = status["device"]["cpu_load_percent"].clone();
        if !load.is_null() || std::time::Instant::now() > deadline {
            break load;
        }
        std::thread::sleep(std::time::Duration::from_millis(200));
    };
    assert!(load.as_u64().is_some_and(|percent| percent <= 100), "cpu_load_percent: {load}");
}

#[test]
fn a_change_applies_at_once_and_a_bad_one_changes_nothing() {
    let sim = HalSim::start(&["--robot", "idle"]);
    let password = Some(sim.claim());
    let changed = ok(sim.put("/api/settings", r#"{"modbus": {"unit_id": 7}}"#, password));
    assert_eq!(changed["modbus"]["unit_id"], "7");
    assert_eq!(changed["reboot_required"], false);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        ctx.set_slave(Slave(9));
        assert_eq!(ctx.read_holding_registers(256, 3).await.unwrap(), Err(ExceptionCode::GatewayTargetDevice));
        ctx.set_slave(Slave(7));
        assert_eq!(ctx.read_holding_registers(256, 3).await.unwrap().unwrap().len(), 3);
    });

    // One bad field refuses the whole change, with a message per field.
    let before = ok(sim.get("/api/settings"));
    let refused =
        sim.put("/api/settings", r#"{"modbus": {"unit_id": 300, "idle_timeout_s": 30, "colour": "red"}}"#, password);
    assert_eq!(refused.status, 400, "{}", refused.body);
    let errors = &refused.json()["errors"];
    assert_eq!(errors["modbus.unit_id"], "any, or 1-247");
    assert_eq!(errors["modbus.colour"], "unknown setting");
    assert!(errors.get("modbus.idle_timeout_s").is_none(), "{errors}");
    assert_eq!(ok(sim.get("/api/settings")), before, "nothing changed");
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        ctx.set_slave(Slave(7));
        assert!(ctx.read_holding_registers(256, 1).await.unwrap().is_ok(), "unit 7 is still the one answered");
    });

    // A network setting waits for a reboot: saved, not in force.
    let changed = ok(sim.put("/api/settings", r#"{"network": {"gateway": "198.18.0.254"}}"#, password));
    assert_eq!(changed["reboot_required"], true);
    assert_eq!(changed["network"]["gateway"], "198.18.0.254");
    assert_eq!(ok(sim.get("/api/status"))["network"]["gateway"], Value::Null);
}

#[test]
fn a_password_and_allow_write_guard_changes() {
    let sim = HalSim::start(&["--robot", "idle"]);
    // A second address on the host side of the TAP, for a second client.
    sim.ns().ip(&["addr", "add", "198.18.0.3/24", "dev", system_tests::netns::TAP]).unwrap();

    let set = ok(sim.put("/api/password", &format!(r#"{{"password": "{PASSWORD}"}}"#), None));
    assert_eq!(set, json!({"admin": {"password_set": true}}));
    assert_eq!(ok(sim.get("/api/settings"))["admin"]["password_set"], true);
    let change = r#"{"modbus": {"idle_timeout_s": 30}}"#;
    assert_eq!(sim.put("/api/settings", change, None).status, 401);
    assert_eq!(sim.put("/api/settings", change, Some("wrong-horse")).status, 401);
    assert_eq!(sim.put("/api/password", r#"{"password": "another-one"}"#, None).status, 401);
    assert_eq!(ok(sim.put("/api/settings", change, Some(PASSWORD)))["modbus"]["idle_timeout_s"], 30);

    // Writes only from 198.18.0.3: 198.18.0.1 (which set it) is out, with the password or not.
    let only_3 = r#"{"modbus": {"allow_write": "198.18.0.3/32"}}"#;
    assert_eq!(ok(sim.put("/api/settings", only_3, Some(PASSWORD)))["modbus"]["allow_write"], "198.18.0.3/32");
    let refused = sim.put("/api/settings", r#"{"modbus": {"idle_timeout_s": 40}}"#, Some(PASSWORD));
    assert_eq!(refused.status, 403, "{}", refused.body);
    let from_3 = ["--interface", "198.18.0.3", "-u"];
    let credentials = format!("admin:{PASSWORD}");
    let put = ["-X", "PUT", "-H", JSON, "--data-binary", r#"{"modbus": {"idle_timeout_s": 50}}"#];
    let args: Vec<&str> = from_3.iter().copied().chain([credentials.as_str()]).chain(put).collect();
    assert_eq!(ok(sim.http("/api/settings", &args))["modbus"]["idle_timeout_s"], 50);
    let without_password: Vec<&str> = ["--interface", "198.18.0.3"].into_iter().chain(put).collect();
    assert_eq!(sim.http("/api/settings", &without_password).status, 401);
    // Reading stays open to everyone.
    assert_eq!(ok(sim.get("/api/settings"))["modbus"]["idle_timeout_s"], 50);
}

#[test]
fn settings_and_password_survive_a_restart_and_a_reboot() {
    let state = StateFile::new("restart");
    let mut sim = HalSim::start_with(Some(&state.0), 80, &["--robot", "idle"]);
    ok(sim.put("/api/password", &format!(r#"{{"password": "{PASSWORD}"}}"#), None));
    ok(sim.put("/api/settings", r#"{"device": {"name": "kept"}, "modbus": {"unit_id": 7}}"#, Some(PASSWORD)));
    assert_eq!(std::fs::metadata(&state.0).unwrap().len(), 65536);

    sim.restart();
    let settings = ok(sim.get("/api/settings"));
    assert_eq!(settings["device"]["name"], "kept");
    assert_eq!(settings["modbus"]["unit_id"], "7");
    assert_eq!(settings["admin"]["password_set"], true);
    assert_eq!(ok(sim.get("/api/status"))["storage"]["ok"], true);
    assert_eq!(sim.put("/api/settings", r#"{"modbus": {"port": 1502}}"#, None).status, 401);
    let changed = ok(sim.put("/api/settings", r#"{"modbus": {"port": 1502}}"#, Some(PASSWORD)));
    assert_eq!(changed["reboot_required"], true);

    // A reboot: the same process executes itself again and reads the file.
    let pid = sim.pid();
    let reboot = sim.http("/api/reboot", &["-X", "POST", "-H", JSON, "-u", &format!("admin:{PASSWORD}")]);
    assert_eq!((reboot.status, reboot.json()), (202, json!({"rebooting": true})));
    sim.wait_ready();
    assert!(sim.is_running());
    assert_eq!(sim.pid(), pid);
    assert_eq!(ok(sim.get("/api/settings"))["modbus"]["port"], 1502);
    sim.run(|| async {
        let addr = std::net::SocketAddr::new(sim.addr().ip(), 1502);
        let mut ctx = tokio_modbus::client::tcp::connect_slave(addr, Slave(7)).await.unwrap();
        assert_eq!(ctx.read_holding_registers(256, 3).await.unwrap().unwrap().len(), 3);
        assert!(tokio::net::TcpStream::connect(sim.addr()).await.is_err(), "502 is closed after the reboot");
    });

    // Locate: the control socket sees the LED blink.
    assert_eq!(sim.control("get locate"), "ok 0");
    let locate = sim.http("/api/locate", &["-X", "POST", "-H", JSON, "-u", &format!("admin:{PASSWORD}")]);
    assert_eq!(locate.status, 200, "{}", locate.body);
    assert_eq!(sim.control("get locate"), "ok 1");

    // A factory reset from the control socket: erased, rebooted, factory settings.
    assert_eq!(sim.control("factory-reset"), "ok erasing the settings, then rebooting");
    sim.wait_ready();
    assert_eq!(sim.pid(), pid);
    let settings = ok(sim.get("/api/settings"));
    assert_eq!(settings["device"]["name"], "mbio-53494d");
    assert_eq!(settings["modbus"]["port"], 502);
    assert_eq!(settings["admin"]["password_set"], false);
    let status = ok(sim.get("/api/status"));
    // Erased, then a new TLS key and certificate made at the start after.
    assert_eq!(status["storage"], json!({"ok": true, "records": 2, "erases": 0}));
    assert_eq!(status["admin"], json!({"password_set": false, "first_password_open": true}), "new again");
    assert_eq!(sim.put("/api/settings", r#"{"modbus": {"unit_id": 7}}"#, Some(PASSWORD)).status, 403);
}

/// xorshift64*: enough randomness for the moment of a cut, seeded from the clock.
struct Random(u64);

impl Random {
    fn next(&mut self, below: u64) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) % below
    }
}

/// Saves cut this many times.
const CUTS: u32 = 100;
/// The cut comes this long after curl starts, at most: past the save
/// (curl in the namespace answers in about 10 ms).
const MAX_CUT_DELAY_US: u64 = 25_000;

#[test]
fn a_power_cut_during_a_save_leaves_the_old_or_the_new_settings() {
    let state = StateFile::new("cuts");
    let mut sim = HalSim::start_with(Some(&state.0), 80, &["--robot", "idle"]);
    let credentials = format!("admin:{}", sim.claim());
    let seed = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_nanos() as u64 | 1;
    let mut random = Random(seed);
    // (name, idle timeout) saved together: a mix would pair them wrong.
    let pair = |settings: &Value| {
        (
            settings["device"]["name"].as_str().unwrap().to_owned(),
            settings["modbus"]["idle_timeout_s"].as_u64().unwrap(),
        )
    };
    let mut current = ("mbio-53494d".to_owned(), 60);
    let (mut kept_old, mut took_new, mut acknowledged) = (0, 0, 0);
    let started = Instant::now();
    for n in 1..=CUTS {
        let new = (format!("cut-{n}"), u64::from(n));
        let body = json!({"device": {"name": new.0}, "modbus": {"idle_timeout_s": new.1}}).to_string();
        let mut curl = sim
            .curl("/api/settings")
            .args(["-X", "PUT", "-H", JSON, "-u", &credentials, "--data-binary", &body])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_micros(random.next(MAX_CUT_DELAY_US)));
        sim.kill();
        // The client goes too: a request it would send again would reach the
        // restarted hal-sim behind this test's back. What it has read by
        // now is all hal-sim sent before the cut.
        let _ = curl.kill();
        let reply = Reply::parse(&curl.wait_with_output().unwrap().stdout);
        sim.restart();
        let settings = ok(sim.get("/api/settings"));
        let found = pair(&settings);
        assert!(found == current || found == new, "cut {n} (seed {seed}): {found:?}, not {current:?} or {new:?}");
        if let Some(reply) = &reply {
            assert_eq!(reply.status, 200, "cut {n}: {}", reply.body);
            assert_eq!(found, new, "cut {n} (seed {seed}): the save was acknowledged, then lost");
            acknowledged += 1;
        }
        let status = ok(sim.get("/api/status"));
        // Until a first save has landed, a cut one leaves a torn record on
        // an otherwise erased range, which the store cannot tell from
        // foreign content: factory settings and `ok: false` (the store's
        // own tests allow the same), mended by the next save. After that,
        // every cut leaves the storage ok.
        let factory = ("mbio-53494d".to_owned(), 60);
        if !(current == factory && found == factory) {
            assert_eq!(status["storage"]["ok"], true, "cut {n} (seed {seed}): {status}");
        }
        if found == new {
            took_new += 1
        } else {
            kept_old += 1
        }
        current = found;
    }
    eprintln!(
        "power cuts: {CUTS} in {:?} (seed {seed}): {kept_old} kept the old settings, {took_new} the new \
         ({acknowledged} of them acknowledged before the cut); none mixed, none lost",
        started.elapsed()
    );
    assert_eq!(kept_old + took_new, CUTS);
}

#[test]
fn http_never_delays_modbus() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let http = std::net::SocketAddr::new(sim.addr().ip(), 80);
        // Four clients that start a request and never finish it: two are
        // served (and wait for the rest), the others wait or are refused.
        let mut held = Vec::new();
        let mut refused = Vec::new();
        for _ in 0..4 {
            // Generous: the machine may be busy with the other tests.
            match tokio::time::timeout(Duration::from_secs(3), tokio::net::TcpStream::connect(http)).await {
                Ok(Ok(mut stream)) => {
                    let half =
                        b"PUT /api/settings HTTP/1.1\r\nHost: 198.18.0.2\r\nContent-Length: 40\r\n\r\n{\"modbus\":";
                    stream.write_all(half).await.unwrap();
                    held.push(stream);
                }
                Ok(Err(e)) => refused.push(e.kind().to_string()),
                Err(_) => refused.push("no answer in 3 s".to_owned()),
            }
        }
        assert!(held.len() >= 2, "{} held, refused: {refused:?}", held.len());
        let refused = refused.len();
        let mut ctx = sim.connect().await;
        let started = Instant::now();
        for _ in 0..50 {
            assert_eq!(ctx.read_holding_registers(256, 3).await.unwrap().unwrap().len(), 3);
        }
        let elapsed = started.elapsed();
        assert!(
            elapsed < Duration::from_secs(2),
            "50 reads took {elapsed:?} beside {} held HTTP connections",
            held.len()
        );
        eprintln!("50 Modbus reads in {elapsed:?} beside {} held HTTP connections ({refused} refused)", held.len());
    });
    // The held connections are gone (the runtime closed them): HTTP serves again.
    assert_eq!(ok(sim.get("/api/status"))["device"]["model"], "hal-sim");
}

/// What a web page of another site, or a DNS-rebinding one, would send,
/// over real TCP with curl (docs/http-api.md, "What a page of another site
/// cannot do"): each refused with its status and nothing changed; and the
/// fields every response carries.
#[test]
fn a_hostile_page_s_requests_are_refused_and_change_nothing() {
    let sim = HalSim::start(&["--robot", "idle"]);
    let password = Some(sim.claim());
    let change = r#"{"modbus": {"unit_id": 9}}"#;
    // A "simple" request: no preflight, so refused by its type.
    for (path, kind) in [
        ("/api/locate", "Content-Type: text/plain"),
        ("/api/reboot", "Content-Type: application/x-www-form-urlencoded"),
        ("/api/factory-reset", "Content-Type: text/plain"),
    ] {
        let reply = sim.http(path, &["-X", "POST", "-H", kind]);
        assert_eq!(reply.status, 415, "{path}: {}", reply.body);
    }
    let reply = sim.http("/api/settings", &["-X", "PUT", "-H", "Content-Type: text/plain", "--data-binary", change]);
    assert_eq!(reply.status, 415, "{}", reply.body);
    // curl's -d without a type is a form: refused too.
    assert_eq!(sim.http("/api/settings", &["-X", "PUT", "-d", change]).status, 415);
    // A rebinding page: its own domain name in Host, even to read.
    let reply = sim.http("/api/status", &["-H", "Host: evil.example"]);
    assert_eq!(reply.status, 421, "{}", reply.body);
    assert_eq!(sim.http("/api/settings", &["-H", "Host: evil.example:80"]).status, 421);
    // The device's own names are fine.
    assert_eq!(sim.http("/api/status", &["-H", "Host: mbio-53494d.local"]).status, 200);
    // A page of another site that got its type through: its Origin.
    let foreign = ["-X", "PUT", "-H", JSON, "-H", "Origin: http://evil.example", "--data-binary", change];
    assert_eq!(sim.http("/api/settings", &foreign).status, 403);
    // Two Authorization fields: neither taken.
    let (wrong, right) = ("Authorization: Basic eDp5", OWNER_AUTHORIZATION);
    let twice = ["-X", "PUT", "-H", JSON, "-H", wrong, "-H", right, "--data-binary", change];
    assert_eq!(sim.http("/api/settings", &twice).status, 400);
    // An empty allow-list, an octal-looking address, a password with a NUL.
    for body in [r#"{"modbus": {"allow_write": ""}}"#, r#"{"modbus": {"allow_connect": "198.018.0.0/16"}}"#] {
        assert_eq!(sim.put("/api/settings", body, password).status, 400, "{body}");
    }
    assert_eq!(sim.put("/api/password", r#"{"password": "correct\u0000horse"}"#, password).status, 400);
    // Nothing changed.
    let settings = ok(sim.get("/api/settings"));
    assert_eq!(settings["modbus"]["unit_id"], "any");
    assert_eq!(settings["modbus"]["allow_write"], "any");
    assert_eq!(settings["admin"], json!({"password_set": true}));
    assert_eq!(
        ok(sim.get("/api/status"))["storage"]["records"],
        3,
        "nothing saved but the password (and the TLS key and certificate made at the start)"
    );

    // The fields every response carries, the page's and a refusal's alike.
    for args in [&["-H", "Accept-Encoding: gzip"][..], &["-H", "Host: evil.example"][..]] {
        let output = sim.curl("/").args(["-o", "/dev/null", "-D", "-"]).args(args).output().unwrap();
        let head = String::from_utf8_lossy(&output.stdout).to_lowercase();
        for field in [
            "x-frame-options: deny",
            "x-content-type-options: nosniff",
            "referrer-policy: no-referrer",
            "content-security-policy: default-src 'none'; script-src 'sha256-",
        ] {
            assert!(head.contains(field), "{field} in {head}");
        }
    }
}
