//! The device's page (`GET /`) as a person sees it: Debian's chromium,
//! driven by playwright-core (tests/browser/page.js), inside hal-sim's
//! network namespace. The script checks each step in the browser and
//! prints what it measured; this test checks that again, and the device
//! behind it through the API, the control socket and curl: the I/O, the
//! robot's telemetry live in its units, the typed settings (a mask's
//! boxes, an allow-list), focus kept across the refresh, and an
//! accessibility audit (axe-core) with no serious or critical violation.
//! It keeps screenshots in target/artifacts/ (page.png, page-error.png with
//! a refused setting, page-narrow.png at a phone's width, and
//! page-failure.png when a step fails) and the audit's findings (axe.json);
//! the run over HTTPS (chromium trusting the device's own certificate)
//! keeps its own in target/artifacts/https/.
//!
//! Needs root (a namespace), node, chromium and `npm ci` in tests/browser
//! (scripts/setup installs them); fails loudly without any of them.

use std::process::Stdio;
use std::time::Duration;

use serde_json::Value;
use system_tests::browser::{BROWSER_TIMEOUT, browser_dir, fresh_artifacts_in, require_browser, run_within, summary};
use system_tests::hal_sim::{HalSim, Reply, read_frame};
use system_tests::netns::DEVICE_IP;
use tokio::io::AsyncWriteExt;
use tokio_modbus::prelude::*;

/// How long a lamp may take to follow an input.
const LAMP_LIMIT_MS: u64 = 1000;
/// The page as served (docs/http-api.md).
const MAX_PAGE_LEN: usize = 24 * 1024;

fn ok(reply: Reply) -> Value {
    assert_eq!(reply.status, 200, "{}", reply.body);
    reply.json()
}

#[test]
fn the_page_shows_the_device_live_and_changes_it_through_the_api() {
    the_page_in_chromium(Transport::Http);
}

/// The same, over HTTPS: chromium trusts the device's own certificate (in
/// its NSS store, as a trusted peer), and the page says it is encrypted.
#[test]
fn the_page_works_over_https_with_the_device_certificate_trusted() {
    the_page_in_chromium(Transport::Https);
}

#[derive(Clone, Copy, PartialEq)]
enum Transport {
    Http,
    Https,
}

/// A home directory whose chromium trusts the device's certificate (NSS's
/// store in `.pki/nssdb`, where chromium on Linux reads it), and the
/// certificate's file (for the script's own requests, through node).
fn trusting_home(sim: &HalSim) -> (std::path::PathBuf, std::path::PathBuf) {
    let dir = system_tests::update::test_dir("hal-sim-page-https");
    let cert = system_tests::tls::device_certificate(sim.ns(), &dir, 443);
    let home = dir.join("home");
    let nssdb = home.join(".pki/nssdb");
    std::fs::create_dir_all(&nssdb).unwrap();
    let db = format!("sql:{}", nssdb.display());
    for args in [
        vec!["-N", "-d", &db, "--empty-password"],
        vec!["-A", "-d", &db, "-n", "device", "-t", "P,,", "-i", cert.to_str().unwrap()],
    ] {
        let status = std::process::Command::new("certutil").args(&args).status();
        assert!(status.is_ok_and(|s| s.success()), "certutil {args:?} (scripts/setup installs libnss3-tools)");
    }
    (home, cert)
}

