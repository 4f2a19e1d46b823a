//! Writes the seed corpora of the fuzz targets from the codec fixtures
//! (`test_support::fixtures::PYMODBUS` and `PYMODBUS_DEVICE`, bytes captured
//! from pymodbus, the latter Read Device Identification and Diagnostics), and
//! the store's from records and real saves (`firmware_fuzz::storage::seeds`):
//!
//! ```text
//! cargo run -p fuzz-seeds -- DIR    # writes DIR/session, DIR/handler, DIR/codec, DIR/store, DIR/record, DIR/http, DIR/mdns, DIR/reply, DIR/certificate, DIR/tls
//! ```
//!
//! The http target's seeds are requests to every endpoint of the API
//! (docs/http-api.md), whole and cut, with and without the password.
//!
//! Each seed runs through its target's checks before it is written, so a
//! seed that fails them is reported here and not handed to the fuzzer.

use std::path::{Path, PathBuf};

use firmware_fuzz::input::{
    HTTP_KEEP_OPEN, HTTP_KEPT, HTTP_OUTSIDE, HTTP_PARTIAL_WRITES, HTTP_PASSWORD_SET, HTTP_SAVE_FAILS, HTTP_STALL_READS,
    PARTIAL_WRITES, READ_ONLY, STALL_READS, STRICT, UNIT_FILTER,
};
use firmware_fuzz::{HandlerInput, HttpInput, SessionInput};
use test_support::fixtures::{PYMODBUS, PYMODBUS_DEVICE};
use test_support::framer::adu;

fn main() {
    let dir = std::env::args_os().nth(1).map(PathBuf::from).unwrap_or_else(|| {
        eprintln!("usage: fuzz-seeds DIR");
        std::process::exit(2);
    });
    let written = [
        write(&dir.join("session"), &session_seeds(), firmware_fuzz::session),
        write(&dir.join("handler"), &handler_seeds(), firmware_fuzz::handler),
        write(&dir.join("codec"), &codec_seeds(), firmware_fuzz::codec),
        write(&dir.join("store"), &firmware_fuzz::storage::seeds(), firmware_fuzz::store),
        write(&dir.join("record"), &firmware_fuzz::storage::record_seeds(), firmware_fuzz::record),
        write(&dir.join("http"), &http_seeds(), firmware_fuzz::http),
        write(&dir.join("mdns"), &firmware_fuzz::mdns::seeds(), firmware_fuzz::mdns),
        write(&dir.join("reply"), &firmware_fuzz::reply::seeds(), firmware_fuzz::reply::reply),
        write(&dir.join("certificate"), &firmware_fuzz::certificate::seeds(), firmware_fuzz::certificate::certificate),
        write(&dir.join("tls"), &firmware_fuzz::tls::seeds(), firmware_fuzz::tls::tls),
    ];
    println!(
        "fuzz-seeds: {} session, {} handler, {} codec, {} store, {} record, {} http, {} mdns, {} reply, {} certificate, {} tls seeds in {}",
        written[0],
        written[1],
        written[2],
        written[3],
        written[4],
        written[5],
        written[6],
        written[7],
        written[8],
        written[9],
        dir.display()
    );
}

/// Runs each seed through `check`, then writes it as `DIR/seed-NN`.
fn write(dir: &Path, seeds: &[Vec<u8>], check: fn(&[u8])) -> usize {
    std::fs::create_dir_all(dir).unwrap_or_else(|e| panic!("creating {}: {e}", dir.display()));
    for (i, seed) in seeds.iter().enumerate() {
        check(seed);
        let path = dir.join(format!("seed-{i:03}"));
        std::fs::write(&path, seed).unwrap_or_else(|e| panic!("writing {}: {e}", path.display()));
    }
    seeds.len()
}

fn requests() -> impl Iterator<Item = &'static [u8]> {
    PYMODBUS.iter().map(|f| f.request)
}

fn device_requests() -> impl Iterator<Item = &'static [u8]> {
    PYMODBUS_DEVICE.iter().map(|f| f.request)
}

