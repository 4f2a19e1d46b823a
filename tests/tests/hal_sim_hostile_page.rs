//! A page of another site in the operator's browser (docs/http-api.md,
//! "What a page of another site cannot do"): Debian's chromium, driven by
//! playwright-core (tests/browser/hostile.js) inside hal-sim's network
//! namespace, opens a page that the script serves from another address of
//! that namespace ([`PAGE_IP`]) while the device is at 198.18.0.2. As soon
//! as it loads, the page's script (tests/browser/hostile.html) tries what
//! cross-site attacks do: "simple" POSTs (no-cors fetches, text/plain and
//! form bodies, the text/plain JSON CSRF), JSON and PUTs that need a CORS
//! preflight, GETs from images, reads of the API and a frame of the page,
//! and a new device's first password; it reports back to its own site what
//! the browser let it see.
//!
//! The test checks that report (every attempt ran, and none gave the page
//! anything to read), the browser's record of what it sent the device and
//! what the device answered (every change that reached it refused), and
//! then the device itself, through the control socket and the API: no
//! locate, the same settings and stored records, no reboot, the same
//! password state, on a device with a password and on a new one.
//!
//! Needs root (a namespace), node, chromium and `npm ci` in tests/browser
//! (scripts/setup installs them); fails loudly without any of them.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use system_tests::browser::{BROWSER_TIMEOUT, browser_dir, require_browser, run_within, summary};
use system_tests::hal_sim::{HalSim, Reply};
use system_tests::netns::{DEVICE_IP, TAP};

/// The other site: a second address on the namespace's side of the TAP,
/// where hostile.js serves the page (port 8000).
const PAGE_IP: &str = "198.18.0.3";

/// An input set on the control socket before the page runs: hal-sim
/// reboots by executing itself again, with every input off, so a reboot
/// shows as this input gone (`get di`: bit 4 of the 16).
const MARKER: (&str, &str) = ("set di 5 1", "16");

/// What the page may see of an attempt.
#[derive(Debug, Clone, Copy)]
enum Seen {
    /// An opaque response: status 0 and no body (a no-cors fetch, sent).
    Opaque,
    /// An error and nothing else: CORS withheld the answer, or the browser
    /// refused to send it at all.
    Error,
    /// A form posted into a frame whose content the page cannot read.
    Submitted,
    /// The device's page framed, which the page cannot read either.
    Framed,
}

/// hostile.html's attempts, in its order, and what the page may see of each.
const ATTEMPTS: &[(&str, Seen)] = &[
    ("locate-no-cors", Seen::Opaque),
    ("locate-no-cors-text", Seen::Opaque),
    ("locate-no-cors-json", Seen::Opaque),
    ("reboot-no-cors-text", Seen::Opaque),
    ("factory-reset-no-cors", Seen::Opaque),
    ("locate-cors-json", Seen::Error),
    ("settings-cors-json", Seen::Error),
    ("password-cors-text", Seen::Error),
    // A PUT in no-cors mode: the browser refuses it before sending.
    ("password-no-cors-put", Seen::Error),
    ("password-no-cors-post", Seen::Opaque),
    ("settings-form", Seen::Submitted),
    ("password-form", Seen::Submitted),
    ("reboot-form", Seen::Submitted),
    ("factory-reset-form", Seen::Submitted),
    ("locate-form", Seen::Submitted),
    ("locate-img", Seen::Error),
    ("reboot-img", Seen::Error),
    ("status-cors", Seen::Error),
    ("settings-read-cors", Seen::Error),
    ("status-no-cors", Seen::Opaque),
    ("page-frame", Seen::Framed),
];

/// The changes the browser sends without asking (method, path, what sent
/// it), in the order the page makes them: each must reach the device and be
/// refused by its Origin rule (403).
const SENT_AND_REFUSED: &[(&str, &str, &str)] = &[
    ("POST", "/api/locate", "fetch"),
    ("POST", "/api/locate", "fetch"),
    ("POST", "/api/locate", "fetch"),
    ("POST", "/api/reboot", "fetch"),
    ("POST", "/api/factory-reset", "fetch"),
    ("POST", "/api/password", "fetch"),
    ("POST", "/api/settings", "document"),
    ("POST", "/api/password", "document"),
    ("POST", "/api/reboot", "document"),
    ("POST", "/api/factory-reset", "document"),
    ("POST", "/api/locate", "document"),
];