/// One browser at a time: two would share the machine's two cores, and the
/// lamps' time limit.
static ONE_BROWSER: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn the_page_in_chromium(transport: Transport) {
    let _one = ONE_BROWSER.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    require_browser();
    let sim = HalSim::start(&["--robot", "idle"]);
    // The telemetry the page reads.
    let telemetry = ok(sim.get("/api/telemetry"));
    assert_eq!(telemetry["tool_offset_mm"], serde_json::json!([0.0, 0.0, 120.0]), "hal-sim's 120 mm tool");

    // curl sees what a browser gets, and a client without gzip is told why not.
    let head = sim.http("/", &["-H", "Accept-Encoding: gzip", "-D", "-", "-o", "/dev/null"]);
    assert_eq!(head.status, 200, "{}", head.body);
    let headers = head.body.to_ascii_lowercase();
    assert!(headers.contains("content-type: text/html; charset=utf-8"), "{headers}");
    assert!(headers.contains("content-encoding: gzip"), "{headers}");
    let length: usize = headers
        .lines()
        .find_map(|l| l.strip_prefix("content-length:"))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("a Content-Length: {headers}"));
    assert!(length <= MAX_PAGE_LEN, "{length} bytes served");
    let page = sim.http("/", &["--compressed"]);
    assert_eq!(page.status, 200);
    assert!(page.body.starts_with("<!DOCTYPE html>") && page.body.trim_end().ends_with("</html>"), "{}", page.body);
    let refused = sim.get("/");
    assert_eq!(refused.status, 406, "{}", refused.body);
    assert!(refused.json()["errors"]["request"].as_str().is_some_and(|m| m.contains("curl --compressed")));

    // A Modbus master drives outputs, and stays connected while the page
    // is open (the page lists it).
    let master = sim.run(|| async {
        let mut ctx = sim.connect().await;
        let mut outputs = [false; 16];
        for n in [1, 4, 16] {
            outputs[n - 1] = true;
        }
        ctx.write_multiple_coils(16, &outputs).await.unwrap().unwrap();
        // Tool outputs 1 and 3; AO1 8 mA (current), AO2 5 V (voltage).
        ctx.write_single_register(22, 0b101).await.unwrap().unwrap();
        ctx.write_multiple_registers(16, &[8000, 0, 5000, 1]).await.unwrap().unwrap();
        let mut raw = sim.raw().await;
        // FC 03, one register at 256 (the version), transaction 1, unit 0xFF.
        raw.write_all(&[0, 1, 0, 0, 0, 6, 0xff, 3, 1, 0, 0, 1]).await.unwrap();
        assert!(read_frame(&mut raw, Duration::from_secs(2)).await.is_some(), "a reply to the master");
        raw.into_std().expect("the master's connection, kept open")
    });
    // The firmware version the page must show.
    let [major, minor, patch] = system_tests::hal_sim::firmware_version();
    let version = format!("{major}.{minor}.{patch}");
    let before = ok(sim.get("/api/settings"));
    assert_eq!(sim.control_ok("get locate"), "0");

    let sub = if transport == Transport::Https { "https" } else { "" };
    let artifacts =
        fresh_artifacts_in(sub, &["page.png", "page-error.png", "page-narrow.png", "page-failure.png", "axe.json"]);
    let mut node = sim.ns().command("node");
    let scheme = match transport {
        Transport::Http => "http",
        Transport::Https => {
            let (home, cert) = trusting_home(&sim);
            node.env("HOME", home).env("NODE_EXTRA_CA_CERTS", cert);
            "https"
        }
    };
    node.current_dir(browser_dir())
        .arg("page.js")
        .arg(format!("{scheme}://{DEVICE_IP}/"))
        .arg(sim.control_path())
        .arg(&artifacts)
        .arg(&version)
        .stdin(Stdio::null());
    let (passed, stdout, stderr) = run_within(node, BROWSER_TIMEOUT);
    assert!(
        passed,
        "the page failed in the browser (screenshot: {}):\n{stderr}\n{stdout}",
        artifacts.join("page-failure.png").display()
    );
    let summary = summary(&stdout);
    let connection = if transport == Transport::Https { "HTTPS, encrypted" } else { "plain HTTP: NOT ENCRYPTED" };
    assert_eq!(summary["connection"], connection, "the page says how it is reached");

    assert!(summary["title"].as_str().is_some_and(|t| t.contains("mbio-53494d")), "{summary}");
    assert!(summary["model"].as_str().is_some_and(|m| m.contains(&format!("firmware {version}"))), "{summary}");
    let lamps: Vec<u64> = summary["lamp_ms"].as_array().expect("lamp times").iter().filter_map(Value::as_u64).collect();
    assert_eq!(lamps.len(), 3, "{summary}");
    assert!(lamps.iter().all(|&ms| ms < LAMP_LIMIT_MS), "a lamp followed its input within 1 s: {lamps:?}");
    assert_eq!(summary["field_error"], "any, or 1-247", "the error beside modbus.unit_id");
    assert!(summary["refused"].as_str().is_some_and(|m| m.starts_with("401")), "{summary}");
    assert_eq!(summary["page_errors"], serde_json::json!([]));
    assert_eq!(summary["telemetry_cells"], 54, "every telemetry point has a cell: {summary}");
    assert!(summary["telemetry_moved"].as_u64().is_some_and(|n| n > 0), "the telemetry changes live: {summary}");
    assert_eq!(summary["focus_kept"], "modbus-port", "focus stays across the refresh");
    assert!(summary["list_error"].as_str().is_some_and(|m| m.contains("networks")), "{summary}");
    // The audit, read again from what the script wrote: no serious or critical violation.
    let audits: Value =
        serde_json::from_slice(&std::fs::read(artifacts.join("axe.json")).expect("axe.json")).expect("the audits");
    assert_eq!(audits.as_object().map(|a| a.len()), Some(3), "three audits: {audits}");
    for (name, audit) in audits.as_object().into_iter().flatten() {
        assert!(audit["passes"].as_u64().is_some_and(|n| n > 10), "{name}: axe ran its rules: {audit}");
        let violations = audit["violations"].as_array().expect("violations");
        let severe: Vec<&Value> =
            violations.iter().filter(|v| v["impact"] == "serious" || v["impact"] == "critical").collect();
        assert!(severe.is_empty(), "{name}: {severe:?}");
    }

    // The device behind the page: only the good change applied, the
    // password set, and locate on.
    let after = ok(sim.get("/api/settings"));
    let mut expected = before.clone();
    expected["modbus"]["unit_id"] = "7".into();
    expected["modbus"]["allow_connect"] = "198.18.0.0/15,10.0.0.9/32".into();
    expected["watchdog"]["safe_do"] = (1 << 2 | 1 << 15).into();
    expected["watchdog"]["safe_tool_do"] = 2.into();
    expected["admin"]["password_set"] = true.into();
    assert_eq!(after, expected, "the page changed unit_id, the masks, allow_connect and the password, nothing else");
    assert_eq!(sim.control_ok("get locate"), "1", "the locate button set hal-sim's flag");
    drop(master);

    for shot in ["page.png", "page-error.png", "page-narrow.png"] {
        let png = std::fs::read(artifacts.join(shot)).unwrap_or_else(|e| panic!("{shot}: {e}"));
        assert!(png.starts_with(b"\x89PNG\r\n\x1a\n") && png.len() > 10_000, "{shot} is a screenshot");
    }
}
