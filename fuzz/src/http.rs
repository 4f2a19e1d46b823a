//! The http target: arbitrary bytes as one HTTP connection to
//! `adapter::http::serve` (or, with [`HTTP_KEPT`], to `serve_kept`, as
//! HTTPS serves one: request after request), over test-support's duplex,
//! with the settings service over a real store on a rule-keeping flash
//! (that wears out when the input says so). The API has its TLS part (the
//! certificate endpoints), without a TLS engine started: a certificate is
//! read and refused by the device's own checks before the engine's.
//!
//! Checks, on every input:
//! - no panic, and the connection ends within the request and response
//!   deadlines (the mock clock moves on while the server waits);
//! - what the server wrote is nothing, or exactly one whole response
//!   (its `Content-Length` bytes of body and nothing after), and a JSON
//!   body is JSON;
//! - the settings change only through a `PUT /api/settings` answered 200,
//!   from an address `allow_write` admits, on a device with a password and
//!   with it, typed as JSON (a page of another site cannot), and then to
//!   what the response shows; a refused one (any other status) changes
//!   nothing and saves nothing;
//! - a reboot, a factory reset, a blink, an update happen only through
//!   their own endpoint, answered 200 or 202, under the same conditions;
//! - the password changes only through its endpoint, answered 200, from
//!   `allow_write`, typed, and with the current password once one is set
//!   (the first one without: the device's first minutes);
//! - a TLS record (the client CA, the device's certificate) is saved only
//!   through its endpoint, answered 200, under the same conditions;
//! - kept connections: what the server wrote is whole responses one after
//!   another, only the last may say `Connection: close`, and the changes
//!   above happen only for a client who may make them (what each request
//!   asked is not told apart there).

use core::pin::pin;
use core::task::Poll;
use std::cell::{Cell, RefCell};

use adapter::control::{Controller, NetworkStatus, Platform};
use adapter::device::{Device, Watchdog};
use adapter::http::{self, Action, Buffers, Http};
use adapter::io::Version;
use adapter::server::Server;
use adapter::settings::{Field, Kind, NetMode, Settings};
use adapter::storage::Store;
use adapter::storage::flash::{RuleFlash, Wearing};
use adapter::update::boot::{Refused, Source};
use embassy_futures::block_on;
use embassy_time::{Duration, MockDriver};
use test_support::duplex::poll_once;

use crate::check::Pins;
use crate::input::{
    HTTP_KEEP_OPEN, HTTP_KEPT, HTTP_OUTSIDE, HTTP_PARTIAL_WRITES, HTTP_PASSWORD_SET, HTTP_SAVE_FAILS, HTTP_STALL_READS,
    HttpInput, PASSWORD,
};

/// The client inside `allow_write`, and one outside it.
const INSIDE: [u8; 4] = [10, 0, 0, 2];
const OUTSIDE: [u8; 4] = [10, 0, 1, 2];

/// The settings flash: two pages.
const PAGE: usize = 4096;

/// The settings flash's type.
type RuleFlashOf<'a> = Wearing<'a, 4, PAGE>;

/// A platform that records what it is asked.
#[derive(Default)]
struct FuzzPlatform {
    located: Cell<bool>,
    reboots: Cell<u32>,
    /// The update files received whole, each as it arrived.
    firmware: RefCell<Vec<Vec<u8>>>,
}

/// The largest update file the platform takes: small, so inputs reach it.
const FIRMWARE_CAPACITY: usize = 2500;