/// Read Device Identification and Diagnostics requests the fixtures do not
/// hold: each exception path, the other sub-functions and streams (unit 1).
fn device_variants() -> Vec<Vec<u8>> {
    let pdus: [&[u8]; 14] = [
        &[0x2b, 0x0e, 0x02, 0x04],       // a regular stream from object 4
        &[0x2b, 0x0e, 0x01, 0x05],       // a basic stream from a regular object: from 0
        &[0x2b, 0x0e, 0x04, 0x07],       // no object 7: 02
        &[0x2b, 0x0e, 0x03, 0x00],       // extended: 03
        &[0x2b, 0x0d, 0x01, 0x00],       // MEI type 0D: 01
        &[0x2b, 0x0e, 0x01],             // cut short: 03
        &[0x08, 0x00, 0x0c, 0x00, 0x00], // communication errors
        &[0x08, 0x00, 0x0d, 0x00, 0x00], // exceptions
        &[0x08, 0x00, 0x0e, 0x00, 0x00], // server messages
        &[0x08, 0x00, 0x0f, 0x00, 0x00], // no response
        &[0x08, 0x00, 0x12, 0x00, 0x00], // overrun
        &[0x08, 0x00, 0x01, 0x00, 0x00], // restart communications: 01
        &[0x08, 0x00, 0x0b, 0x00, 0x01], // a count's data not 0000: 03
        &[0x08, 0x00, 0x00],             // an empty query: echoed
    ];
    pdus.iter().enumerate().map(|(i, pdu)| adu(0x100 + i as u16, 0, 1, pdu)).collect()
}

/// `frame` with another unit id, protocol id or length field.
fn with(frame: &[u8], at: usize, bytes: &[u8]) -> Vec<u8> {
    let mut out = frame.to_vec();
    out[at..at + bytes.len()].copy_from_slice(bytes);
    out
}

fn session_seeds() -> Vec<Vec<u8>> {
    let all: Vec<u8> = requests().flatten().copied().collect();
    let seed =
        |flags: u8, unit_id: u8, cuts: &[u8], stream: &[u8]| SessionInput { flags, unit_id, cuts, stream }.to_bytes();
    let mut seeds: Vec<Vec<u8>> = requests().map(|r| seed(0, 0, &[], r)).collect();
    seeds.extend([
        // Every fixture pipelined, in one read, in single bytes, in odd cuts.
        seed(0, 0, &[], &all),
        seed(0, 0, &[1], &all),
        seed(0, 0, &[5, 0, 13, 2], &all),
        seed(STALL_READS | PARTIAL_WRITES, 0, &[3, 7], &all),
        // The unit id filter (the fixtures use unit 1) and the strict policy.
        seed(UNIT_FILTER, 1, &[], &all),
        seed(UNIT_FILTER, 2, &[], &all),
        seed(STRICT, 0, &[], &all),
    ]);
    // Not Modbus (protocol id 1) between two requests; a bad length; a frame cut short.
    let first = PYMODBUS[0].request;
    let other_protocol = [with(first, 2, &[0, 1]), first.to_vec()].concat();
    seeds.push(seed(0, 0, &[], &other_protocol));
    seeds.push(seed(0, 0, &[], &[first, &with(first, 4, &[0, 255])].concat()));
    seeds.push(seed(0, 0, &[], &[first, &first[..9]].concat()));
    // Read Device Identification and Diagnostics: alone, among the map's
    // functions, cut into reads, from a client that may not clear the
    // counters, behind the unit filter, and counting a skipped frame.
    let device: Vec<u8> = device_requests().flatten().copied().collect();
    let variants: Vec<u8> = device_variants().concat();
    seeds.extend(device_requests().map(|r| seed(0, 0, &[], r)));
    seeds.extend([
        seed(0, 0, &[], &device),
        seed(0, 0, &[], &[&all[..], &device, &variants, &all].concat()),
        seed(0, 0, &[3, 1, 0, 7], &[&device[..], &variants].concat()),
        seed(READ_ONLY, 0, &[], &[&all[..], &device, &variants].concat()),
        seed(UNIT_FILTER, 2, &[], &[&device[..], &variants].concat()),
        seed(STALL_READS | PARTIAL_WRITES, 0, &[5, 9], &[&device[..], &variants].concat()),
    ]);
    let count = PYMODBUS_DEVICE[5].request;
    seeds.push(seed(0, 0, &[], &[&with(first, 2, &[0, 1])[..], count, &device, count].concat()));
    seeds
}