/// The changes the browser asks the device about first (path, method asked):
/// each preflight is refused, so the change itself is never sent.
const PREFLIGHTED: &[(&str, &str)] = &[("/api/locate", "POST"), ("/api/settings", "PUT"), ("/api/password", "PUT")];

fn ok(reply: Reply) -> Value {
    assert_eq!(reply.status, 200, "{}", reply.body);
    reply.json()
}

/// The longest the namespace's addresses may take to settle.
const SETTLE_LIMIT: Duration = Duration::from_secs(5);

/// Waits until no address of the namespace is tentative. The TAP's IPv6
/// link-local address is, for about a second after hal-sim opens the TAP
/// (duplicate address detection); chromium takes the end of that for a
/// change of network and aborts what it has in flight
/// (`net::ERR_NETWORK_CHANGED`): an attempt that never reaches the device.
fn wait_for_addresses(sim: &HalSim) {
    let deadline = Instant::now() + SETTLE_LIMIT;
    loop {
        let output = Command::new("ip").args(["-n", sim.ns().name(), "addr", "show"]).output().expect("ip runs");
        let addresses = String::from_utf8_lossy(&output.stdout);
        if output.status.success() && !addresses.contains("tentative") {
            return;
        }
        assert!(Instant::now() < deadline, "addresses still tentative after {SETTLE_LIMIT:?}:\n{addresses}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// What a page must not change, as the test reads it from outside the browser.
#[derive(Debug, PartialEq)]
struct Device {
    settings: Value,
    /// `storage` of the status: whether it works, its records and erases.
    storage: Value,
    /// `admin` of the status: whether a password is set, and the first password's window.
    admin: Value,
    /// The control socket's `get locate`.
    locate: String,
    /// The control socket's `get di`: [`MARKER`] still set.
    inputs: String,
    pid: u32,
}

/// The device now, and its uptime in seconds.
fn device(sim: &HalSim) -> (Device, u64) {
    let status = ok(sim.get("/api/status"));
    let device = Device {
        settings: ok(sim.get("/api/settings")),
        storage: status["storage"].clone(),
        admin: status["admin"].clone(),
        locate: sim.control_ok("get locate"),
        inputs: sim.control_ok("get di"),
        pid: sim.pid(),
    };
    (device, status["device"]["uptime_s"].as_u64().expect("uptime_s"))
}

/// Serves the page from [`PAGE_IP`], opens it in chromium and waits for its
/// report; checks the report, the browser's record of what reached the
/// device, and that the device is as before. Returns the device as it was.
fn open_hostile_page(sim: &HalSim) -> Device {
    sim.ns().ip(&["addr", "add", &format!("{PAGE_IP}/24"), "dev", TAP]).expect("a second address on the TAP");
    wait_for_addresses(sim);
    sim.control_ok(MARKER.0);
    let (before, uptime_before) = device(sim);
    assert_eq!((before.locate.as_str(), before.inputs.as_str()), ("0", MARKER.1), "{before:?}");
    let started = Instant::now();

    let mut node = sim.ns().command("node");
    node.current_dir(browser_dir())
        .arg("hostile.js")
        .arg(format!("http://{DEVICE_IP}/"))
        .arg(PAGE_IP)
        .stdin(Stdio::null());
    let (passed, stdout, stderr) = run_within(node, BROWSER_TIMEOUT);
    assert!(passed, "the hostile page did not run to its report:\n{stderr}\n{stdout}");
    let summary = summary(&stdout);
    check_report(&summary);
    check_sent(&summary);

    let elapsed = started.elapsed();
    let (after, uptime_after) = device(sim);
    assert_eq!(after, before, "the page changed the device");
    // No reboot: the uptime went on (whole seconds, so within one second).
    assert!(
        uptime_after as f64 > uptime_before as f64 + elapsed.as_secs_f64() - 1.0,
        "uptime {uptime_before} s, then {uptime_after} s {elapsed:?} later: a reboot"
    );
    println!("the page's attempts took {elapsed:?}");
    before
}

/// The page's own report: it ran every attempt, and none gave it anything.
fn check_report(summary: &Value) {
    let page = &summary["page"];
    assert_eq!(page["failure"], Value::Null, "the page's script failed");
    assert_eq!(page["device"], format!("http://{DEVICE_IP}"));
    assert_eq!(summary["shown_equal"], true, "the page wrote the report it posted into its document");
    assert_eq!(summary["page_errors"], json!([]));
    let attempts = page["attempts"].as_array().expect("the page's attempts");
    let names: Vec<&str> = attempts.iter().map(|a| a["name"].as_str().expect("a name")).collect();
    let expected: Vec<&str> = ATTEMPTS.iter().map(|(name, _)| *name).collect();
    assert_eq!(names, expected, "the page made every attempt, in order");
    for (attempt, (name, seen)) in attempts.iter().zip(ATTEMPTS) {
        let as_expected = match seen {
            Seen::Opaque => {
                attempt["outcome"] == "response"
                    && attempt["type"] == "opaque"
                    && attempt["status"] == 0
                    && attempt["body"] == ""
            }
            Seen::Error => attempt["outcome"] == "error",
            Seen::Submitted => attempt["outcome"] == "submitted" && attempt["read"].is_null(),
            Seen::Framed => attempt["outcome"] == "loaded" && attempt["read"].is_null(),
        };
        assert!(as_expected, "{name}: expected {seen:?}, the page saw {attempt}");
    }
}

/// `value[key]` as text ("" when it is not).
fn text<'v>(value: &'v Value, key: &str) -> &'v str {
    value[key].as_str().unwrap_or_default()
}

/// What the browser sent the device and what came back: every change that
/// went out refused, and the rest never sent.
fn check_sent(summary: &Value) {
    let sent = summary["sent"].as_array().expect("the browser's requests to the device");
    let answered: Vec<(&str, &str, &str, u64)> = sent
        .iter()
        .filter(|r| r["method"] != "GET" && !r["status"].is_null())
        .map(|r| (text(r, "method"), text(r, "path"), text(r, "resource"), r["status"].as_u64().unwrap_or_default()))
        .collect();
    let expected: Vec<_> =
        SENT_AND_REFUSED.iter().map(|&(method, path, resource)| (method, path, resource, 403)).collect();
    assert_eq!(answered, expected, "every change the browser sent reached the device and was refused: {sent:?}");

    let preflights = summary["preflights"].as_array().expect("the CORS preflights");
    let asked: Vec<(&str, &str, u64)> = preflights
        .iter()
        .map(|p| (text(p, "path"), text(p, "asks"), p["status"].as_u64().unwrap_or_default()))
        .collect();
    let expected: Vec<_> = PREFLIGHTED.iter().map(|&(path, method)| (path, method, 403)).collect();
    assert_eq!(asked, expected, "each preflight refused: {preflights:?}");
    for &(path, method) in PREFLIGHTED {
        let unanswered = sent.iter().any(|r| r["method"] == method && r["path"] == path && r["status"].is_null());
        assert!(unanswered, "{method} {path} answered after its refused preflight: {sent:?}");
    }
}

#[test]
fn a_page_of_another_site_changes_nothing_on_a_device_with_a_password() {
    require_browser();
    let sim = HalSim::start(&["--robot", "idle"]);
    let password = sim.claim();
    let before = open_hostile_page(&sim);
    assert_eq!(before.settings["admin"], json!({"password_set": true}));
    // The owner's password still opens the device: a change with it (of nothing) is taken.
    ok(sim.put("/api/settings", "{}", Some(password)));
    assert_eq!(ok(sim.get("/api/status"))["storage"], before.storage, "and saved nothing");
}

#[test]
fn a_page_of_another_site_cannot_set_a_new_device_s_first_password() {
    require_browser();
    let sim = HalSim::start(&["--robot", "idle"]);
    let before = open_hostile_page(&sim);
    // Still no password, and the first password's window still open: the
    // page was refused, not too late.
    assert_eq!(before.admin, json!({"password_set": false, "first_password_open": true}));
    assert_eq!(before.storage["records"], 2, "nothing saved (but the TLS key and certificate of the start)");
    // Its owner still can set it.
    sim.claim();
}
