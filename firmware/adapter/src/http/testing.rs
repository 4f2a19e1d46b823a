//! What the HTTP tests share: the settings service over a real store on a
//! rule-keeping flash, with a platform that records what it is asked, and
//! a client that sends bytes over test-support's duplex and reads the
//! response back, on embassy-time's mock clock.

use std::cell::Cell;
#[cfg(feature = "update")]
use std::cell::RefCell;
use std::future::Future;
use std::ops::Range;
use std::pin::Pin;
use std::task::Poll;

use embassy_time::Duration;
use test_support::duplex::{Wire, poll_once};

use super::{Action, Buffers, Error, HTTP_PORT, Http, serve};
use crate::control::{Controller, NetworkStatus, Platform};
use crate::device::Watchdog;
use crate::server::testing::{Clock, server_with};
use crate::settings::{Cidr, NetMode, Settings};
use crate::storage::Store;
use crate::storage::flash::{RuleFlash, Wearing};

/// The client the tests talk from (`ALLOWED` is in `allow_write` when one is set).
pub const CLIENT: [u8; 4] = [10, 0, 0, 2];

/// The largest update file the test platform takes.
#[cfg(feature = "update")]
pub const TEST_FIRMWARE_CAPACITY: usize = 6000;

/// The version the test platform says an update file holds.
#[cfg(feature = "update")]
pub const TEST_FIRMWARE_VERSION: crate::io::Version = crate::io::Version { major: 9, minor: 8, patch: 7 };

/// The test platform's MAC.
pub const TEST_MAC: [u8; 6] = [0x02, 0x4d, 0x42, 0x53, 0x49, 0x4d];

/// The settings flash's page, and its range: two pages.
const PAGE: usize = 4096;
const RANGE: Range<u32> = 0..(2 * PAGE) as u32;

/// The tests' settings flash: rule-keeping, worn out while the platform's
/// `flash_fails` is set.
pub type TestFlash = Wearing<'static, 4, PAGE>;

/// A platform that records what it is asked.
pub struct TestPlatform {
    pub located: Cell<Option<Duration>>,
    pub reboots: Cell<usize>,
    /// The settings flash fails while set.
    pub flash_fails: &'static Cell<bool>,
    /// Records in the settings flash when the test began ([`saved`]).
    pub records_at_start: Cell<u32>,
    /// The last update file received, and the length of each chunk it came in.
    #[cfg(feature = "update")]
    pub firmware: RefCell<Vec<u8>>,
    #[cfg(feature = "update")]
    pub firmware_chunks: RefCell<Vec<usize>>,
    /// The next update file is refused so, once received whole.
    #[cfg(feature = "update")]
    pub firmware_refusal: Cell<Option<crate::update::Error>>,
    /// The largest update file taken ([`TEST_FIRMWARE_CAPACITY`] unless changed).
    #[cfg(feature = "update")]
    pub firmware_capacity: Cell<usize>,
}

impl Platform for TestPlatform {
    fn model(&self) -> &'static str {
        "test-board"
    }

    fn mac(&self) -> [u8; 6] {
        TEST_MAC
    }

    fn network(&self) -> NetworkStatus {
        NetworkStatus {
            mode: NetMode::Static,
            address: Cidr::parse_optional("10.0.0.1/24").ok().flatten(),
            gateway: None,
            link: true,
        }
    }

    fn reboot(&self) {
        self.reboots.set(self.reboots.get() + 1);
    }

    fn locate(&self, duration: Duration) {
        self.located.set(Some(duration));
    }

    fn salt(&self) -> [u8; 16] {
        [7; 16]
    }

    #[cfg(feature = "update")]
    fn firmware_capacity(&self) -> usize {
        self.firmware_capacity.get()
    }

    #[cfg(feature = "update")]
    async fn receive_firmware<S: crate::update::boot::Source>(
        &self,
        body: &mut S,
    ) -> Result<crate::io::Version, crate::update::boot::Refused<S::Error>> {
        use crate::update::boot::Refused;
        self.firmware.borrow_mut().clear();
        self.firmware_chunks.borrow_mut().clear();
        while let Some(chunk) = body.chunk().await.map_err(Refused::Source)? {
            self.firmware.borrow_mut().extend_from_slice(chunk);
            self.firmware_chunks.borrow_mut().push(chunk.len());
        }
        match self.firmware_refusal.take() {
            Some(error) => Err(Refused::Update(error)),
            None => Ok(TEST_FIRMWARE_VERSION),
        }
    }
}