impl Platform for FuzzPlatform {
    fn model(&self) -> &'static str {
        "fuzz"
    }

    fn mac(&self) -> [u8; 6] {
        MAC
    }

    fn network(&self) -> NetworkStatus {
        NetworkStatus { mode: NetMode::Static, address: None, gateway: None, link: true }
    }

    fn reboot(&self) {
        self.reboots.set(self.reboots.get() + 1);
    }

    fn locate(&self, _duration: Duration) {
        self.located.set(true);
    }

    fn salt(&self) -> [u8; 16] {
        [7; 16]
    }

    fn firmware_capacity(&self) -> usize {
        FIRMWARE_CAPACITY
    }

    /// Takes a file whose first byte is not 0 (a stand-in for the real check).
    async fn receive_firmware<S: Source>(&self, body: &mut S) -> Result<Version, Refused<S::Error>> {
        let mut file = Vec::new();
        let mut last = false;
        while let Some(chunk) = body.chunk().await.map_err(Refused::Source)? {
            assert!(!last, "whole chunks but the last");
            last = chunk.len() < http::request::CHUNK_LEN;
            file.extend_from_slice(chunk);
        }
        let taken = file.first().is_some_and(|&first| first != 0);
        self.firmware.borrow_mut().push(file);
        if taken {
            Ok(Version { major: 1, minor: 2, patch: 3 })
        } else {
            Err(Refused::Update(adapter::update::Error::TooLong))
        }
    }
}

/// The settings the target starts from: `allow_write` admits [`INSIDE`] only.
fn initial_settings() -> Settings {
    let mut settings = Settings::DEFAULT;
    let set = settings.set(Field::ModbusAllowWrite, "10.0.0.0/24");
    assert_eq!(set, Ok(()));
    settings
}

/// base64 of `admin:` and [`PASSWORD`], unpadded (a prefix of the padded form).
fn credentials() -> String {
    let plain = format!("admin:{PASSWORD}");
    let table = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut text = String::new();
    for chunk in plain.as_bytes().chunks(3) {
        let n = chunk.iter().enumerate().fold(0u32, |n, (i, &b)| n | u32::from(b) << (16 - 8 * i));
        for i in 0..=chunk.len() {
            text.push(char::from(table[(n >> (18 - 6 * i) & 63) as usize]));
        }
    }
    text
}

/// A response as the client reads it.
struct Response {
    status: u16,
    head: String,
    body: Vec<u8>,
}

impl Response {
    fn header(&self, name: &str) -> Option<&str> {
        self.head.lines().skip(1).find_map(|line| {
            let (n, v) = line.split_once(':')?;
            n.trim().eq_ignore_ascii_case(name).then_some(v.trim())
        })
    }
}

/// Whole responses one after another and nothing else, or a failed check.
fn responses(mut bytes: &[u8]) -> Vec<Response> {
    let mut all = Vec::new();
    while !bytes.is_empty() {
        let end = bytes.windows(4).position(|w| w == b"\r\n\r\n").expect("a response head");
        let head = String::from_utf8(bytes[..end].to_vec()).expect("a UTF-8 head");
        let status = head.strip_prefix("HTTP/1.1 ").and_then(|s| s.get(..3)).and_then(|s| s.parse().ok());
        let status = status.unwrap_or_else(|| panic!("a status line: {head:?}"));
        let mut response = Response { status, head, body: Vec::new() };
        let length: usize = response.header("content-length").and_then(|v| v.parse().ok()).expect("a Content-Length");
        let body = bytes.get(end + 4..end + 4 + length).expect("the body is Content-Length bytes");
        response.body = body.to_vec();
        if response.header("content-type") == Some("application/json") {
            serde_json::from_slice::<serde_json::Value>(&response.body).expect("a JSON body");
        }
        bytes = &bytes[end + 4 + length..];
        all.push(response);
    }
    all
}

/// Exactly one whole response, as plain HTTP writes it, or a failed check.
fn one_response(bytes: &[u8]) -> Response {
    let mut all = responses(bytes);
    assert_eq!(all.len(), 1, "one request per connection: one response, and nothing follows");
    let response = all.remove(0);
    assert_eq!(response.header("connection"), Some("close"), "one request per connection");
    response
}