fn handler_seeds() -> Vec<Vec<u8>> {
    let mut seeds: Vec<Vec<u8>> = requests().map(|r| HandlerInput::encode(0, 0, &[r])).collect();
    let all: Vec<&[u8]> = requests().collect();
    seeds.push(HandlerInput::encode(0, 0, &all));
    seeds.push(HandlerInput::encode(UNIT_FILTER | STRICT, 1, &all));
    // Replies are no requests: each gets an exception or is discarded.
    let replies: Vec<&[u8]> = PYMODBUS.iter().map(|f| f.reply).collect();
    seeds.push(HandlerInput::encode(0, 0, &replies));
    // Read Device Identification and Diagnostics, and their exceptions.
    seeds.extend(device_requests().map(|r| HandlerInput::encode(0, 0, &[r])));
    let variants = device_variants();
    let device: Vec<&[u8]> =
        device_requests().map(|r| -> &[u8] { r }).chain(variants.iter().map(Vec::as_slice)).collect();
    seeds.push(HandlerInput::encode(0, 0, &device));
    seeds.push(HandlerInput::encode(READ_ONLY | UNIT_FILTER, 1, &device));
    let device_replies: Vec<&[u8]> = PYMODBUS_DEVICE.iter().map(|f| f.reply).collect();
    seeds.push(HandlerInput::encode(0, 0, &device_replies));
    seeds
}

fn codec_seeds() -> Vec<Vec<u8>> {
    let mut seeds = Vec::new();
    for fixture in PYMODBUS.iter().chain(&PYMODBUS_DEVICE) {
        seeds.push(fixture.request[7..].to_vec());
        seeds.push(fixture.reply[7..].to_vec());
        seeds.push(fixture.request.to_vec());
    }
    seeds
}

/// `method path` with `headers` (each ending `\r\n`) and `body`.
/// Sent as the device's page sends it: `Host` its address, and a change
/// typed (JSON; an update file as octet-stream).
fn http_request(method: &str, path: &str, headers: &str, body: &str) -> Vec<u8> {
    let length = if body.is_empty() { String::new() } else { format!("Content-Length: {}\r\n", body.len()) };
    let kind = match (method, path) {
        ("GET", _) => "",
        (_, "/api/firmware") => "Content-Type: application/octet-stream\r\n",
        _ => "Content-Type: application/json\r\n",
    };
    format!("{method} {path} HTTP/1.1\r\nHost: 10.0.0.1\r\n{kind}{headers}{length}\r\n{body}").into_bytes()
}