/// The settings service the tests' API changes the device through.
pub type TestControl = Controller<'static, TestFlash, TestPlatform>;

/// The API the tests talk to.
pub type TestHttp = Http<'static, TestFlash, TestPlatform>;

/// The settings service over a fresh server and device, and an empty
/// settings flash (all leaked: tests only).
pub fn control() -> &'static TestControl {
    let settings = Settings::DEFAULT;
    let (server, _) = server_with(settings.server_config(TEST_MAC), Watchdog::OFF);
    let fails: &'static Cell<bool> = Box::leak(Box::default());
    let memory: &'static mut [u8] = Box::leak(vec![0xff; 2 * PAGE].into_boxed_slice());
    let flash = Wearing::new(RuleFlash::new(memory), fails);
    let mut store = Store::new(flash, RANGE).expect("two whole pages");
    let loaded = embassy_futures::block_on(store.load(&settings));
    let platform = TestPlatform {
        located: Cell::new(None),
        reboots: Cell::new(0),
        flash_fails: fails,
        records_at_start: Cell::new(0),
        #[cfg(feature = "update")]
        firmware: RefCell::default(),
        #[cfg(feature = "update")]
        firmware_chunks: RefCell::default(),
        #[cfg(feature = "update")]
        firmware_refusal: Cell::new(None),
        #[cfg(feature = "update")]
        firmware_capacity: Cell::new(TEST_FIRMWARE_CAPACITY),
    };
    Box::leak(Box::new(Controller::new(server, platform, store, &loaded)))
}

/// The admin password of [`api`]'s device.
pub const OWNER_PASSWORD: &str = "owner-pass";

/// The API over a fresh [`control`] whose admin password is set to
/// [`OWNER_PASSWORD`], as a device in service is (leaked: tests only):
/// changes need [`owner`]'s credentials.
pub fn api() -> &'static TestHttp {
    let http = unowned_api();
    embassy_futures::block_on(http.control().set_password(OWNER_PASSWORD.as_bytes())).expect("the first password");
    http.control().platform().records_at_start.set(http.control().storage().records);
    http
}

/// The API over a fresh [`control`] with no admin password yet, as a new
/// device is (leaked: tests only).
pub fn unowned_api() -> &'static TestHttp {
    Box::leak(Box::new(Http::new(control(), HTTP_PORT)))
}

/// `Authorization: Basic` for `admin` and [`OWNER_PASSWORD`].
pub fn owner() -> String {
    basic(OWNER_PASSWORD)
}

/// Records saved in the settings flash since the test began (the
/// owner's password [`api`] sets is not counted): each change saved adds
/// one (the settings, or the password).
pub fn saved(http: &TestHttp) -> u32 {
    let control = http.control();
    control.storage().records - control.platform().records_at_start.get()
}

/// A response as the client read it.
#[derive(Debug, Clone)]
pub struct Response {
    pub status: u16,
    pub head: String,
    pub body: Vec<u8>,
}

impl Response {
    /// Splits what the server wrote; `None` when it is not one whole response.
    pub fn parse(bytes: &[u8]) -> Option<Self> {
        let end = bytes.windows(4).position(|w| w == b"\r\n\r\n")?;
        let head = String::from_utf8(bytes[..end].to_vec()).ok()?;
        let status = head.strip_prefix("HTTP/1.1 ")?.get(..3)?.parse().ok()?;
        let body = bytes[end + 4..].to_vec();
        let response = Self { status, head, body };
        let length: usize = response.header("content-length")?.parse().ok()?;
        (length == response.body.len()).then_some(response)
    }

    /// A header's value (the first of that name, any case).
    pub fn header(&self, name: &str) -> Option<&str> {
        self.head.lines().skip(1).find_map(|line| {
            let (n, v) = line.split_once(':')?;
            n.trim().eq_ignore_ascii_case(name).then_some(v.trim())
        })
    }

    /// The body as JSON (the test fails if it is not).
    pub fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("not JSON ({e}): {}", String::from_utf8_lossy(&self.body)))
    }
}