/// The longest a connection may take: the request's deadline, the
/// response's, and a failed password's delay.
const BOUND: Duration = Duration::from_secs(
    http::REQUEST_TIMEOUT.as_secs()
        + http::UPLOAD_TIMEOUT.as_secs()
        + http::WRITE_TIMEOUT.as_secs()
        + http::AUTH_FAILURE_DELAY.as_secs(),
);

/// The platform's MAC.
const MAC: [u8; 6] = [0x02, 0, 0, 0, 0, 1];

/// Serves `data` (see [`HttpInput`]) as one connection and checks it.
pub fn http(data: &[u8]) {
    let input = HttpInput::parse(data);
    let flag = |bit: u8| input.flags & bit != 0;
    MockDriver::get().reset();
    let pins = Pins::default();
    let device = Device::new(Watchdog::OFF, "fuzz", &pins);
    let settings = initial_settings();
    let server = Server::new(settings.server_config(MAC), &device);
    let password = flag(HTTP_PASSWORD_SET).then_some(PASSWORD);
    let mut memory = vec![0xff; 2 * PAGE];
    let worn = Cell::new(false);
    let mut store = Store::new(Wearing::new(RuleFlash::<4, PAGE>::new(&mut memory[..]), &worn), 0..2 * PAGE as u32)
        .expect("two whole pages");
    let loaded = block_on(store.load(&settings));
    let control = Controller::new(&server, FuzzPlatform::default(), store, &loaded);
    if let Some(password) = password {
        assert_eq!(block_on(control.set_password(password.as_bytes())), Ok(()));
    }
    let saved_before = control.storage().records;
    worn.set(flag(HTTP_SAVE_FAILS));
    let api = Http::new(&control, http::HTTP_PORT);

    let (wire, end) =
        crate::connection::shaped(input.stream, input.cuts, flag(HTTP_STALL_READS), flag(HTTP_PARTIAL_WRITES));
    if !flag(HTTP_KEEP_OPEN) {
        wire.close();
    }
    let peer = if flag(HTTP_OUTSIDE) { OUTSIDE } else { INSIDE };
    if flag(HTTP_KEPT) {
        return kept(&api, &control, &wire, end, &input, peer, password);
    }
    let (reader, writer) = end.split();
    let mut buffers = Box::new(Buffers::new());
    let serving = pin!(http::serve(&api, Some(peer), reader, writer, &mut buffers));
    let result = run_to_end(serving, &wire, BOUND);

    let written = wire.take_replies();
    let response = (!written.is_empty()).then(|| one_response(&written));
    let status = response.as_ref().map(|r| r.status);
    // The request line, split more loosely than the server does (it takes
    // only single spaces between the words): UTF-8, words between
    // whitespace (Unicode's), the path before any `?` or `#`.
    let request_line = input.stream.split(|&b| b == b'\n').next().unwrap_or_default();
    let mut words = std::str::from_utf8(request_line).unwrap_or_default().split_whitespace();
    let method = words.next().unwrap_or_default();
    let target = words.next().unwrap_or_default();
    let path = target.split(['?', '#']).next().unwrap_or_default();
    let asked = |m: &str, p: &str| method == m && path == p;
    // An upper bound on who may change things: the credentials anywhere
    // in the stream, even split by NUL bytes (the server refuses those).
    let without_nul: Vec<u8> = input.stream.iter().copied().filter(|&b| b != 0).collect();
    // And a change says it is JSON (an update file, octet-stream): what a
    // page of another site cannot send without a preflight.
    let lower = input.stream.to_ascii_lowercase();
    let typed = contains(&lower, b"application/json") || contains(&lower, b"application/octet-stream");
    let credentialed = contains(&without_nul, credentials().as_bytes());
    // Until a password is set the only change taken is setting it.
    let may_set_password = !flag(HTTP_OUTSIDE) && typed && (password.is_none() || credentialed);
    let may_change = !flag(HTTP_OUTSIDE) && typed && password.is_some() && credentialed;

    // The password: changed when its set state did, or the one set no longer verifies.
    let password_changed = control.password_set() != password.is_some()
        || password.is_some_and(|password| !block_on(control.verify_password(password.as_bytes())));
    // Settings: only through an accepted PUT, and as the response shows them.
    let now = control.settings();
    let changed = now != settings;
    // One record for a settings change, one for a password set (the same
    // one again included), nothing else.
    let password_put = asked("PUT", "/api/password") && status == Some(200);
    // A TLS record: only through its endpoint, answered 200 (no engine runs
    // here, so only a removal can be: the CA's or the installed certificate's).
    let tls_put = ["/api/tls/client-ca", "/api/tls/certificate"]
        .iter()
        .any(|&p| (asked("PUT", p) || asked("DELETE", p)) && status == Some(200));
    assert!(!tls_put || may_change, "a TLS record from outside, without the password or before one is set");
    let saved = control.storage().records - saved_before;
    let expected = u32::from(changed) + u32::from(password_put) + u32::from(tls_put);
    assert_eq!(saved, expected, "saved exactly when changed");
    if changed {
        assert!(asked("PUT", "/api/settings") && status == Some(200), "a change without an accepted PUT");
        assert!(may_change, "a change from outside allow_write, without the password or before one is set");
        let body = response.as_ref().map_or(&[][..], |r| r.body.as_slice());
        let shown: serde_json::Value = serde_json::from_slice(body).expect("the new settings");
        for &field in Field::ALL {
            let mut text = String::new();
            now.show(field, &mut text).unwrap();
            let value = &shown[field.group()][field.name()];
            let value = match field.kind() {
                Kind::Number => value.as_u64().map(|n| n.to_string()),
                Kind::Text => value.as_str().map(str::to_string),
            };
            assert_eq!(value, Some(text), "the response shows {} as in force", field.key());
        }
        assert!(shown["reboot_required"].is_boolean());
    }
    if asked("PUT", "/api/settings") && status != Some(200) {
        assert!(!changed, "a refused change changed something");
    }
    // The password, the actions, the blink: each only through its endpoint.
    if password_changed {
        assert!(asked("PUT", "/api/password") && status == Some(200), "the password changed");
        assert!(may_set_password, "the password changed from outside or without the current one");
    }
    // An update file: only through its endpoint, whole, from those who may
    // change the device; taken (and a reboot asked) exactly when accepted.
    let platform = control.platform();
    let files = platform.firmware.borrow();
    assert!(files.len() <= 1, "one request, one file");
    let uploaded = asked("POST", "/api/firmware");
    if let Some(file) = files.first() {
        assert!(uploaded && may_change, "a file from outside, without the password or another endpoint");
        assert!(file.len() <= FIRMWARE_CAPACITY);
        assert!(contains(&input.stream, file), "the file is bytes the client sent, in order");
        let taken = file.first().is_some_and(|&first| first != 0);
        assert_eq!(status == Some(202), taken, "202 exactly for a file taken");
    }
    match result {
        Ok(Some(action)) => {
            let path = match action {
                Action::Reboot if uploaded => "/api/firmware",
                Action::Reboot => "/api/reboot",
                Action::FactoryReset => "/api/factory-reset",
            };
            assert!(asked("POST", path) && status == Some(202), "{action:?} without its request");
            assert!(may_change);
            if path == "/api/firmware" {
                assert!(
                    files.first().is_some_and(|file| file.first().is_some_and(|&b| b != 0)),
                    "a reboot without a file taken"
                );
            }
        }
        Ok(None) | Err(_) => {}
    }
    assert_eq!(platform.reboots.get(), 0, "a reboot is the caller's, after the connection closed");
    if platform.located.get() {
        assert!(asked("POST", "/api/locate") && status == Some(200));
        assert!(may_change);
    }
    if let Some(response) = &response
        && response.status == 401
    {
        assert!(password.is_some(), "401 without a password set");
        assert_eq!(response.header("www-authenticate"), Some("Basic realm=\"mbio\""));
    }
}

