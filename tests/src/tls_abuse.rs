//! Abuse of port 802 (Modbus/TCP Security) while a watcher polls plain
//! Modbus on 502: what `tests/hal_sim_tls_abuse.rs` and
//! `tests/qemu_tls_abuse.rs` share.
//!
//! [`abuse_802`] runs the abuse in phases, one after the other, on the
//! device at [`DEVICE_IP`] inside the test's namespace, while a
//! [`Watcher`] on a thread of its own reads holding registers on 502 over
//! one connection, request after request, and times each:
//!
//! 1. **half-open**: connections that connect and send nothing, and ones
//!    that send half a real ClientHello and stall, kept up (and opened
//!    again when the device closes or refuses them) for longer than the
//!    device's handshake timeout;
//! 2. **slow**: a real handshake (python's ssl, an operator's certificate)
//!    sent a byte at a time, once fast enough to finish inside the
//!    handshake timeout and once too slow to;
//! 3. **flood**: [`FLOOD_RATE`] handshakes a second from python's ssl for
//!    [`FLOOD_SECONDS`], with an operator's certificate, another CA's and
//!    none, in turn;
//! 4. **garbage**: random bytes, record headers with huge lengths, other
//!    malformed records, and real ClientHellos followed by junk;
//!
//! and then a quiet while (**after**). The TLS side is python's ssl
//! (tests/peers/tls_abuse.py); the raw TCP side is tokio here.

use std::net::{Ipv4Addr, SocketAddr};
use std::path::Path;
use std::process::Stdio;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde_json::Value;
use tokio::io::AsyncWriteExt;
use tokio_modbus::prelude::*;

use crate::abuse::Rng;
use crate::hal_sim::{End, end_within};
use crate::netns::{DEVICE_IP, Namespace};
use crate::tls::fixtures;

/// The longest a request on 502 may take, abuse or not.
pub const LIMIT: Duration = Duration::from_secs(2);
/// The secure port.
pub const SECURE_PORT: u16 = 802;
/// The device's handshake timeout (`adapter::server::secure::HANDSHAKE_TIMEOUT`).
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);
/// The longest the device may keep a connection that sends garbage or
/// stalls: its handshake timeout, and 2 s for the device's and the
/// client's own delays.
pub const CLOSE_LIMIT: Duration = Duration::from_secs(12);
/// The flood: handshakes started each second, and for how long.
pub const FLOOD_RATE: u32 = 100;
pub const FLOOD_SECONDS: u32 = 5;
/// The half-open phase: connections kept at once, and for how long (past
/// the handshake timeout, so the device's closing them is seen).
pub const HALF_OPEN_CONNECTIONS: usize = 12;
pub const HALF_OPEN_TIME: Duration = Duration::from_secs(13);
/// How long a watched request may take before the watcher gives up on it
/// (a request that long has failed the test anyway).
const HARD_LIMIT: Duration = Duration::from_secs(15);
/// The watcher's pause between two requests.
const POLL_PAUSE: Duration = Duration::from_millis(10);

/// A socket address of the device.
pub fn device(port: u16) -> SocketAddr {
    let ip: Ipv4Addr = DEVICE_IP.parse().expect("DEVICE_IP is an IPv4 address");
    SocketAddr::from((ip, port))
}

/// The requests of one phase as the watcher saw them.
#[derive(Debug, Clone, Default)]
pub struct PhaseStats {
    pub name: String,
    pub requests: usize,
    pub worst: Duration,
    pub total: Duration,
    /// Requests that took longer than [`LIMIT`], and how long.
    pub over_limit: Vec<Duration>,
}

/// What the watcher saw, phase by phase.
#[derive(Debug, Clone, Default)]
pub struct WatchReport {
    pub phases: Vec<PhaseStats>,
    /// Why the watcher stopped before it was told to: an error, a reply
    /// that never came, the connection closed or reset.
    pub failure: Option<String>,
}