fn http_seeds() -> Vec<Vec<u8>> {
    // admin:s3cret-pass (firmware_fuzz::input::PASSWORD).
    let auth = "Authorization: Basic YWRtaW46czNjcmV0LXBhc3M=\r\n";
    let requests = [
        http_request("GET", "/api/status", "", ""),
        http_request("GET", "/api/settings", "", ""),
        http_request("PUT", "/api/settings", "", r#"{"modbus": {"unit_id": 7, "port": "1502"}}"#),
        http_request("PUT", "/api/settings", auth, r#"{"network": {"mode": "static", "address": "10.0.0.9/24"}}"#),
        http_request("PUT", "/api/settings", "", r#"{"network": {"mode": "static"}, "robot": {"poll_ms": 5}}"#),
        http_request("PUT", "/api/settings", "", r#"{"device": {"name": "cell-4"}, "admin": {"password_set": true}}"#),
        http_request("PUT", "/api/settings", "", r#"{"watchdog": {"timeout_ms": 500, "safe_do": "0x8001"}}"#),
        http_request("PUT", "/api/settings", "", r#"{"modbus": {"allow_write": "10.0.0.0/8,192.168.1.7"}}"#),
        http_request("PUT", "/api/settings", "", r#"{"nonsense": [1, {"a": null}], "modbus": {"x": true}}"#),
        http_request("PUT", "/api/password", "", r#"{"password": "n3w-password"}"#),
        http_request("PUT", "/api/password", auth, r#"{"password": "\u00e9\u00e9\u00e9\u00e9"}"#),
        http_request("POST", "/api/reboot", auth, ""),
        http_request("POST", "/api/factory-reset", "", "{}"),
        http_request("POST", "/api/locate", auth, ""),
        http_request("DELETE", "/api/settings", "", ""),
        http_request("GET", "/api/events?x=1", "", ""),
        b"PUT /api/settings HTTP/1.1\r\nContent-Length: 4096\r\n\r\n{".to_vec(),
        b"GET /api/status HTTP/1.1\r\nX: \0Content-Length: 1\r\n\r\n".to_vec(),
        // Update files: one taken (first byte not 0) over two chunks, one
        // refused, one over the capacity.
        http_request("POST", "/api/firmware", "", &"F".repeat(1100)),
        http_request("POST", "/api/firmware", auth, &format!("\0{}", "x".repeat(300))),
        b"POST /api/firmware HTTP/1.1\r\nContent-Length: 9999\r\n\r\nF".to_vec(),
        // What a page of another site sends: a simple POST, a rebinding
        // Host, a foreign Origin.
        b"POST /api/locate HTTP/1.1\r\nHost: 10.0.0.1\r\nContent-Type: text/plain\r\n\r\n".to_vec(),
        b"GET /api/status HTTP/1.1\r\nHost: evil.example\r\n\r\n".to_vec(),
        http_request("PUT", "/api/settings", "Origin: http://evil.example\r\n", r#"{"modbus": {"unit_id": 9}}"#),
        b"GET /api/settings HTTP/1.0\r\n\r\n".to_vec(),
    ];
    let seed = |flags: u8, cuts: &[u8], stream: &[u8]| HttpInput { flags, cuts, stream }.to_bytes();
    let mut seeds: Vec<Vec<u8>> = requests.iter().map(|r| seed(0, &[], r)).collect();
    for request in &requests[2..4] {
        seeds.extend([
            seed(HTTP_PASSWORD_SET, &[], request),
            seed(HTTP_OUTSIDE, &[], request),
            seed(HTTP_SAVE_FAILS, &[], request),
            seed(HTTP_STALL_READS | HTTP_PARTIAL_WRITES, &[1, 7, 0], request),
            seed(HTTP_KEEP_OPEN, &[], &request[..request.len() / 2]),
        ]);
    }
    seeds.push(seed(HTTP_PASSWORD_SET, &[], &requests[11]));
    // Right credentials but for a NUL byte inside them: refused.
    let nul = "Authorization: Basic YWRtaW46czNjcmV0LX\0Bhc3M=\r\n";
    seeds.push(seed(HTTP_PASSWORD_SET, &[], &http_request("POST", "/api/reboot", nul, "")));
    // The TLS endpoints: a CA and a device certificate with a key, each PEM
    // (refused by the device's checks: the text is not a certificate), and
    // the removals.
    let pem = "-----BEGIN CERTIFICATE-----\\nMIIBkTCB+wIJAL0=\\n-----END CERTIFICATE-----\\n";
    let key =
        "-----BEGIN PRIVATE KEY-----\\nMIGHAgEAMBMGByqGSM49AgEGCCqGSM49AwEHBG0wawIBAQQg\\n-----END PRIVATE KEY-----\\n";
    for request in [
        http_request("PUT", "/api/tls/client-ca", auth, &format!(r#"{{"certificate": "{pem}"}}"#)),
        http_request("PUT", "/api/tls/certificate", auth, &format!(r#"{{"certificate": "{pem}", "key": "{key}"}}"#)),
        http_request("DELETE", "/api/tls/certificate", auth, ""),
        http_request("GET", "/api/tls", "", ""),
    ] {
        seeds.push(seed(HTTP_PASSWORD_SET, &[], &request));
    }
    // Kept connections (HTTPS's): requests one after another, a pipelined
    // pair, a change among reads, one left half sent.
    let kept = [
        [requests[0].clone(), requests[1].clone(), requests[0].clone()].concat(),
        [requests[0].clone(), requests[3].clone(), b"GET /api/status HTTP/1.1\r\nConnection: close\r\n\r\n".to_vec()]
            .concat(),
        [requests[9].clone(), requests[3].clone()].concat(),
        [requests[1].clone(), requests[2][..20].to_vec()].concat(),
    ];
    for stream in &kept {
        seeds.push(seed(HTTP_KEPT | HTTP_PASSWORD_SET, &[], stream));
        seeds.push(seed(HTTP_KEPT | HTTP_STALL_READS | HTTP_PARTIAL_WRITES, &[3, 0, 50], stream));
    }
    seeds
}