/// Polls `serving` to its end as an executor would, moving the mock clock
/// on by 100 ms whenever it waits with nothing stalled; fails if that
/// takes longer than `bound`.
fn run_to_end<F: Future>(
    mut serving: core::pin::Pin<&mut F>,
    wire: &test_support::duplex::Wire,
    bound: Duration,
) -> F::Output {
    let step = Duration::from_millis(100);
    let mut waited = Duration::from_ticks(0);
    loop {
        let stalls = wire.stalls();
        match poll_once(serving.as_mut()) {
            Poll::Ready(result) => return result,
            // A stalled read or write: poll again, as an executor would.
            Poll::Pending if wire.stalls() > stalls => {}
            Poll::Pending => {
                assert!(waited < bound, "the connection ends within {} s", bound.as_secs());
                MockDriver::get().advance(step);
                waited += step;
            }
        }
    }
}

fn contains(haystack: &[u8], needle: &[u8]) -> bool {
    needle.is_empty() || haystack.windows(needle.len()).any(|window| window == needle)
}

/// A connection served as HTTPS serves one (`serve_kept`), checked: whole
/// responses, `Connection: close` on the last one only, and nothing changed
/// for a client who may not change it.
#[allow(clippy::too_many_arguments, reason = "the connection's parts, made by the caller")]
fn kept(
    api: &Http<'_, RuleFlashOf<'_>, FuzzPlatform>,
    control: &Controller<'_, RuleFlashOf<'_>, FuzzPlatform>,
    wire: &test_support::duplex::Wire,
    mut end: test_support::duplex::ServerEnd,
    input: &HttpInput<'_>,
    peer: [u8; 4],
    password: Option<&str>,
) {
    let settings = control.settings();
    let saved_before = control.storage().records;
    let mut buffers = Box::new(Buffers::new());
    // Each request may take its whole bound, and the stream holds fewer
    // requests than bytes.
    let bound = BOUND * (input.stream.len() as u32 + 1);
    let serving = pin!(http::serve_kept(api, Some(peer), http::Scheme::Https, &mut end, &mut buffers));
    let result = run_to_end(serving, wire, bound);
    let all = responses(&wire.take_replies());
    if let Some((_, before_last)) = all.split_last() {
        for response in before_last {
            assert_eq!(response.header("connection"), None, "only the last response ends the connection");
        }
    }
    let without_nul: Vec<u8> = input.stream.iter().copied().filter(|&b| b != 0).collect();
    let lower = input.stream.to_ascii_lowercase();
    let typed = contains(&lower, b"application/json") || contains(&lower, b"application/octet-stream");
    let credentialed = contains(&without_nul, credentials().as_bytes());
    let outside = peer == OUTSIDE;
    let may_set_password = !outside && typed && (password.is_none() || credentialed);
    // A connection that set the first password may go on with it (any, not
    // only [`PASSWORD`]): then only the address and the type bound it.
    let first_set = password.is_none() && control.password_set();
    let may_change = !outside && typed && (credentialed && password.is_some() || first_set);
    let password_changed = control.password_set() != password.is_some()
        || password.is_some_and(|password| !block_on(control.verify_password(password.as_bytes())));
    if password_changed {
        assert!(may_set_password, "the password changed from outside or without the current one");
    }
    let saved = control.storage().records - saved_before;
    if control.settings() != settings || saved > u32::from(password_changed) {
        assert!(may_change, "a change from outside allow_write, without the password or before one is set");
    }
    let platform = control.platform();
    if platform.located.get() || !platform.firmware.borrow().is_empty() || matches!(result, Ok(Some(_))) {
        assert!(may_change, "an action from outside allow_write or without the password");
    }
    assert_eq!(platform.reboots.get(), 0, "a reboot is the caller's, after the connection closed");
}