impl WatchReport {
    pub fn requests(&self) -> usize {
        self.phases.iter().map(|p| p.requests).sum()
    }

    pub fn worst(&self) -> Duration {
        self.phases.iter().map(|p| p.worst).max().unwrap_or_default()
    }

    /// The report as a table, a phase a line.
    pub fn table(&self) -> String {
        let mut text = String::from("phase       requests on 502   worst      mean\n");
        for p in &self.phases {
            let mean = if p.requests == 0 { Duration::ZERO } else { p.total / p.requests as u32 };
            text.push_str(&format!(
                "{:<11} {:>15}   {:>7.1} ms {:>7.1} ms\n",
                p.name,
                p.requests,
                p.worst.as_secs_f64() * 1e3,
                mean.as_secs_f64() * 1e3
            ));
        }
        text.push_str(&format!("all         {:>15}   {:>7.1} ms\n", self.requests(), self.worst().as_secs_f64() * 1e3));
        text
    }

    /// Fails unless every request was answered on the one connection,
    /// none took longer than `limit`, and every phase saw requests.
    pub fn assert_within(&self, limit: Duration) {
        assert!(self.failure.is_none(), "the watcher on 502 failed: {:?}\n{}", self.failure, self.table());
        for p in &self.phases {
            assert!(p.requests > 0, "no request on 502 was answered during {}:\n{}", p.name, self.table());
            let over: Vec<_> = p.over_limit.iter().filter(|&&d| d > limit).collect();
            assert!(
                over.is_empty(),
                "{} requests on 502 took longer than {limit:?} during {}: {over:?}\n{}",
                over.len(),
                p.name,
                self.table()
            );
            assert!(p.worst <= limit, "a request on 502 took {:?} during {}:\n{}", p.worst, p.name, self.table());
        }
    }
}

/// The phase the abuse is in, which the watcher files its requests under.
#[derive(Debug)]
pub struct Phase {
    name: Mutex<String>,
    stop: AtomicBool,
}

impl Phase {
    /// Starts phase `name`.
    pub fn set(&self, name: &str) {
        eprintln!("tls abuse: phase {name}");
        *self.name.lock().unwrap() = name.to_owned();
    }

    fn get(&self) -> String {
        self.name.lock().unwrap().clone()
    }
}

/// Sets the stop flag when dropped: the watcher ends even if the abuse panics.
struct StopOnDrop<'a>(&'a AtomicBool);

impl Drop for StopOnDrop<'_> {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

/// Runs `abuse` while a watcher, on a thread of its own inside `ns`, reads
/// holding registers 128-131 at `modbus` over one tokio-modbus connection,
/// request after request, [`POLL_PAUSE`] apart, timing each. Returns what
/// `abuse` returned and what the watcher saw.
pub fn watched<T: Send>(
    ns: &Namespace,
    modbus: SocketAddr,
    abuse: impl FnOnce(&Phase) -> T + Send,
) -> (T, WatchReport) {
    let phase = Phase { name: Mutex::new("before".to_owned()), stop: AtomicBool::new(false) };
    std::thread::scope(|scope| {
        let watcher = scope.spawn(|| {
            ns.enter().expect("the watcher enters the namespace");
            let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("a tokio runtime");
            runtime.block_on(watch(modbus, &phase))
        });
        let result = {
            let _stop = StopOnDrop(&phase.stop);
            abuse(&phase)
        };
        let report = match watcher.join() {
            Ok(report) => report,
            Err(panic) => std::panic::resume_unwind(panic),
        };
        (result, report)
    })
}

