//! The API over test-support's duplex on the mock clock: every endpoint,
//! every refusal, the limits and the deadlines, and random streams.

use embassy_time::{Duration, Instant};
use proptest::prelude::*;
use serde_json::json;

use super::testing::{CLIENT, Connection, HOST, Response, api, basic, exchange, owner, request, saved, unowned_api};
use super::*;
use crate::server::Rights;
use crate::server::testing::Clock;
use crate::settings::{Field, Settings};

fn get(http: &'static testing::TestHttp, clock: &Clock, path: &str) -> Response {
    let (response, result) = exchange(http, clock, Some(CLIENT), &request("GET", path, "", ""));
    assert_eq!(result, Ok(None));
    response.expect("a whole response")
}

fn send(
    http: &'static testing::TestHttp,
    clock: &Clock,
    method: &str,
    path: &str,
    headers: &str,
    body: &str,
) -> Response {
    let (response, _) = exchange(http, clock, Some(CLIENT), &request(method, path, headers, body));
    response.expect("a whole response")
}

/// `PUT /api/settings` with the owner's credentials.
fn put_settings(http: &'static testing::TestHttp, clock: &Clock, body: &str) -> Response {
    send(http, clock, "PUT", "/api/settings", &owner(), body)
}

#[test]
fn the_status_document_shows_the_device() {
    let clock = Clock::take();
    let http = api();
    let server = http.control().server();
    server.service().set_digital_inputs(0b101);
    server.service().update(|image| image.set_register(crate::map::table::reg::DIGITAL_OUTPUTS, 0x8001));
    server.slots().open(0, 8, Instant::now(), [198, 18, 0, 1], Rights::Read);
    clock.advance(Duration::from_secs(3));
    let response = get(http, &clock, "/api/status");
    assert_eq!(response.status, 200);
    assert_eq!(response.header("content-type"), Some("application/json"));
    assert_eq!(response.header("cache-control"), Some("no-store"));
    assert_eq!(response.header("connection"), Some("close"));
    let status = response.json();
    let device = &status["device"];
    assert_eq!(device["name"], "mbio-53494d", "the default name, from the MAC");
    assert_eq!(device["model"], "test-board");
    assert_eq!(device["firmware"], "0.1.0");
    assert_eq!(device["uptime_s"], 3);
    assert_eq!(device["mac"], "02:4d:42:53:49:4d");
    assert!(
        device["cpu_load_percent"].is_null() && device["reset_reason"].is_null(),
        "no executor loop measures the load here; no reset reason"
    );
    assert_eq!(status["network"], json!({"mode": "static", "address": "10.0.0.1/24", "gateway": null, "link": true}));
    let io = &status["io"];
    assert_eq!((io["di"].as_u64(), io["do"].as_u64()), (Some(0b101), Some(0x8001)));
    assert_eq!(io["ai"], json!([0, 0]));
    assert_eq!(io["ao_types"], json!(["current", "current"]));
    assert_eq!(status["robot"]["state"], "not_ready");
    assert_eq!(status["robot"]["state_code"], 15);
    assert_eq!(status["robot"]["source"], "none");
    assert!(status["robot"]["link"].is_null());
    assert_eq!(
        status["connections"],
        json!([{"peer": "198.18.0.1", "requests": null, "idle_ms": 3000, "read_only": true}])
    );
    assert_eq!(status["counters"].as_object().unwrap().len(), 18);
    assert_eq!(status["counters"]["requests"], 0);
    assert_eq!(status["watchdog"], json!({"timeout_ms": 0, "tripped": false}));
    assert_eq!(status["storage"], json!({"ok": true, "records": 1, "erases": 0}), "the owner's password alone");
    assert_eq!(status["admin"], json!({"password_set": true, "first_password_open": false}));
}

/// The robot's telemetry in the map's units, every group, read at once.
#[test]
fn the_telemetry_document_has_every_point_in_its_unit() {
    let clock = Clock::take();
    let http = api();
    let response = get(http, &clock, "/api/telemetry");
    assert_eq!(response.status, 200);
    assert_eq!(response.header("content-type"), Some("application/json"));
    assert_eq!(response.header("cache-control"), Some("no-store"));
    let zeros = response.json();
    assert_eq!(zeros["joint_position_deg"], json!([0.0, 0.0, 0.0, 0.0, 0.0, 0.0]), "no robot: zeros");

    let telemetry = crate::io::Telemetry {
        joint_position: [123, -456, 0, 1800, -1800, 5],
        joint_velocity: [-1, 2, -3, 4, -5, 6],
        joint_current: [1000, 2000, 3000, 4000, 5000, 65535],
        joint_temperature: [25, 26, 27, 28, 29, 30],
        joint_torque: [-100, 99, 0, 1, -1, 32767],
        task_pose: [6000, -2000, 4500, 900, -1800, 0],
        task_velocity: [15, -15, 0, 1, -1, 0],
        tool_offset: [0, 0, 1200, 0, 0, 0],
        external_wrench: [10, -20, 30, -4, 5, -32768],
    };
    http.control().server().service().update(|image| image.set_telemetry(&telemetry));
    let document = get(http, &clock, "/api/telemetry").json();
    let expected = json!({
        "joint_position_deg": [12.3, -45.6, 0.0, 180.0, -180.0, 0.5],
        "joint_velocity_deg_s": [-0.1, 0.2, -0.3, 0.4, -0.5, 0.6],
        "joint_current_ma": [1000, 2000, 3000, 4000, 5000, 65535],
        "joint_temperature_c": [25, 26, 27, 28, 29, 30],
        "joint_torque_nm": [-100, 99, 0, 1, -1, 32767],
        "task_position_mm": [600.0, -200.0, 450.0],
        "task_orientation_deg": [90.0, -180.0, 0.0],
        "task_velocity_mm_s": [1.5, -1.5, 0.0],
        "task_angular_velocity_deg_s": [0.1, -0.1, 0.0],
        "tool_offset_mm": [0.0, 0.0, 120.0],
        "tool_offset_deg": [0.0, 0.0, 0.0],
        "external_force_n": [10, -20, 30],
        "external_moment_nm": [-4, 5, -32768],
    });
    assert_eq!(document, expected);
    // Every group is the registers docs/data-map.md gives it, in order.
    let keys: Vec<&str> = document.as_object().unwrap().keys().map(String::as_str).collect();
    let mut listed: Vec<&str> = api::TELEMETRY.iter().map(|&(key, ..)| key).collect();
    listed.sort_unstable();
    assert_eq!(keys, listed);
    for &(key, first, count, _) in &api::TELEMETRY {
        assert_eq!(document[key].as_array().unwrap().len(), usize::from(count), "{key}");
        assert!(crate::map::table::register_row(first + u16::from(count) - 1).is_some(), "{key} ends inside the map");
    }
    let response = send(http, &clock, "PUT", "/api/telemetry", &owner(), "{}");
    assert_eq!((response.status, response.header("allow")), (405, Some("GET")));
}

/// The page shows every telemetry group with the unit its key ends in:
/// its table of units knows each suffix the document uses.
#[test]
fn the_page_knows_the_unit_of_every_telemetry_key() {
    let html = page::tests::decompressed(page::PAGE);
    assert!(html.contains("'/api/telemetry'"), "the page reads the telemetry");
    let units = html.lines().find(|line| line.starts_with("const UNITS = {")).expect("the page's units");
    for &(key, ..) in &api::TELEMETRY {
        let suffix = ["deg_s", "mm_s"]
            .into_iter()
            .find(|two| key.ends_with(&format!("_{two}")))
            .unwrap_or_else(|| key.rsplit('_').next().unwrap());
        let known =
            [format!("{{{suffix}: '"), format!(" {suffix}: '")].iter().any(|entry| units.contains(entry.as_str()));
        assert!(known, "{key}: the page has no unit for {suffix}: {units}");
    }
}