/// What serving one connection gave.
pub type Served = Result<Option<Action>, Error>;

/// One connection being served: the client's wire and the server's future.
pub struct Connection {
    pub wire: Wire,
    future: Pin<Box<dyn Future<Output = Served>>>,
    pub result: Option<Served>,
}

impl Connection {
    /// A connection from `peer` to `http`.
    pub fn open(http: &'static TestHttp, peer: Option<[u8; 4]>) -> Self {
        let (wire, end) = Wire::new();
        let (reader, writer) = end.split();
        let buffers: &'static mut Buffers = Box::leak(Box::default());
        let future = Box::pin(serve(http, peer, reader, writer, buffers));
        Self { wire, future, result: None }
    }

    #[cfg(feature = "tls")]
    /// A connection from `peer` served as HTTPS serves one, request after
    /// request ([`super::serve_kept`]), over the bytes alone (no TLS here).
    pub fn open_kept(http: &'static TestHttp, peer: Option<[u8; 4]>) -> Self {
        let (wire, end) = Wire::new();
        let end: &'static mut test_support::duplex::ServerEnd = Box::leak(Box::new(end));
        let buffers: &'static mut Buffers = Box::leak(Box::default());
        let future = Box::pin(super::serve_kept(http, peer, super::Scheme::Https, end, buffers));
        Self { wire, future, result: None }
    }

    /// Polls the server until it ends or waits (for bytes or for time):
    /// whether it has ended.
    pub fn poll(&mut self) -> bool {
        if self.result.is_none() {
            // Each poll makes progress or waits: a few dozen are plenty.
            for _ in 0..64 {
                if let Poll::Ready(result) = poll_once(self.future.as_mut()) {
                    self.result = Some(result);
                    break;
                }
            }
        }
        self.result.is_some()
    }

    /// Polls, moving the clock on by `step` while the server waits, until it
    /// ends or `limit` has passed: the time it took.
    pub fn run(&mut self, clock: &Clock, step: Duration, limit: Duration) -> Option<Duration> {
        let mut waited = Duration::from_ticks(0);
        loop {
            if self.poll() {
                return Some(waited);
            }
            if waited >= limit {
                return None;
            }
            clock.advance(step);
            waited += step;
        }
    }
}

/// Sends `request` whole from `peer` and serves it to the end (the clock
/// moves on while the server waits): the response and the result.
pub fn exchange(
    http: &'static TestHttp,
    clock: &Clock,
    peer: Option<[u8; 4]>,
    request: &[u8],
) -> (Option<Response>, Served) {
    let mut connection = Connection::open(http, peer);
    connection.wire.send(request);
    let took = connection.run(clock, Duration::from_millis(100), Duration::from_secs(30));
    assert!(took.is_some(), "the connection ends");
    let bytes = connection.wire.take_replies();
    (Response::parse(&bytes), connection.result.unwrap_or(Err(Error::Timeout)))
}

/// The `Host` the tests' requests name: the device's address.
pub const HOST: &str = "10.0.0.1";

/// A request with `body` and the headers given (each ending `\r\n`), as
/// the device's page sends it: `Host` its address, and a change (any method
/// but `GET`) as JSON.
pub fn request(method: &str, path: &str, headers: &str, body: &str) -> Vec<u8> {
    let length = if body.is_empty() { String::new() } else { format!("Content-Length: {}\r\n", body.len()) };
    let json = if method.eq_ignore_ascii_case("GET") { "" } else { "Content-Type: application/json\r\n" };
    format!("{method} {path} HTTP/1.1\r\nHost: {HOST}\r\n{json}{headers}{length}\r\n{body}").into_bytes()
}

/// `Authorization: Basic` for `admin` and `password`.
pub fn basic(password: &str) -> String {
    let plain = format!("admin:{password}");
    let table = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut text = String::new();
    for chunk in plain.as_bytes().chunks(3) {
        let n = chunk.iter().enumerate().fold(0u32, |n, (i, &b)| n | u32::from(b) << (16 - 8 * i));
        for i in 0..4 {
            text.push(if i <= chunk.len() { char::from(table[(n >> (18 - 6 * i) & 63) as usize]) } else { '=' });
        }
    }
    format!("Authorization: Basic {text}\r\n")
}