async fn watch(modbus: SocketAddr, phase: &Phase) -> WatchReport {
    let mut report = WatchReport::default();
    let mut ctx = match crate::modbus_answers(modbus, 128, Duration::from_secs(5)).await {
        Ok(ctx) => ctx,
        Err(error) => {
            report.failure = Some(format!("the watcher could not connect to {modbus}: {error}"));
            return report;
        }
    };
    while !phase.stop.load(Ordering::Relaxed) {
        let name = phase.get();
        if report.phases.last().is_none_or(|p| p.name != name) {
            report.phases.push(PhaseStats { name: name.clone(), ..PhaseStats::default() });
        }
        let started = Instant::now();
        let outcome = tokio::time::timeout(HARD_LIMIT, ctx.read_holding_registers(128, 4)).await;
        let took = started.elapsed();
        let stats = report.phases.last_mut().expect("a phase");
        match outcome {
            Ok(Ok(Ok(values))) if values.len() == 4 => {
                stats.requests += 1;
                stats.total += took;
                stats.worst = stats.worst.max(took);
                if took > LIMIT {
                    stats.over_limit.push(took);
                }
            }
            other => {
                let request = report.requests() + 1;
                report.failure = Some(format!("request {request} (phase {name}) after {took:?}: {other:?}"));
                break;
            }
        }
        tokio::time::sleep(POLL_PAUSE).await;
    }
    report
}

/// tests/peers/tls_abuse.py with `args`, inside `ns`: its JSON line.
pub fn peer(ns: &Namespace, args: &[&str]) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("peers/tls_abuse.py");
    let output = ns.command("python3").arg(&script).args(args).stdin(Stdio::null()).output().expect("python3 runs");
    let stdout = String::from_utf8_lossy(&output.stdout);
    serde_json::from_str(stdout.trim()).unwrap_or_else(|e| {
        panic!("tls_abuse.py {args:?} printed no JSON ({e}):\n{stdout}\n{}", String::from_utf8_lossy(&output.stderr))
    })
}

/// A real ClientHello, as python's ssl sends it to the device.
pub fn client_hello() -> Vec<u8> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("peers/tls_abuse.py");
    let output = std::process::Command::new("python3").arg(&script).args(["hello", DEVICE_IP]).output().unwrap();
    let hex = String::from_utf8_lossy(&output.stdout);
    let hex = hex.trim();
    assert!(hex.len() > 100 && hex.starts_with("16"), "a ClientHello record: {hex:?}");
    (0..hex.len()).step_by(2).map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap()).collect()
}

/// `GET /api/status` through curl inside `ns` (port 80).
pub fn status(ns: &Namespace) -> Value {
    let output = ns
        .command("curl")
        .args(["-sS", "-m", "10", &format!("http://{DEVICE_IP}/api/status")])
        .stdin(Stdio::null())
        .output()
        .expect("curl runs");
    serde_json::from_slice(&output.stdout).unwrap_or_else(|e| {
        panic!("/api/status is not JSON ({e}): {:?} {}", output.stdout, String::from_utf8_lossy(&output.stderr))
    })
}

/// A counter of `/api/status`.
pub fn counter(status: &Value, name: &str) -> u64 {
    status["counters"][name].as_u64().unwrap_or_else(|| panic!("no counter {name} in {status}"))
}

/// What the half-open connections met.
#[derive(Debug, Default)]
pub struct HalfOpen {
    /// Connections the device accepted.
    pub accepted: usize,
    /// Connections it refused (no socket listening on 802 at that moment).
    pub refused: usize,
    /// Accepted ones it closed (or reset) while they stalled, and the
    /// longest and shortest it kept one.
    pub closed: usize,
    pub longest_kept: Duration,
    pub shortest_kept: Option<Duration>,
    /// Accepted ones still open when the phase ended.
    pub open_at_end: usize,
}