#[test]
fn the_page_is_served_gzipped_from_flash_to_a_client_that_takes_gzip() {
    let clock = Clock::take();
    let http = api();
    let (response, result) = exchange(
        http,
        &clock,
        Some(CLIENT),
        &request("GET", "/?from=bookmark", "Accept-Encoding: gzip, deflate\r\n", ""),
    );
    assert_eq!(result, Ok(None));
    let response = response.expect("a whole response");
    assert_eq!(response.status, 200);
    assert_eq!(response.header("content-type"), Some("text/html; charset=utf-8"));
    assert_eq!(response.header("content-encoding"), Some("gzip"));
    assert_eq!(response.header("cache-control"), Some("no-store"));
    assert_eq!(response.header("connection"), Some("close"));
    assert_eq!(response.body, page::PAGE, "the bytes in flash, as they are");
    let html = page::tests::decompressed(&response.body);
    assert!(html.starts_with("<!DOCTYPE html>") && html.contains("<title>"), "{html}");
    let served = response.head.len() + 4 + response.body.len();
    assert!(served <= page::MAX_PAGE_LEN, "{served} bytes served: over the page's 24 KiB");

    // A client that does not take gzip is told how to get the page.
    for headers in ["", "Accept-Encoding: identity\r\n", "Accept-Encoding: deflate, br\r\n"] {
        let response = send(http, &clock, "GET", "/", headers, "");
        assert_eq!(response.status, 406, "{headers:?}");
        assert_eq!(response.header("content-type"), Some("application/json"));
        assert_eq!(response.header("content-encoding"), None);
        assert_eq!(response.json(), json!({"errors": {"request": page::NOT_ACCEPTABLE}}));
        assert!(page::NOT_ACCEPTABLE.contains("curl --compressed"));
    }
}

/// Every response, the page's, the API's and a refusal's, carries the
/// fields a browser honours; the policy names the page's one script and
/// one style by the SHA-256 of their text as served, and nothing else runs.
#[test]
fn every_response_carries_the_security_fields() {
    use sha2::Digest as _;
    let clock = Clock::take();
    let http = api();
    let page = send(http, &clock, "GET", "/", "Accept-Encoding: gzip\r\n", "");
    let responses = [
        page.clone(),
        get(http, &clock, "/api/status"),
        get(http, &clock, "/nowhere"),
        exchange(http, &clock, Some(CLIENT), b"NOT HTTP\r\n\r\n").0.unwrap(),
    ];
    let html = page::tests::decompressed(&page.body);
    let hash = |open: &str, close: &str| {
        let inside = html.split_once(open).unwrap().1.split_once(close).unwrap().0;
        let digest = sha2::Sha256::digest(inside.as_bytes());
        format!("'sha256-{}'", base64(&digest))
    };
    let policy = format!(
        "default-src 'none'; script-src {}; style-src {}; connect-src 'self'; img-src 'self'; form-action 'none'; \
         frame-ancestors 'none'; base-uri 'none'",
        hash("<script>", "</script>"),
        hash("<style>", "</style>")
    );
    for response in &responses {
        assert_eq!(response.header("x-frame-options"), Some("DENY"), "{}", response.head);
        assert_eq!(response.header("x-content-type-options"), Some("nosniff"));
        assert_eq!(response.header("referrer-policy"), Some("no-referrer"));
        assert_eq!(response.header("content-security-policy"), Some(policy.as_str()));
    }
    assert!(
        !html.contains(" onclick=") && !html.contains(" style="),
        "no inline handler or style: the policy blocks them"
    );
}

/// Base64 (RFC 4648), padded: the tests' own, apart from build.rs's.
fn base64(data: &[u8]) -> String {
    let table = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut bits = 0u32;
    let mut held = 0;
    let mut out = String::new();
    for &byte in data {
        bits = bits << 8 | u32::from(byte);
        held += 8;
        while held >= 6 {
            held -= 6;
            out.push(char::from(table[(bits >> held & 63) as usize]));
        }
    }
    if held > 0 {
        out.push(char::from(table[(bits << (6 - held) & 63) as usize]));
    }
    while !out.len().is_multiple_of(4) {
        out.push('=');
    }
    out
}

#[test]
fn the_settings_document_has_every_field_grouped_and_no_secret() {
    let clock = Clock::take();
    let http = api();
    embassy_futures::block_on(http.control().set_password(b"correct horse")).unwrap();
    let response = get(http, &clock, "/api/settings");
    assert_eq!(response.status, 200);
    assert!(!String::from_utf8_lossy(&response.body).contains("horse"));
    let document = response.json();
    let groups = document.as_object().unwrap();
    assert_eq!(groups.keys().collect::<Vec<_>>(), ["admin", "device", "modbus", "network", "robot", "tls", "watchdog"]);
    for &field in Field::ALL {
        let value = &document[field.group()][field.name()];
        match field.kind() {
            crate::settings::Kind::Number => assert!(value.is_u64(), "{} is a number: {value}", field.key()),
            crate::settings::Kind::Text => assert!(value.is_string(), "{} is text: {value}", field.key()),
        }
    }
    let fields: usize = groups.values().map(|group| group.as_object().unwrap().len()).sum();
    assert_eq!(fields, Field::ALL.len() + 1, "every setting and admin.password_set");
    assert_eq!(document["modbus"]["unit_id"], "any");
    assert_eq!(document["modbus"]["port"], 502);
    assert_eq!(document["admin"], json!({"password_set": true}));
}