/// Keeps [`HALF_OPEN_CONNECTIONS`] connections to 802 for [`HALF_OPEN_TIME`]:
/// the even ones send nothing, the odd ones the first half of `hello`; each
/// waits for the device to close it, and opens again 200 ms after a close
/// or a refusal. Call it inside [`crate::run_client`].
pub async fn half_open(hello: &[u8]) -> HalfOpen {
    let deadline = tokio::time::Instant::now() + HALF_OPEN_TIME;
    let results = Arc::new(Mutex::new(HalfOpen::default()));
    let half = Arc::new(hello[..hello.len() / 2].to_vec());
    let mut tasks = tokio::task::JoinSet::new();
    for i in 0..HALF_OPEN_CONNECTIONS {
        let (results, half) = (results.clone(), half.clone());
        tasks.spawn(async move {
            while tokio::time::Instant::now() < deadline {
                let connect = tokio::net::TcpStream::connect(device(SECURE_PORT));
                let mut stream = match tokio::time::timeout(Duration::from_secs(2), connect).await {
                    Ok(Ok(stream)) => stream,
                    _ => {
                        results.lock().unwrap().refused += 1;
                        tokio::time::sleep(Duration::from_millis(200)).await;
                        continue;
                    }
                };
                results.lock().unwrap().accepted += 1;
                let opened = Instant::now();
                if i % 2 == 1 {
                    let _ = stream.write_all(&half).await;
                }
                let end = loop {
                    let left = deadline.saturating_duration_since(tokio::time::Instant::now());
                    match end_within(&mut stream, left).await {
                        End::Bytes(_) => {}
                        end => break end,
                    }
                };
                let kept = opened.elapsed();
                {
                    let mut results = results.lock().unwrap();
                    if end.is_closed() {
                        results.closed += 1;
                        results.longest_kept = results.longest_kept.max(kept);
                        results.shortest_kept = Some(results.shortest_kept.map_or(kept, |s| s.min(kept)));
                    } else {
                        results.open_at_end += 1;
                    }
                }
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
        });
    }
    while let Some(done) = tasks.join_next().await {
        done.expect("a half-open client");
    }
    std::mem::take(&mut *results.lock().unwrap())
}

/// How the device ended one garbage connection.
#[derive(Debug)]
pub struct GarbageEnd {
    pub what: &'static str,
    pub end: End,
    /// Bytes the device sent first (an alert, say).
    pub replied: usize,
    pub after: Duration,
}

/// The garbage: a name and the bytes, each sent on a connection of its own.
pub fn garbage_payloads(hello: &[u8], rng: &mut Rng) -> Vec<(&'static str, Vec<u8>)> {
    let with = |head: &[u8], tail: Vec<u8>| [head, &tail].concat();
    vec![
        ("random 16 bytes", rng.bytes(16)),
        ("random 600 bytes", rng.bytes(600)),
        ("random 5000 bytes", rng.bytes(5000)),
        ("handshake record of length 65535", with(&[0x16, 0x03, 0x01, 0xff, 0xff], rng.bytes(2000))),
        ("application data record of length 65535", with(&[0x17, 0x03, 0x03, 0xff, 0xff], rng.bytes(2000))),
        ("record of an unknown type", with(&[0x63, 0x03, 0x03, 0x00, 0x10], rng.bytes(16))),
        ("ClientHello of length 16 MiB", with(&[0x16, 0x03, 0x01, 0x00, 0x40, 0x01, 0xff, 0xff, 0xff], rng.bytes(60))),
        ("500 empty handshake records", [0x16, 0x03, 0x01, 0x00, 0x00].repeat(500)),
        ("an alert before the handshake", vec![0x15, 0x03, 0x03, 0x00, 0x02, 0x02, 0x28]),
        ("an SSLv2 ClientHello", {
            let mut v = vec![0x80, 0x2e, 0x01, 0x00, 0x02, 0x00, 0x15, 0x00, 0x00, 0x00, 0x10];
            v.extend(rng.bytes(0x2e - 9));
            v
        }),
        ("an HTTP request", b"GET / HTTP/1.1\r\nHost: 198.18.0.2\r\n\r\n".to_vec()),
        ("a Modbus request", vec![0, 1, 0, 0, 0, 6, 1, 3, 0, 128, 0, 4]),
        ("a ClientHello cut and followed by junk", with(&hello[..hello.len() / 2], rng.bytes(3000))),
        ("a ClientHello with its bytes flipped", {
            let mut v = hello.to_vec();
            for i in (9..v.len()).step_by(7) {
                v[i] ^= 0x5a;
            }
            v
        }),
    ]
}

/// Sends each of [`garbage_payloads`] on a connection of its own, one after
/// the other, and waits (up to [`CLOSE_LIMIT`] and 3 s) for the device to
/// end it. Call it inside [`crate::run_client`].
pub async fn garbage(hello: &[u8], seed: u64) -> Vec<GarbageEnd> {
    let mut rng = Rng::new(seed);
    let mut ends = Vec::new();
    for (what, bytes) in garbage_payloads(hello, &mut rng) {
        // A socket on 802 may still be closing the last one: try for 5 s.
        let mut stream = None;
        for _ in 0..50 {
            if let Ok(s) = tokio::net::TcpStream::connect(device(SECURE_PORT)).await {
                stream = Some(s);
                break;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        let mut stream = stream.unwrap_or_else(|| panic!("802 accepted no connection for the garbage {what:?}"));
        stream.set_nodelay(true).unwrap();
        let started = Instant::now();
        let _ = stream.write_all(&bytes).await;
        let mut replied = 0;
        let end = loop {
            let left = (CLOSE_LIMIT + Duration::from_secs(3)).saturating_sub(started.elapsed());
            match end_within(&mut stream, left).await {
                End::Bytes(b) => replied += b.len(),
                end => break end,
            }
        };
        ends.push(GarbageEnd { what, end, replied, after: started.elapsed() });
    }
    ends
}

/// What [`abuse_802`] did and saw.
#[derive(Debug)]
pub struct Summary {
    pub watch: WatchReport,
    pub half_open: HalfOpen,
    pub slow: Vec<Value>,
    pub flood: Value,
    pub garbage: Vec<GarbageEnd>,
    pub hello_junk: Value,
    pub took: Duration,
}

impl Summary {
    /// Everything, for the test's output.
    pub fn print(&self) {
        eprintln!(
            "tls abuse on 802, {:.1} s; Modbus on 502 meanwhile:\n{}",
            self.took.as_secs_f64(),
            self.watch.table()
        );
        eprintln!("half-open: {:?}", self.half_open);
        for slow in &self.slow {
            eprintln!("slow handshake: {slow}");
        }
        eprintln!("flood ({FLOOD_RATE}/s for {FLOOD_SECONDS} s): {}", self.flood);
        for end in &self.garbage {
            eprintln!(
                "garbage {:?}: {:?} after {:.0} ms ({} bytes from the device)",
                end.what,
                end.end,
                end.after.as_secs_f64() * 1e3,
                end.replied
            );
        }
        eprintln!("ClientHello and junk: {}", self.hello_junk);
    }

    /// What holds whatever the device: every garbage connection and every
    /// stalled one was closed by the device, the slow handshake inside the
    /// handshake timeout got through and the one past it did not, and the
    /// flood's clients all finished.
    pub fn assert_device_coped(&self) {
        for end in &self.garbage {
            assert!(end.end.is_closed(), "the device did not close the garbage {:?}: {:?}", end.what, end.end);
            assert!(end.after <= CLOSE_LIMIT, "the device kept the garbage {:?} for {:?}", end.what, end.after);
        }
        assert!(self.half_open.accepted > 0, "802 accepted none of the half-open connections: {:?}", self.half_open);
        assert!(
            self.half_open.closed > 0,
            "the device closed none of the stalled connections in {HALF_OPEN_TIME:?}: {:?}",
            self.half_open
        );
        assert!(
            self.half_open.longest_kept <= CLOSE_LIMIT,
            "a stalled connection was kept past the handshake timeout: {:?}",
            self.half_open
        );
        assert_eq!(self.slow[0]["result"], "handshake_done", "the byte-a-time handshake: {}", self.slow[0]);
        assert_ne!(self.slow[1]["result"], "handshake_done", "the handshake past the timeout: {}", self.slow[1]);
        assert_eq!(self.flood["unfinished"], 0, "the flood's clients all finished: {}", self.flood);
        assert_eq!(self.hello_junk["closed"].as_u64().unwrap_or(0) + self.hello_junk["reset"].as_u64().unwrap_or(0), 5);
    }
}

/// The abuse of port 802 in its phases (module docs), watched on 502 at
/// `modbus`. `slow_fast_ms`: the slow handshake's pause between two bytes
/// when it is to finish inside the handshake timeout (the device's speed
/// decides it).
pub fn abuse_802(ns: &Namespace, modbus: SocketAddr, slow_fast_ms: u32) -> Summary {
    let hello = client_hello();
    let fixtures = fixtures();
    let fixtures = fixtures.to_str().unwrap();
    let (operator, operator_key) = (crate::tls::fixture("operator.pem"), crate::tls::fixture("operator.key"));
    let started = Instant::now();
    let (summary, watch) = watched(ns, modbus, |phase| {
        // A quiet start, to see the ordinary round trip.
        std::thread::sleep(Duration::from_secs(2));

        phase.set("half-open");
        let half_open = crate::run_client(Some(ns), || half_open(&hello));

        phase.set("slow");
        let fast = slow_fast_ms.to_string();
        let limit = (HANDSHAKE_TIMEOUT.as_secs() + 5).to_string();
        let done = peer(ns, &["slow", DEVICE_IP, "802", &operator, &operator_key, &fast, &limit]);
        let timed_out = peer(ns, &["slow", DEVICE_IP, "802", &operator, &operator_key, "50", &limit]);

        phase.set("flood");
        let flood =
            peer(ns, &["flood", DEVICE_IP, "802", &FLOOD_RATE.to_string(), &FLOOD_SECONDS.to_string(), fixtures]);

        phase.set("garbage");
        let garbage = crate::run_client(Some(ns), || garbage(&hello, 0x7463_6c73));
        let hello_junk = peer(ns, &["hello-junk", DEVICE_IP, "802", "5"]);

        phase.set("after");
        std::thread::sleep(Duration::from_secs(3));
        (half_open, vec![done, timed_out], flood, garbage, hello_junk)
    });
    let (half_open, slow, flood, garbage, hello_junk) = summary;
    Summary { watch, half_open, slow, flood, garbage, hello_junk, took: started.elapsed() }
}

/// Fails unless the device kept running through the abuse: its uptime
/// (`/api/status`, seconds since it started) grew by the time between the
/// two looks, less a second for rounding; a restart would have set it back.
pub fn assert_not_restarted(before: &Value, after: &Value, between: Duration) {
    let uptime = |status: &Value| status["device"]["uptime_s"].as_u64().expect("uptime_s in /api/status");
    let (before, after) = (uptime(before), uptime(after));
    eprintln!("uptime: {before} s before the abuse, {after} s after ({:.1} s between)", between.as_secs_f64());
    assert!(
        after + 1 >= before + between.as_secs(),
        "the device restarted: uptime {before} s, then {after} s {between:?} later"
    );
}

/// The TLS counters of `/api/status` before and after, printed; fails
/// unless the abuse moved `tls_failed` and `tls_refused`.
pub fn assert_counters_moved(before: &Value, after: &Value) {
    let names = ["tls_sessions", "tls_failed", "tls_refused", "refused_connections", "evictions"];
    for name in names {
        eprintln!("{name}: {} -> {}", counter(before, name), counter(after, name));
    }
    for name in ["tls_failed", "tls_refused", "tls_sessions"] {
        assert!(counter(after, name) > counter(before, name), "{name} did not move: {}", after["counters"]);
    }
}