#[test]
fn a_change_applies_a_subset_and_says_whether_to_reboot() {
    let clock = Clock::take();
    let http = api();
    let control = http.control();
    let response = put_settings(http, &clock, r#"{"modbus": {"unit_id": 7, "idle_timeout_s": "30"}}"#);
    assert_eq!(response.status, 200, "{}", String::from_utf8_lossy(&response.body));
    let document = response.json();
    assert_eq!(document["modbus"]["unit_id"], "7");
    assert_eq!(document["modbus"]["idle_timeout_s"], 30);
    assert_eq!(document["reboot_required"], false);
    assert_eq!(control.settings().modbus.unit_id, Some(7));
    assert_eq!(control.server().config().policy.unit_id, Some(7), "in force at once");
    assert_eq!(saved(http), 1);

    let response = put_settings(http, &clock, r#"{"modbus": {"port": 1502}, "network": {"mode": "dhcp"}}"#);
    assert_eq!(response.json()["reboot_required"], true, "the port applies after a reboot");
    assert_eq!(control.settings().modbus.port, 1502);

    // The document from GET, sent back as it is: nothing changes.
    let document = get(http, &clock, "/api/settings");
    let response = put_settings(http, &clock, std::str::from_utf8(&document.body).unwrap());
    assert_eq!(response.status, 200);
    assert_eq!(response.json()["reboot_required"], false);
    assert_eq!(saved(http), 2, "no change, no save");
    assert_eq!(put_settings(http, &clock, "{}").status, 200);
    assert_eq!(saved(http), 2);
}

#[test]
fn a_bad_change_is_refused_field_by_field_and_changes_nothing() {
    let clock = Clock::take();
    let http = api();
    let control = http.control();
    let before = control.settings();
    let body = r#"{
        "modbus": {"unit_id": 300, "port": true, "write_policy": "loose", "colour": "red", "unit_id": 5},
        "network": {"gateway": "10.0.0.1"},
        "watchdog": {"timeout_ms": [100]},
        "robot": 7,
        "nonsense": {"a": 1},
        "admin": {"password": "12345678", "password_set": false}
    }"#;
    let response = put_settings(http, &clock, body);
    assert_eq!(response.status, 400);
    assert_eq!(
        response.json(),
        json!({"errors": {
            "modbus.unit_id": "any, or 1-247",
            "modbus.port": "must be a number or a string",
            "modbus.write_policy": "seed or strict",
            "modbus.colour": "unknown setting",
            "watchdog.timeout_ms": "must be a number or a string",
            "robot": "must be an object",
            "nonsense": "unknown group",
            "admin.password": "set it with PUT /api/password",
        }})
    );
    assert_eq!(control.settings(), before);
    assert_eq!(saved(http), 0);
    // Each field's own rules pass: the rules between fields are checked.
    let response = put_settings(http, &clock, r#"{"network": {"mode": "static", "gateway": "10.0.0.1"}}"#);
    assert_eq!(response.status, 400);
    assert_eq!(
        response.json(),
        json!({"errors": {"network.address": "required when the mode is static", "network.gateway": "needs an address"}})
    );
    let response = put_settings(http, &clock, r#"{"modbus": {"unit_id": 5, "unit_id": 5}}"#);
    assert_eq!(response.json(), json!({"errors": {"modbus.unit_id": "given more than once"}}));
    // The rule the settings cannot check alone: the API's own port.
    let response = put_settings(http, &clock, r#"{"modbus": {"port": 80}}"#);
    assert_eq!(response.status, 400);
    assert_eq!(response.json(), json!({"errors": {"modbus.port": "must not be the HTTP port"}}));
    assert_eq!(control.settings(), before);
    assert_eq!(saved(http), 0);
}

#[test]
fn a_body_that_is_not_json_is_refused_where_it_breaks() {
    let clock = Clock::take();
    let http = api();
    for (body, at) in [("", 0), ("{\"modbus\": {\"unit_id\": 7}", 25), ("[1]", 0), ("{\"a\":1}x", 7)] {
        let response = put_settings(http, &clock, body);
        assert_eq!(response.status, 400, "{body:?}");
        assert_eq!(response.json(), json!({"errors": {"body": format!("not valid JSON (at byte {at})")}}), "{body:?}");
    }
    assert_eq!(saved(http), 0);
}

#[test]
fn a_failed_save_changes_nothing() {
    let clock = Clock::take();
    let http = api();
    let control = http.control();
    // A flash that fails every write and erase: the store cannot save.
    control.platform().flash_fails.set(true);
    let response = put_settings(http, &clock, r#"{"modbus": {"unit_id": 9}}"#);
    assert_eq!(response.status, 500);
    assert_eq!(response.json()["errors"]["request"], "the settings were not saved; nothing changed");
    assert_eq!(control.settings(), Settings::DEFAULT);
    assert_eq!(control.server().config().policy.unit_id, None, "nothing in force either");
    let response = send(http, &clock, "PUT", "/api/password", &owner(), r#"{"password": "s3cret-pass"}"#);
    assert_eq!(response.status, 500);
    assert_eq!(response.json()["errors"]["request"], "the password was not saved; nothing changed");
    assert!(
        embassy_futures::block_on(control.verify_password(testing::OWNER_PASSWORD.as_bytes())),
        "the old one stays"
    );
    assert_eq!(get(http, &clock, "/api/status").json()["storage"]["ok"], false);
}

#[test]
fn changes_need_the_password_once_one_is_set() {
    let clock = Clock::take();
    let http = api();
    let control = http.control();
    embassy_futures::block_on(control.set_password(b"s3cret-pass")).unwrap();
    let body = r#"{"modbus": {"unit_id": 3}}"#;
    let response = put_settings(http, &clock, body);
    assert_eq!(response.status, 401);
    assert_eq!(response.header("www-authenticate"), Some("Basic realm=\"mbio\""));
    for post in ["/api/reboot", "/api/factory-reset", "/api/locate"] {
        assert_eq!(send(http, &clock, "POST", post, "", "").status, 401, "{post}");
    }
    // Wrong credentials: answered after the delay, not before.
    let mut connection = Connection::open(http, Some(CLIENT));
    connection.wire.send(&request("PUT", "/api/settings", &basic("guess-1234"), body));
    let took = connection.run(&clock, Duration::from_millis(100), Duration::from_secs(10)).unwrap();
    assert_eq!(took, AUTH_FAILURE_DELAY);
    assert_eq!(Response::parse(&connection.wire.take_replies()).unwrap().status, 401);
    assert_eq!(send(http, &clock, "PUT", "/api/settings", "Authorization: Bearer x\r\n", body).status, 401);
    assert_eq!(saved(http), 1, "the password's record alone");

    let response = send(http, &clock, "PUT", "/api/settings", &basic("s3cret-pass"), body);
    assert_eq!(response.status, 200);
    assert_eq!(control.settings().modbus.unit_id, Some(3));
    // Reading never needs it.
    assert_eq!(get(http, &clock, "/api/status").json()["admin"]["password_set"], true);
}

/// What a page on another site can send, and a DNS-rebinding page's
/// `Host`: refused before anything is done, reads included.
#[test]
fn a_page_of_another_site_changes_nothing_and_reads_nothing() {
    let clock = Clock::take();
    let http = api();
    let raw = |method: &str, path: &str, headers: &str, body: &str| {
        let length = format!("Content-Length: {}\r\n", body.len());
        let bytes = format!("{method} {path} HTTP/1.1\r\n{headers}{length}\r\n{body}");
        exchange(http, &clock, Some(CLIENT), bytes.as_bytes()).0.unwrap()
    };
    // A "simple" cross-site request: no preflight, so refused by its type.
    for path in ["/api/locate", "/api/reboot", "/api/factory-reset"] {
        for kind in ["", "Content-Type: text/plain\r\n", "Content-Type: application/x-www-form-urlencoded\r\n"] {
            let response = raw("POST", path, &format!("Host: {HOST}\r\n{kind}"), "");
            assert_eq!(response.status, 415, "{path} {kind:?}");
            assert_eq!(response.json()["errors"]["request"], "a change must be sent as Content-Type: application/json");
        }
    }
    let body = r#"{"modbus": {"unit_id": 7}}"#;
    assert_eq!(raw("PUT", "/api/settings", &format!("Host: {HOST}\r\nContent-Type: text/plain\r\n"), body).status, 415);
    // A rebinding page: another host, even for a read.
    for path in ["/api/status", "/api/settings", "/"] {
        let response = raw("GET", path, "Host: evil.example\r\n", "");
        assert_eq!(response.status, 421, "{path}");
        assert!(response.json()["errors"]["request"].as_str().unwrap().starts_with("Host must be this device"));
    }
    assert_eq!(raw("GET", "/api/status", "", "").status, 400, "HTTP/1.1 without Host");
    let old = exchange(http, &clock, Some(CLIENT), b"GET /api/status HTTP/1.0\r\n\r\n").0.unwrap();
    assert_eq!(old.status, 200, "HTTP/1.0 without Host");
    for host in ["mbio-53494d", "MBIO-53494D.local", "127.0.0.1:8080"] {
        assert_eq!(raw("GET", "/api/status", &format!("Host: {host}\r\n"), "").status, 200, "{host}");
    }
    // A page of another site, with the right type (a preflight it did not get).
    let json = format!("Host: {HOST}\r\nContent-Type: application/json\r\n");
    let response = raw("PUT", "/api/settings", &format!("{json}Origin: http://evil.example\r\n"), body);
    assert_eq!(response.status, 403);
    assert_eq!(response.json()["errors"]["request"], "a page of another site may not use this device (Origin)");
    assert_eq!(raw("GET", "/api/status", &format!("Host: {HOST}\r\nOrigin: null\r\n"), "").status, 403);
    assert_eq!(saved(http), 0);
    assert_eq!(http.control().platform().located.get(), None, "never blinked");
    // The device's own page: its origin, JSON, the owner's password.
    let response = raw("PUT", "/api/settings", &format!("{json}Origin: http://{HOST}\r\n{}", owner()), body);
    assert_eq!(response.status, 200);
    assert_eq!(saved(http), 1);
}

/// Credentials, lengths, hosts, types and origins come once: a second
/// `Authorization` (a wrong password, then the right one) is a 400, not
/// "the last one wins", and nothing changes.
#[test]
fn a_repeated_authorization_is_refused_and_changes_nothing() {
    let clock = Clock::take();
    let http = api();
    let control = http.control();
    embassy_futures::block_on(control.set_password(b"s3cret-pass")).unwrap();
    let body = r#"{"modbus": {"unit_id": 3}}"#;
    let headers = format!("{}{}", basic("guess-1234"), basic("s3cret-pass"));
    let (response, result) = exchange(http, &clock, Some(CLIENT), &request("PUT", "/api/settings", &headers, body));
    assert_eq!((response.unwrap().status, result), (400, Err(Error::BadRequest)));
    assert_eq!(control.settings().modbus.unit_id, None);
    assert_eq!(saved(http), 1, "the password's record alone");
    let response = send(http, &clock, "PUT", "/api/settings", &basic("s3cret-pass"), body);
    assert_eq!(response.status, 200, "once: taken");
}

/// An empty allow-list is not `any`: clearing the field would open the
/// device to everyone; and no address is read with a leading zero.
#[test]
fn an_empty_allow_list_and_an_octal_looking_address_are_refused() {
    let clock = Clock::take();
    let http = api();
    let rule = "any, or up to 8 comma-separated networks such as 192.168.1.0/24,10.0.0.9 (empty is refused: write any)";
    for field in ["allow_write", "allow_connect"] {
        let response = put_settings(http, &clock, &format!(r#"{{"modbus": {{"{field}": ""}}}}"#));
        assert_eq!(response.status, 400, "{field}");
        assert_eq!(response.json(), json!({"errors": {format!("modbus.{field}"): rule}}));
        let response = put_settings(http, &clock, &format!(r#"{{"modbus": {{"{field}": "198.018.0.0/16"}}}}"#));
        assert_eq!(response.status, 400, "{field}: a leading zero");
    }
    let response = put_settings(http, &clock, r#"{"network": {"mode": "static", "address": "198.018.0.2/24"}}"#);
    assert_eq!(response.status, 400);
    assert_eq!(saved(http), 0);
    assert_eq!(put_settings(http, &clock, r#"{"modbus": {"allow_write": "any"}}"#).status, 200, "any, written out");
}

#[test]
fn changes_come_only_from_addresses_allow_write_admits() {
    let clock = Clock::take();
    let http = api();
    let control = http.control();
    let response = put_settings(http, &clock, r#"{"modbus": {"allow_write": "10.0.0.0/24"}}"#);
    assert_eq!(response.status, 200);
    let body = r#"{"modbus": {"unit_id": 4}}"#;
    for peer in [Some([10, 0, 1, 2]), None] {
        let (response, _) = exchange(http, &clock, peer, &request("PUT", "/api/settings", "", body));
        let response = response.unwrap();
        assert_eq!(response.status, 403, "{peer:?}");
        assert_eq!(response.json()["errors"]["request"], "this address may not change the device (modbus.allow_write)");
        let (response, _) = exchange(http, &clock, peer, &request("POST", "/api/reboot", "", ""));
        assert_eq!(response.unwrap().status, 403);
    }
    // Even with the right password, from outside.
    embassy_futures::block_on(control.set_password(b"s3cret-pass")).unwrap();
    let (response, _) =
        exchange(http, &clock, Some([192, 168, 0, 1]), &request("PUT", "/api/settings", &basic("s3cret-pass"), body));
    assert_eq!(response.unwrap().status, 403);
    assert_eq!(control.settings().modbus.unit_id, None);
    // Reading is for everyone.
    let (response, _) = exchange(http, &clock, Some([192, 168, 0, 1]), &request("GET", "/api/settings", "", ""));
    assert_eq!(response.unwrap().status, 200);
}

#[test]
fn the_password_is_set_first_freely_then_only_with_the_current_one() {
    let clock = Clock::take();
    let http = unowned_api();
    let control = http.control();
    for (body, message) in [
        (r#"{"password": "short"}"#, json!({"password": "8-64 bytes"})),
        (&format!(r#"{{"password": "{}"}}"#, "x".repeat(65)), json!({"password": "8-64 bytes"})),
        (r#"{"password": 12345678}"#, json!({"password": "must be a string"})),
        (r#"{}"#, json!({"password": "required"})),
        (r#"{"password": "12345678", "user": "root"}"#, json!({"user": "unknown field"})),
        (r#"{"password": "12345678\u0000"}"#, json!({"password": "no control characters (NUL, tab, newline, DEL)"})),
        (r#"{"password": "1234\t5678"}"#, json!({"password": "no control characters (NUL, tab, newline, DEL)"})),
    ] {
        let response = send(http, &clock, "PUT", "/api/password", "", body);
        assert_eq!(response.status, 400, "{body}");
        assert_eq!(response.json(), json!({ "errors": message }), "{body}");
    }
    assert!(!control.password_set());
    let response = send(http, &clock, "PUT", "/api/password", "", &format!(r#"{{"password": "{}"}}"#, "é".repeat(32)));
    assert_eq!(response.status, 200, "64 bytes of UTF-8");
    assert_eq!(response.json(), json!({"admin": {"password_set": true}}));
    assert!(embassy_futures::block_on(control.verify_password("é".repeat(32).as_bytes())), "all 64 bytes");

    let again = r#"{"password": "n3w-password"}"#;
    assert_eq!(send(http, &clock, "PUT", "/api/password", "", again).status, 401);
    let current = basic(&"é".repeat(32));
    // The password with a NUL after it: HMAC's padding would have let it in.
    let padded = basic(&format!("{}\0", "é".repeat(32)));
    assert_eq!(send(http, &clock, "PUT", "/api/password", &padded, again).status, 401);
    assert_eq!(send(http, &clock, "PUT", "/api/password", &current, again).status, 200);
    assert!(embassy_futures::block_on(control.verify_password(b"n3w-password")));
    assert_eq!(get(http, &clock, "/api/settings").json()["admin"]["password_set"], true);
}

#[test]
fn reboot_factory_reset_and_locate() {
    let clock = Clock::take();
    let http = api();
    let control = http.control();
    let (response, result) = exchange(http, &clock, Some(CLIENT), &request("POST", "/api/reboot", &owner(), ""));
    let response = response.unwrap();
    assert_eq!((response.status, response.json()), (202, json!({"rebooting": true})));
    assert_eq!(result, Ok(Some(Action::Reboot)), "left to the caller, after the connection closes");
    let platform = control.platform();
    assert_eq!(platform.reboots.get(), 0);
    embassy_futures::block_on(http.perform(Action::Reboot));
    assert_eq!(platform.reboots.get(), 1);

    let (response, result) = exchange(http, &clock, Some(CLIENT), &request("POST", "/api/factory-reset", &owner(), ""));
    assert_eq!(response.unwrap().json(), json!({"factory_reset": true, "rebooting": true}));
    assert_eq!(result, Ok(Some(Action::FactoryReset)));
    embassy_futures::block_on(http.perform(Action::FactoryReset));
    assert_eq!((platform.reboots.get(), saved(http)), (2, 0), "erased, then rebooted");

    let (response, result) = exchange(http, &clock, Some(CLIENT), &request("POST", "/api/locate", &owner(), "{}"));
    assert_eq!(response.unwrap().json(), json!({"locating_s": 10}));
    assert_eq!(result, Ok(None));
    assert_eq!(platform.located.get(), Some(LOCATE_DURATION));
}

#[test]
fn unknown_paths_are_404_and_wrong_methods_405() {
    let clock = Clock::take();
    let http = api();
    let firmware = if cfg!(feature = "update") { "/api/events" } else { "/api/firmware" };
    for path in ["/api/events", firmware, "/api/status/", "/api", "/index.html", "/api/STATUS"] {
        let response = get(http, &clock, path);
        assert_eq!(response.status, 404, "{path}");
        assert_eq!(response.json(), json!({"errors": {"request": "no such resource"}}));
    }
    assert_eq!(get(http, &clock, "/api/status?x=1#y").status, 200, "a query is ignored");
    for (method, path, allow) in [
        ("POST", "/", "GET"),
        ("HEAD", "/", "GET"),
        ("POST", "/api/status", "GET"),
        ("DELETE", "/api/settings", "GET, PUT"),
        ("GET", "/api/password", "PUT"),
        ("GET", "/api/reboot", "POST"),
        ("PUT", "/api/locate", "POST"),
        ("get", "/api/status", "GET"),
        ("HEAD", "/api/status", "GET"),
    ] {
        let response = send(http, &clock, method, path, "", "");
        assert_eq!(response.status, 405, "{method} {path}");
        assert_eq!(response.header("allow"), Some(allow));
    }
    assert_eq!((http.control().platform().reboots.get(), saved(http)), (0, 0));
}

#[test]
fn a_body_over_the_limit_is_refused_before_it_is_read() {
    let clock = Clock::take();
    let http = api();
    let head = format!("PUT /api/settings HTTP/1.1\r\nHost: {HOST}\r\nContent-Length: {}\r\n\r\n", MAX_BODY_LEN + 1);
    let mut connection = Connection::open(http, Some(CLIENT));
    connection.wire.send(head.as_bytes());
    assert!(connection.poll(), "answered at once, without waiting for the body");
    assert_eq!(connection.result, Some(Err(Error::Limit(Limit::BodyTooLarge))));
    let response = Response::parse(&connection.wire.take_replies()).unwrap();
    assert_eq!(response.status, 413);
    assert_eq!(response.json(), json!({"errors": {"request": format!("body over {MAX_BODY_LEN} bytes")}}));
    // The largest body is read: one that fits the limit and breaks a rule.
    let mut body = r#"{"device": {"name": ""#.to_string();
    body.push_str(&"a".repeat(MAX_BODY_LEN - body.len() - 3));
    body.push_str("\"}}");
    assert_eq!(body.len(), MAX_BODY_LEN);
    let response = put_settings(http, &clock, &body);
    assert_eq!(response.status, 400);
    assert!(response.json()["errors"]["device.name"].is_string());
    // A length no usize holds.
    let (response, result) = exchange(
        http,
        &clock,
        Some(CLIENT),
        b"PUT /api/settings HTTP/1.1\r\nHost: 10.0.0.1\r\nContent-Length: 18446744073709551616\r\n\r\n",
    );
    assert_eq!((response.unwrap().status, result), (413, Err(Error::Limit(Limit::BodyTooLarge))));
    assert_eq!(saved(http), 0);
}

#[test]
fn a_head_over_the_limit_is_refused() {
    let clock = Clock::take();
    let http = api();
    let filler = format!("X-Filler: {}\r\n", "a".repeat(MAX_HEAD_LEN));
    let (response, result) = exchange(http, &clock, Some(CLIENT), &request("GET", "/api/status", &filler, ""));
    assert_eq!(result, Err(Error::Limit(Limit::HeadTooLarge)));
    let response = response.unwrap();
    assert_eq!(response.status, 431);
    assert_eq!(response.json(), json!({"errors": {"request": "head over 1024 bytes"}}));
    // Just within it: served.
    let base = request("GET", "/api/status", "X-Filler: \r\n", "").len();
    let filler = format!("X-Filler: {}\r\n", "a".repeat(MAX_HEAD_LEN - base));
    let request = request("GET", "/api/status", &filler, "");
    assert_eq!(request.len(), MAX_HEAD_LEN);
    let (response, result) = exchange(http, &clock, Some(CLIENT), &request);
    assert_eq!((response.unwrap().status, result), (200, Ok(None)));
}

#[test]
fn a_half_sent_request_times_out() {
    let clock = Clock::take();
    let http = api();
    let whole = request("PUT", "/api/settings", "", r#"{"modbus": {"unit_id": 7}}"#);
    for cut in [0, 10, whole.len() - 5] {
        let mut connection = Connection::open(http, Some(CLIENT));
        connection.wire.send(&whole[..cut]);
        let took = connection.run(&clock, Duration::from_millis(100), Duration::from_secs(30));
        assert_eq!(took, Some(REQUEST_TIMEOUT), "cut at {cut}");
        assert_eq!(connection.result, Some(Err(Error::Timeout)));
        let response = Response::parse(&connection.wire.take_replies()).unwrap();
        assert_eq!(response.status, 408);
        assert_eq!(response.json(), json!({"errors": {"request": "not complete within 5 s"}}));
    }
    // A slow client that keeps sending is cut off all the same.
    let mut connection = Connection::open(http, Some(CLIENT));
    let started = Instant::now();
    for byte in whole.iter().take(60) {
        connection.wire.send(&[*byte]);
        assert!(!connection.poll() || Instant::now() - started >= REQUEST_TIMEOUT);
        clock.advance(Duration::from_millis(100));
    }
    assert_eq!(connection.result, Some(Err(Error::Timeout)));
    assert_eq!(saved(http), 0);
}

#[test]
fn every_prefix_of_a_request_is_waited_on_then_answered_or_closed() {
    let _clock = Clock::take();
    let http = api();
    let whole = request("PUT", "/api/settings", &owner(), r#"{"modbus": {"unit_id": 7}}"#);
    for cut in 0..whole.len() {
        let mut connection = Connection::open(http, Some(CLIENT));
        connection.wire.send(&whole[..cut]);
        assert!(!connection.poll(), "waits for the rest after {cut} bytes");
        connection.wire.close();
        assert!(connection.poll(), "a closed connection ends at once ({cut} bytes)");
        let replies = connection.wire.take_replies();
        if cut == 0 {
            assert_eq!(connection.result, Some(Ok(None)), "nothing asked, nothing answered");
            assert!(replies.is_empty());
        } else {
            let status = Response::parse(&replies).map(|r| r.status);
            assert!(matches!(status, Some(400)), "cut at {cut}: {status:?}");
        }
        assert_eq!(saved(http), 0, "cut at {cut}");
    }
    // Whole, and in reads of every small size: the same answer.
    for size in [0, 1, 2, 3, 7, 64] {
        let mut connection = Connection::open(http, Some(CLIENT));
        connection.wire.read_sizes([size]);
        connection.wire.stall_reads(size == 3);
        connection.wire.write_sizes([size]);
        connection.wire.send(&whole);
        assert!(connection.poll(), "size {size}");
        let response = Response::parse(&connection.wire.take_replies()).unwrap();
        assert_eq!(response.status, 200, "size {size}");
    }
}

#[test]
fn a_reset_connection_ends_quietly() {
    let _clock = Clock::take();
    let http = api();
    let mut connection = Connection::open(http, Some(CLIENT));
    connection.wire.send(b"GET /api/sta");
    assert!(!connection.poll());
    connection.wire.reset();
    assert!(connection.poll());
    assert_eq!(connection.result, Some(Err(Error::Io(embedded_io_async::ErrorKind::ConnectionReset))));
}

#[test]
fn garbage_gets_a_400() {
    let clock = Clock::take();
    let http = api();
    for garbage in
        [&b"\r\n\r\n"[..], b"HELLO\r\n\r\n", b"GET /api/status\r\n\r\n", b"GET / HTTP/1.1\r\nno colon\r\n\r\n"]
    {
        let (response, result) = exchange(http, &clock, Some(CLIENT), garbage);
        assert_eq!(result, Err(Error::BadRequest), "{garbage:?}");
        let response = response.unwrap();
        assert_eq!(response.status, 400, "{garbage:?}");
        assert_eq!(response.json(), json!({"errors": {"request": "not an HTTP/1.1 request"}}));
    }
}

#[test]
fn the_largest_documents_fit_the_response_buffer() {
    let clock = Clock::take();
    let http = api();
    let control = http.control();
    // Every slot open, the counters and the clock at their widest.
    for slot in 0..crate::server::SLOT_COUNT {
        control.server().slots().open(
            slot,
            crate::server::SLOT_COUNT,
            Instant::now(),
            [198, 18, 0, 1],
            Rights::ReadWrite,
        );
    }
    for counter in [&control.server().stats().requests, &control.server().stats().bad_protocol] {
        counter.store(u32::MAX, core::sync::atomic::Ordering::Relaxed);
    }
    let mut settings = Settings::DEFAULT;
    let list = "255.255.255.255/32,".repeat(8);
    for (field, text) in [
        (Field::DeviceName, "a".repeat(32)),
        (Field::ModbusAllowConnect, list.trim_end_matches(',').to_string()),
        (Field::ModbusAllowWrite, list.trim_end_matches(',').to_string()),
        (Field::NetworkAddress, "255.255.255.254/32".to_string()),
        (Field::RobotLinkAddress, "255.255.255.255:65535/255".to_string()),
    ] {
        settings.set(field, &text).unwrap();
    }
    // Everyone may write: the widest allow-list admits 255.255.255.255/32 only.
    embassy_futures::block_on(control.apply(&settings)).unwrap();
    clock.advance(Duration::from_secs(u64::from(u32::MAX)));
    let status = get(http, &clock, "/api/status");
    assert_eq!(status.status, 200);
    assert_eq!(status.json()["connections"].as_array().unwrap().len(), crate::server::SLOT_COUNT);
    assert!(status.body.len() <= MAX_RESPONSE_LEN - 64, "{} bytes: keep a margin", status.body.len());
    // The telemetry at its widest: every value -3276.8 or -32768 or 65535.
    control.server().service().update(|image| {
        for address in 270..=crate::map::table::reg::LAST {
            image.set_register(address, 0x8000);
        }
        for address in (290..296).chain(300..306) {
            image.set_register(address, u16::MAX);
        }
    });
    let telemetry = get(http, &clock, "/api/telemetry");
    assert_eq!(telemetry.status, 200);
    assert_eq!(telemetry.json()["joint_current_ma"][0], 65535);
    assert_eq!(telemetry.json()["joint_position_deg"][0], -3276.8);
    assert!(telemetry.body.len() <= MAX_RESPONSE_LEN - 64, "{} bytes: keep a margin", telemetry.body.len());
    let document = get(http, &clock, "/api/settings");
    assert_eq!(document.status, 200);
    assert!(document.body.len() <= MAX_BODY_LEN, "the settings document can be sent back: {}", document.body.len());
    // Every field wrong: every message listed.
    embassy_futures::block_on(control.apply(&Settings::DEFAULT)).unwrap();
    let records = saved(http);
    let mut groups: Vec<(&str, Vec<String>)> = Vec::new();
    for &field in Field::ALL {
        if groups.last().is_none_or(|(group, _)| *group != field.group()) {
            groups.push((field.group(), Vec::new()));
        }
        groups.last_mut().unwrap().1.push(format!(r#""{}": "-x""#, field.name()));
    }
    let groups: Vec<String> = groups.iter().map(|(g, fields)| format!(r#""{g}": {{{}}}"#, fields.join(","))).collect();
    let response = put_settings(http, &clock, &format!("{{{}}}", groups.join(",")));
    assert_eq!(response.status, 400);
    assert_eq!(response.json()["errors"].as_object().unwrap().len(), Field::ALL.len());
    assert!(response.body.len() <= MAX_RESPONSE_LEN - 64, "{} bytes: keep a margin", response.body.len());
    // Unknown keys: the first few listed, the change refused all the same.
    let many: Vec<String> = (0..30).map(|i| format!(r#""k{i}": 1"#)).collect();
    let response = put_settings(http, &clock, &format!(r#"{{"modbus": {{{}}}}}"#, many.join(",")));
    assert_eq!(response.status, 400);
    assert_eq!(response.json()["errors"].as_object().unwrap().len(), 8);
    assert_eq!(saved(http), records, "nothing saved");
}

/// A request mostly well-formed, with random parts: a method, a path, a
/// few headers and a body that may or may not match its length.
fn requests() -> impl Strategy<Value = Vec<u8>> {
    let method = prop::sample::select(vec!["GET", "PUT", "POST", "DELETE", "get", ""]);
    let path = prop::sample::select(vec![
        "/api/status",
        "/api/settings",
        "/api/password",
        "/api/reboot",
        "/api/locate",
        "/",
        "/api/settings?x",
    ]);
    let body = prop_oneof![
        Just(String::new()),
        Just(r#"{"modbus": {"unit_id": 7}}"#.to_string()),
        Just(r#"{"password": "12345678"}"#.to_string()),
        Just(r#"{"network": {"mode": "static"}}"#.to_string()),
        "[ -~]{0,40}",
    ];
    let headers = prop::collection::vec(
        prop_oneof![
            2 => Just("Authorization: Basic YWRtaW46MTIzNDU2Nzg=\r\n".to_string()),
            1 => Just("Content-Length: 9999\r\n".to_string()),
            1 => Just("Content-Length: 3\r\n".to_string()),
            4 => Just(format!("Host: {HOST}\r\n")),
            1 => Just("Host: evil.example\r\n".to_string()),
            3 => Just("Content-Type: application/json\r\n".to_string()),
            1 => Just("Content-Type: text/plain\r\n".to_string()),
            1 => Just("Origin: http://evil.example\r\n".to_string()),
            4 => "X-[a-z]{1,8}: [ -~]{0,20}\r\n",
            1 => "[ -~]{0,20}\r\n",
        ],
        0..5,
    );
    (method, path, headers, body, any::<bool>()).prop_map(|(method, path, headers, body, length)| {
        let length = if length { format!("Content-Length: {}\r\n", body.len()) } else { String::new() };
        format!("{method} {path} HTTP/1.1\r\n{}{length}\r\n{body}", headers.concat()).into_bytes()
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, failure_persistence: None, ..ProptestConfig::default() })]

    /// Any stream, cut anywhere: the connection ends in bounded time, with
    /// at most one response, and a refused change changes nothing.
    #[test]
    fn any_stream_ends_with_one_response_and_no_partial_change(
        stream in prop_oneof![requests(), prop::collection::vec(any::<u8>(), 0..300)],
        sizes in prop::collection::vec(0usize..20, 0..4),
        close in any::<bool>(),
    ) {
        let clock = Clock::take();
        let http = api();
        let control = http.control();
        let before = control.settings();
        let mut connection = Connection::open(http, Some(CLIENT));
        connection.wire.read_sizes(sizes);
        connection.wire.send(&stream);
        if close {
            connection.wire.close();
        }
        let bound = REQUEST_TIMEOUT + WRITE_TIMEOUT + AUTH_FAILURE_DELAY;
        let took = connection.run(&clock, Duration::from_millis(250), bound);
        prop_assert!(took.is_some(), "the connection ends within {} ms", bound.as_millis());
        let replies = connection.wire.take_replies();
        let response = Response::parse(&replies);
        let changed = control.settings() != before;
        let accepted = response.as_ref().is_some_and(|r| r.status == 200);
        prop_assert!(!changed || accepted, "a change without a 200");
        if let Some(response) = &response {
            // A refused request saves nothing; an accepted one saves only
            // a change of the settings, or a password.
            let password = stream.windows(13).any(|w| w == b"/api/password");
            if response.status != 200 || !changed && !password {
                prop_assert_eq!(saved(http), 0);
            }
            if response.header("content-type") == Some("application/json") {
                response.json();
            }
        }
    }
}

/// `POST /api/firmware` (feature `update`): the file streamed to the
/// updater, within its capacity, from those who may change the device.
#[cfg(feature = "update")]
mod firmware {
    use super::*;
    use crate::http::request::CHUNK_LEN;
    use crate::http::testing::{TEST_FIRMWARE_CAPACITY, TEST_FIRMWARE_VERSION};

    fn file(len: usize) -> Vec<u8> {
        (0..len).map(|i| (i * 7 % 256) as u8).collect()
    }

    fn upload(headers: &str, file: &[u8]) -> Vec<u8> {
        let head = "POST /api/firmware HTTP/1.1\r\nHost: 10.0.0.1\r\nContent-Type: application/octet-stream\r\n";
        let mut bytes = format!("{head}{headers}Content-Length: {}\r\n\r\n", file.len()).into_bytes();
        bytes.extend_from_slice(file);
        bytes
    }

    /// What the upload's answer is for each refusal of the core: the
    /// image's faults are 400s with their reason; no signature check in
    /// the bootloader (the board can take no update) is 501, as on a
    /// board without updates.
    #[test]
    fn refusals_of_the_core_map_to_answers() {
        use crate::update::{Error, SignatureError};
        let invalid = |error| match super::super::update_refusal(error) {
            FirmwareRefusal::Invalid(reason) => reason,
            other => panic!("{other:?}"),
        };
        assert_eq!(invalid(Error::Signature(SignatureError::Mismatch)), "the image's signature is not valid");
        assert_eq!(invalid(Error::TooLong), "more bytes than the image's header says");
        assert_eq!(
            super::super::update_refusal(Error::Signature(SignatureError::Unavailable)),
            FirmwareRefusal::Unsupported
        );
        assert_eq!(super::super::update_refusal(Error::Config), FirmwareRefusal::Storage);
    }

    #[test]
    fn the_status_says_the_update_state_the_previous_version_and_the_capacity() {
        use crate::device::{BootState, FirmwareStatus};
        let clock = Clock::take();
        let http = api();
        let device = http.control().server().service();
        assert_eq!(get(http, &clock, "/api/status").json()["update"], serde_json::Value::Null, "not set yet");
        // What the board sets at boot, then when it confirms.
        let previous = Some(crate::io::Version { major: 0, minor: 1, patch: 7 });
        device.set_firmware_update(FirmwareStatus { state: BootState::Trial, previous, capacity: 1_234 });
        let status = get(http, &clock, "/api/status").json();
        assert_eq!(status["update"], json!({"state": "trial", "previous": "0.1.7", "capacity": 1234}));
        device.set_firmware_update_state(BootState::Confirmed);
        let status = get(http, &clock, "/api/status").json();
        assert_eq!(status["update"], json!({"state": "confirmed", "previous": "0.1.7", "capacity": 1234}));
        device.set_firmware_update(FirmwareStatus { state: BootState::RolledBack, previous: None, capacity: 1_234 });
        let status = get(http, &clock, "/api/status").json();
        assert_eq!(status["update"], json!({"state": "rolled_back", "previous": null, "capacity": 1234}));
    }

    #[test]
    fn a_file_is_streamed_whole_to_the_updater_then_the_device_reboots() {
        let clock = Clock::take();
        let http = api();
        let file = file(TEST_FIRMWARE_CAPACITY);
        let (response, result) = exchange(http, &clock, Some(CLIENT), &upload(&owner(), &file));
        let response = response.unwrap();
        assert_eq!(response.status, 202);
        let crate::io::Version { major, minor, patch } = TEST_FIRMWARE_VERSION;
        let version = format!("{major}.{minor}.{patch}");
        assert_eq!(response.json(), json!({"firmware": {"version": version, "rebooting": true}}));
        assert_eq!(result, Ok(Some(Action::Reboot)));
        let control = http.control();
        assert!(*control.platform().firmware.borrow() == file, "every byte, in order");
        let chunks = control.platform().firmware_chunks.borrow().clone();
        assert!(chunks.iter().rev().skip(1).all(|&len| len == CHUNK_LEN), "whole chunks but the last: {chunks:?}");
        assert_eq!(control.platform().reboots.get(), 0, "the reboot is the caller's, after the connection closed");
        // A second connection, in reads of every small size: the same file.
        for size in [1, 5, 700] {
            let mut connection = Connection::open(http, Some(CLIENT));
            connection.wire.read_sizes([size]);
            connection.wire.send(&upload(&owner(), &file[..1000]));
            assert!(connection.poll(), "size {size}");
            assert_eq!(connection.result, Some(Ok(Some(Action::Reboot))));
            assert!(*control.platform().firmware.borrow() == file[..1000]);
        }
    }

    #[test]
    fn a_file_of_another_type_is_refused_before_it_is_read() {
        let clock = Clock::take();
        let http = api();
        for kind in ["", "Content-Type: text/plain\r\n", "Content-Type: multipart/form-data; boundary=x\r\n"] {
            let bytes =
                format!("POST /api/firmware HTTP/1.1\r\nHost: {HOST}\r\n{kind}Content-Length: 10\r\n\r\n0123456789");
            let (response, _) = exchange(http, &clock, Some(CLIENT), bytes.as_bytes());
            let response = response.unwrap();
            assert_eq!(response.status, 415, "{kind:?}");
            assert_eq!(
                response.json()["errors"]["request"],
                "an update file must be sent as Content-Type: application/octet-stream"
            );
        }
        assert!(http.control().platform().firmware_chunks.borrow().is_empty(), "nothing reached the updater");
    }

    #[test]
    fn a_file_over_the_capacity_is_refused_before_it_is_read() {
        let _clock = Clock::take();
        let http = api();
        let head = format!(
            "POST /api/firmware HTTP/1.1\r\nHost: {HOST}\r\nContent-Type: application/octet-stream\r\nContent-Length: {}\r\n\r\n",
            TEST_FIRMWARE_CAPACITY + 1
        );
        let mut connection = Connection::open(http, Some(CLIENT));
        connection.wire.send(head.as_bytes());
        assert!(connection.poll(), "answered at once, without waiting for the body");
        let response = Response::parse(&connection.wire.take_replies()).unwrap();
        assert_eq!(response.status, 413);
        assert_eq!(response.json(), json!({"errors": {"firmware": format!("over {TEST_FIRMWARE_CAPACITY} bytes")}}));
        assert_eq!(connection.result, Some(Ok(None)));
        assert!(http.control().platform().firmware_chunks.borrow().is_empty());
    }

    #[test]
    fn only_those_who_may_change_the_device_update_it() {
        let clock = Clock::take();
        let http = api();
        let control = http.control();
        embassy_futures::block_on(control.set_password(b"s3cret-pass")).unwrap();
        let file = file(100);
        let (response, result) = exchange(http, &clock, Some(CLIENT), &upload("", &file));
        assert_eq!((response.unwrap().status, result), (401, Ok(None)));
        let (response, _) = exchange(http, &clock, Some(CLIENT), &upload(&basic("wrong-pass"), &file));
        assert_eq!(response.unwrap().status, 401);
        let (response, _) = exchange(http, &clock, None, &upload(&basic("s3cret-pass"), &file));
        assert_eq!(response.unwrap().status, 403, "not IPv4: never");
        assert!(control.platform().firmware_chunks.borrow().is_empty(), "nothing reached the updater");
        let (response, result) = exchange(http, &clock, Some(CLIENT), &upload(&basic("s3cret-pass"), &file));
        assert_eq!((response.unwrap().status, result), (202, Ok(Some(Action::Reboot))));
        for method in ["GET", "PUT"] {
            assert_eq!(send(http, &clock, method, "/api/firmware", "", "").status, 405);
        }
        // A device without a password takes no update, only its first password.
        let http = unowned_api();
        let (response, result) = exchange(http, &clock, Some(CLIENT), &upload("", &file));
        assert_eq!((response.unwrap().status, result), (403, Ok(None)));
        assert!(http.control().platform().firmware_chunks.borrow().is_empty(), "nothing reached the updater");
    }

    #[test]
    fn a_device_that_takes_no_updates_says_so() {
        let clock = Clock::take();
        let http = api();
        http.control().platform().firmware_capacity.set(0);
        let (response, result) = exchange(http, &clock, Some(CLIENT), &upload("", &file(10)));
        let response = response.unwrap();
        assert_eq!((response.status, result), (501, Ok(None)));
        assert_eq!(response.json(), json!({"errors": {"firmware": "this device takes no updates"}}));
        assert!(http.control().platform().firmware_chunks.borrow().is_empty());
    }

    #[test]
    fn a_refused_or_cut_off_file_changes_nothing() {
        let clock = Clock::take();
        let http = api();
        let control = http.control();
        control
            .platform()
            .firmware_refusal
            .set(Some(crate::update::Error::Signature(crate::update::SignatureError::Mismatch)));
        let (response, result) = exchange(http, &clock, Some(CLIENT), &upload(&owner(), &file(3000)));
        let response = response.unwrap();
        assert_eq!((response.status, result), (400, Ok(None)));
        assert_eq!(response.json(), json!({"errors": {"firmware": "the image's signature is not valid"}}));
        control.platform().firmware_refusal.set(Some(crate::update::Error::Config));
        let (response, result) = exchange(http, &clock, Some(CLIENT), &upload(&owner(), &file(10)));
        assert_eq!((response.unwrap().status, result), (500, Ok(None)));
        // Cut off: the connection closes before the whole file came.
        let whole = upload(&owner(), &file(3000));
        let mut connection = Connection::open(http, Some(CLIENT));
        connection.wire.send(&whole[..whole.len() - 1]);
        assert!(!connection.poll(), "waits for the rest");
        connection.wire.close();
        assert!(connection.poll());
        assert_eq!(connection.result, Some(Err(Error::BadRequest)));
        assert_eq!(control.platform().reboots.get(), 0);
    }
}

/// A new device takes no change but its first password, and that only
/// within 10 minutes of power-up or of a press of its button; then the
/// password guards every change.
#[test]
fn until_a_password_is_set_only_setting_it_is_taken_and_only_in_its_window() {
    let clock = Clock::take();
    let http = unowned_api();
    let control = http.control();
    let admin = get(http, &clock, "/api/status").json()["admin"].clone();
    assert_eq!(admin, json!({"password_set": false, "first_password_open": true}));
    let no_password =
        "no admin password is set: set one first (PUT /api/password); until then no other change is taken";
    for (method, path, body) in [
        ("PUT", "/api/settings", r#"{"modbus": {"unit_id": 7}}"#),
        ("POST", "/api/reboot", ""),
        ("POST", "/api/factory-reset", ""),
        ("POST", "/api/locate", ""),
    ] {
        let (response, result) = exchange(http, &clock, Some(CLIENT), &request(method, path, "", body));
        let response = response.unwrap();
        assert_eq!((response.status, response.json()), (403, json!({"errors": {"request": no_password}})), "{path}");
        assert_eq!(result, Ok(None), "{path}: nothing left to do");
    }
    assert_eq!((saved(http), control.platform().reboots.get(), control.platform().located.get()), (0, 0, None));

    // Ten minutes after power-up nobody can claim it over the network.
    clock.advance(crate::control::FIRST_PASSWORD_WINDOW);
    assert_eq!(get(http, &clock, "/api/status").json()["admin"]["first_password_open"], false);
    let claim = r#"{"password": "a claimant"}"#;
    let response = send(http, &clock, "PUT", "/api/password", "", claim);
    assert_eq!(response.status, 403);
    assert!(
        response.json()["errors"]["password"]
            .as_str()
            .unwrap()
            .starts_with("the first password may be set only within 10 minutes")
    );
    assert!(!control.password_set());
    assert_eq!(saved(http), 0);

    // The owner presses the button: ten more minutes.
    control.open_first_password_window();
    assert_eq!(get(http, &clock, "/api/status").json()["admin"]["first_password_open"], true);
    assert_eq!(send(http, &clock, "PUT", "/api/password", "", claim).status, 200);
    assert_eq!(
        put_settings(http, &clock, r#"{"modbus": {"unit_id": 7}}"#).status,
        401,
        "the owner's password is not this one"
    );
    let response = send(http, &clock, "PUT", "/api/settings", &basic("a claimant"), r#"{"modbus": {"unit_id": 7}}"#);
    assert_eq!(response.status, 200);
    assert_eq!(control.settings().modbus.unit_id, Some(7));
}

/// Every response in `bytes`, in order.
#[cfg(feature = "tls")]
fn responses(mut bytes: &[u8]) -> Vec<Response> {
    let mut all = Vec::new();
    while !bytes.is_empty() {
        let head_end = bytes.windows(4).position(|w| w == b"\r\n\r\n").expect("a head") + 4;
        let head = String::from_utf8_lossy(&bytes[..head_end]).to_ascii_lowercase();
        let length: usize = head
            .lines()
            .find_map(|l| l.strip_prefix("content-length:"))
            .and_then(|v| v.trim().parse().ok())
            .expect("a length");
        all.push(Response::parse(&bytes[..head_end + length]).expect("a whole response"));
        bytes = &bytes[head_end + length..];
    }
    all
}

#[cfg(feature = "tls")]
#[test]
fn a_kept_connection_answers_request_after_request_and_closes_when_idle() {
    let clock = Clock::take();
    let http = api();
    let mut connection = Connection::open_kept(http, Some(CLIENT));
    for path in ["/api/status", "/api/settings", "/api/telemetry"] {
        connection.wire.send(&request("GET", path, "", ""));
        assert!(!connection.poll(), "the connection stays open after {path}");
        let answered = responses(&connection.wire.take_replies());
        assert_eq!(answered.len(), 1, "{path}");
        assert_eq!(answered[0].status, 200, "{path}");
        assert_eq!(answered[0].header("connection"), None, "kept alive: {path}");
    }
    // Nothing more within KEEP_ALIVE_IDLE: closed, without a 408.
    let took = connection.run(&clock, Duration::from_millis(500), Duration::from_secs(30)).expect("it ends");
    assert!(took >= KEEP_ALIVE_IDLE && took <= KEEP_ALIVE_IDLE + Duration::from_secs(1), "{took:?}");
    assert_eq!(connection.result, Some(Ok(None)));
    assert!(connection.wire.take_replies().is_empty(), "no answer to silence");
}

#[cfg(feature = "tls")]
#[test]
fn a_kept_connection_closes_when_asked_when_refused_and_when_a_request_comes_early() {
    let clock = Clock::take();
    let http = api();
    for (what, bytes) in [
        ("Connection: close", request("GET", "/api/status", "Connection: keep-alive, close\r\n", "")),
        ("HTTP/1.0", format!("GET /api/status HTTP/1.0\r\nHost: {HOST}\r\n\r\n").into_bytes()),
        ("another host", b"GET /api/status HTTP/1.1\r\nHost: evil.example\r\n\r\n".to_vec()),
        ("pipelined", [request("GET", "/api/status", "", ""), request("GET", "/api/settings", "", "")].concat()),
        ("a broken limit", format!("GET /{} HTTP/1.1\r\nHost: {HOST}\r\n\r\n", "a".repeat(MAX_HEAD_LEN)).into_bytes()),
    ] {
        let mut connection = Connection::open_kept(http, Some(CLIENT));
        connection.wire.send(&bytes);
        let took = connection.run(&clock, Duration::from_millis(100), Duration::from_secs(30));
        assert!(took.is_some_and(|t| t < KEEP_ALIVE_IDLE), "{what}: closed at once, not when idle");
        let answered = responses(&connection.wire.take_replies());
        assert_eq!(answered.len(), 1, "{what}: one answer");
        assert_eq!(answered[0].header("connection"), Some("close"), "{what}");
    }
}

#[cfg(feature = "tls")]
#[test]
fn over_https_the_origin_is_https_and_plain_http_off_redirects_port_80() {
    let clock = Clock::take();
    let http = api();
    // On the kept (HTTPS) connection, the page's origin is https://.
    let mut connection = Connection::open_kept(http, Some(CLIENT));
    let change = r#"{"modbus":{"unit_id":"5"}}"#;
    connection.wire.send(&request("PUT", "/api/settings", &format!("{}Origin: http://{HOST}\r\n", owner()), change));
    connection.wire.send(&request("PUT", "/api/settings", &format!("{}Origin: https://{HOST}\r\n", owner()), change));
    connection.run(&clock, Duration::from_millis(100), Duration::from_secs(30));
    let answered = responses(&connection.wire.take_replies());
    assert_eq!(answered.iter().map(|r| r.status).collect::<Vec<_>>(), [403], "refused, then closed (pipelined)");
    // Port 80 redirects only once HTTPS serves (here it does not: no secure port).
    let response = put_settings(http, &clock, r#"{"tls":{"plain_http":"off"}}"#);
    assert_eq!(response.status, 200, "{}", String::from_utf8_lossy(&response.body));
    assert_eq!(get(http, &clock, "/api/status").status, 200, "without HTTPS serving, port 80 still serves");
}
