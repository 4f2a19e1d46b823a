//! The TLS server of port 802 (firmware/tls: Mbed TLS 3.6's C behind
//! `tls::Session`), configured as the device configures it: the device's
//! certificate and P-256 key, the client CA installed (a client must present
//! a certificate that chains to it), an arena of the device's size. The
//! input is what a client sends.
//!
//! The input ([`TlsInput`]):
//!
//! ```text
//! | flags (1) | n (1, low 4 bits) | n cut sizes | the client's byte stream |
//! ```
//!
//! Reads take the cut sizes in turn (0: as much as the buffer holds), so the
//! record layer sees records whole, split anywhere, or several in one read.
//! Flags: [`TLS_STALL_READS`], [`TLS_PARTIAL_WRITES`] (writes take
//! `1 + cut % 16` bytes, in turn), [`TLS_SECOND_SESSION`].
//!
//! Each input runs `Session::handshake`, then, if it succeeded, reads the
//! application data until the input runs out, echoing it as a server would
//! answer, and closes. The random generator starts anew from a fixed seed
//! before every input ([`fixed_entropy`], `tls::rng::init`), so an input
//! meets the same random numbers whatever ran before it: a crash reproduces
//! from its input alone, and a client flight recorded against this server
//! ([`seeds`]) completes its handshake again when replayed, so the fuzzer
//! starts from whole sessions (client certificates, Finished, application
//! data), not only from ClientHellos.
//!
//! What is checked, besides AddressSanitizer's checks (the C is built with
//! them too, and with libFuzzer's coverage: `fuzz/clang-fuzz`):
//!
//! - The session ends, with an error or after the stream's end, and never
//!   waits with all of its input there and nothing stalled.
//! - A handshake that succeeds was in TLS 1.2 or 1.3, with a client
//!   certificate issued by the client CA (its issuer is the CA's subject,
//!   read by the certificate crate, not by Mbed TLS).
//! - Everything the server wrote is whole TLS records (type 20-23, version
//!   3.x, at most the device's 4 KiB of content and the protection's bytes).
//! - Once the session is dropped, the arena holds what it held before: no
//!   leak, whatever the input did (the other session of
//!   [`TLS_SECOND_SESSION`] included).

use core::pin::pin;
use core::task::Poll;
use std::sync::atomic::{AtomicBool, Ordering};

use embedded_io_async::{Read, Write};
use test_support::duplex::{Wire, poll_once};
use tls::{Credentials, Server, Session};

use crate::connection;

/// Flags bit 0: every read is `Pending` once before it returns data.
pub const TLS_STALL_READS: u8 = 1 << 0;
/// Bit 1: every write is `Pending` once, then takes only part of the bytes.
pub const TLS_PARTIAL_WRITES: u8 = 1 << 1;
/// Bit 2: another session of the server is open (set up, its record
/// buffers in the arena) while this one runs, as on a device serving two
/// secure connections: the handshake's peak then meets the arena's end.
pub const TLS_SECOND_SESSION: u8 = 1 << 2;

/// The device's TLS arena: `adapter::program::TLS_ARENA_LEN` (the
/// adapter's `tls` feature, which the other targets' adapter is built
/// without): 8 KiB for the configurations, 34 KiB for one handshake's
/// peak, 30 KiB for the other session.
pub const ARENA_LEN: usize = 72 * 1024;

/// The fixtures of the tls crate's tests: the device's certificate and key,
/// and the CA of the clients' certificates.
const DEVICE_CERTIFICATE: &[u8] = include_bytes!("../../firmware/tls/tests/fixtures/device.der");
const DEVICE_KEY: &[u8] = include_bytes!("../../firmware/tls/tests/fixtures/device.key.der");
const CLIENT_CA: &[u8] = include_bytes!("../../firmware/tls/tests/fixtures/client-ca.der");

/// The application data read at a time: a Modbus frame's most (260 bytes),
/// as the secure session reads it.
const READ_LEN: usize = 260;

/// Bound on polls of one session: every `Pending` must come from the
/// connection, which stalls at most once per read or write.
const MAX_POLLS: usize = 1 << 20;

/// The device's records carry at most 4 KiB of content
/// (`ssl-out-content-len-4096`); protection adds at most 256 bytes (the
/// limit RFC 8446 5.2 sets on expansion).
const MAX_RECORD_LEN: usize = 4096 + 256;

/// The tls target's input, split: the http target's layout (flags, the
/// cut sizes, the client's byte stream), its flags the `TLS_*` ones.
pub type TlsInput<'a> = crate::input::HttpInput<'a>;

/// The entropy source: the same bytes on every call (SplitMix64 from a
/// fixed seed), so the generator seeded from it draws the same numbers
/// after every start.
pub fn fixed_entropy(buf: &mut [u8]) -> bool {
    let mut state: u64 = 0x6d62_696f_2d38_3032;
    for chunk in buf.chunks_mut(8) {
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        for (byte, value) in chunk.iter_mut().zip(z.to_le_bytes()) {
            *byte = value;
        }
    }
    true
}

static STARTED: AtomicBool = AtomicBool::new(false);

thread_local! {
    /// The arena, the generator and the server's configuration, made once
    /// (`tls::init` may run once a process): on the thread that runs the
    /// inputs, the only one that does.
    static SERVER: &'static Server = start();
}

fn start() -> &'static Server {
    assert!(!STARTED.swap(true, Ordering::SeqCst), "the tls target runs on one thread");
    let arena: &'static mut [u8] = Box::leak(vec![0u8; ARENA_LEN].into_boxed_slice());
    tls::init([arena], fixed_entropy).unwrap_or_else(|e| panic!("tls::init: {e}"));
    let credentials = Credentials { certificate: DEVICE_CERTIFICATE, key: DEVICE_KEY, client_ca: Some(CLIENT_CA) };
    let server = Server::new(&credentials).unwrap_or_else(|e| panic!("the device's configuration: {e}"));
    assert!(server.verifies_clients());
    Box::leak(Box::new(server))
}

/// What one session came to.
#[derive(Debug, PartialEq, Eq)]
pub struct Outcome {
    pub handshake: Result<(), tls::Error>,
    /// `TLSv1.2` or `TLSv1.3` when the handshake succeeded.
    pub version: Option<&'static str>,
    /// The client certificate's DER.
    pub peer: Option<Vec<u8>>,
    /// The application data read (and echoed).
    pub data: Vec<u8>,
}

/// One input.
pub fn tls(data: &[u8]) {
    let input = TlsInput::parse(data);
    let _ = serve(&input);
}

/// Serves `input`'s stream on the in-memory connection and checks it.
pub fn serve(input: &TlsInput<'_>) -> Outcome {
    let server = SERVER.with(|server| *server);
    let before = tls::arena::usage().used;
    let outcome = {
        // The other session only holds its buffers: it is never driven.
        let other = (input.flags & TLS_SECOND_SESSION != 0).then(|| {
            let (_, end) = Wire::new();
            Session::new(server, end).unwrap_or_else(|e| panic!("a second session fits the device's arena: {e}"))
        });
        assert!(tls::rng::init(fixed_entropy), "the generator starts from the fixed seed");
        let stall_reads = input.flags & TLS_STALL_READS != 0;
        let (wire, end) =
            connection::shaped(input.stream, input.cuts, stall_reads, input.flags & TLS_PARTIAL_WRITES != 0);
        wire.close();
        let mut session = Session::new(server, end)
            .unwrap_or_else(|e| panic!("a session fits the device's arena beside another: {e}"));
        let outcome = {
            let mut exchange = pin!(exchange(&mut session, input.stream.len()));
            let mut polls = 0;
            loop {
                let before = wire.stalls();
                match poll_once(exchange.as_mut()) {
                    Poll::Ready(outcome) => break outcome,
                    Poll::Pending => {
                        assert!(wire.stalls() > before, "the session waits with all input there and nothing stalled");
                        polls += 1;
                        assert!(polls < MAX_POLLS, "the session never ends");
                    }
                }
            }
        };
        drop(session);
        drop(other);
        check_records(&wire.take_replies());
        outcome
    };
    assert_eq!(tls::arena::usage().used, before, "the session left memory in the arena ({outcome:?})");
    if outcome.handshake.is_ok() {
        assert!(matches!(outcome.version, Some("TLSv1.2" | "TLSv1.3")), "version {:?}", outcome.version);
        let peer = outcome.peer.as_deref().unwrap_or_else(|| panic!("a session without a client certificate"));
        let peer = certificate::Certificate::parse(peer).unwrap_or_else(|e| panic!("the client's certificate: {e}"));
        let ca = certificate::Certificate::parse(CLIENT_CA).unwrap_or_else(|e| panic!("the client CA: {e}"));
        assert_eq!(peer.issuer, ca.subject, "a client certificate the CA did not issue");
    }
    outcome
}

/// The session as the device runs one: the handshake, then application
/// data read and answered (echoed) until the stream ends or fails, then
/// close_notify. `len`: the input's length, a bound on the reads.
async fn exchange<S: Read + Write>(session: &mut Session<'_, S>, len: usize) -> Outcome {
    let handshake = session.handshake().await;
    let mut outcome = Outcome { handshake, version: None, peer: None, data: Vec::new() };
    if outcome.handshake.is_err() {
        return outcome;
    }
    outcome.version = Some(session.version());
    outcome.peer = session.peer_certificate().map(<[u8]>::to_vec);
    let mut buf = [0u8; READ_LEN];
    let mut reads = 0;
    loop {
        reads += 1;
        assert!(reads <= len + 2, "a read that took nothing and did not end");
        match session.read(&mut buf).await {
            Ok(0) | Err(_) => break,
            Ok(n) => {
                let data = buf.get(..n).unwrap_or_else(|| panic!("a read of {n} bytes into {READ_LEN}"));
                outcome.data.extend_from_slice(data);
                if session.write_all(data).await.is_err() || session.flush().await.is_err() {
                    break;
                }
            }
        }
    }
    let _ = session.close().await;
    outcome
}

/// Everything the server wrote splits into whole TLS records.
fn check_records(mut out: &[u8]) {
    while !out.is_empty() {
        let [kind, major, _minor, high, low, rest @ ..] = out else {
            panic!("the server's output ends inside a record header: {out:02x?}")
        };
        assert!((20..=23).contains(kind), "a record of type {kind}");
        assert_eq!(*major, 3, "a record of version {major}.x");
        let len = usize::from(u16::from_be_bytes([*high, *low]));
        assert!(len <= MAX_RECORD_LEN, "a record of {len} bytes");
        assert!(len <= rest.len(), "the server's output ends inside a record of {len} bytes");
        out = rest.get(len..).unwrap_or(&[]);
    }
}

/// The first record of `stream` (a client's first flight: its ClientHello).
fn first_record(stream: &[u8]) -> &[u8] {
    let len = match stream {
        [_, _, _, high, low, ..] => 5 + usize::from(u16::from_be_bytes([*high, *low])),
        _ => stream.len(),
    };
    stream.get(..len).unwrap_or(stream)
}

/// The seeds: what `openssl s_client` sends this server (TLS 1.2 and 1.3,
/// with and without a client certificate, one from another CA), each
/// recorded now over real TCP on 127.0.0.1 ([`capture`]) and replayed here
/// to the same end; each plain, cut and stalled, beside a second session,
/// and its first record (the ClientHello) alone.
pub fn seeds() -> Vec<Vec<u8>> {
    // (s_client's arguments, whether the handshake completes)
    let clients: [(&[&str], bool); 10] = [
        (&["-tls1_3", "-cert", "operator.pem", "-key", "operator.key"], true),
        (&["-tls1_3", "-groups", "P-256", "-cert", "viewer.pem", "-key", "viewer.key"], true),
        (&["-cert", "norole.pem", "-key", "norole.key"], true),
        (&["-tls1_2", "-cert", "viewer.pem", "-key", "viewer.key"], true),
        (&["-tls1_2", "-cert", "operator.pem", "-key", "operator.key", "-no_ticket"], true),
        (&["-tls1_3"], false),
        (&["-tls1_2"], false),
        (&["-tls1_3", "-cert", "stranger.pem", "-key", "stranger.key"], false),
        (&["-tls1_2", "-cert", "stranger.pem", "-key", "stranger.key"], false),
        (&["-tls1_3", "-groups", "P-384:P-521"], false),
    ];
    let mut seeds = Vec::new();
    for (args, completes) in clients {
        let (stream, captured) = capture(args);
        let plain = TlsInput { flags: 0, cuts: &[], stream: &stream };
        let replayed = serve(&plain);
        assert_eq!(replayed.handshake.is_ok(), completes, "s_client {args:?}: {replayed:?}");
        assert_eq!(replayed, captured, "s_client {args:?}: the replay differs from the session recorded");
        if completes {
            assert!(!replayed.data.is_empty(), "s_client {args:?}: no application data");
        }
        seeds.push(plain.to_bytes());
        let cut = [1, 0, 7, 200, 3];
        seeds.push(TlsInput { flags: TLS_STALL_READS | TLS_PARTIAL_WRITES, cuts: &cut, stream: &stream }.to_bytes());
        seeds.push(TlsInput { flags: TLS_SECOND_SESSION, cuts: &[100], stream: &stream }.to_bytes());
        seeds.push(TlsInput { flags: 0, cuts: &[], stream: first_record(&stream) }.to_bytes());
    }
    seeds
}

/// Serves one `openssl s_client` run with `args` (and the tls crate's
/// test fixtures) over TCP on 127.0.0.1 as [`serve`] serves an input, and
/// returns what the client sent, and what the session came to.
fn capture(args: &[&str]) -> (Vec<u8>, Outcome) {
    use std::io::Write as _;
    use std::process::{Command, Stdio};

    let fixtures = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware/tls/tests/fixtures");
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap_or_else(|e| panic!("listening: {e}"));
    let port = listener.local_addr().unwrap_or_else(|e| panic!("the port: {e}")).port();
    let mut client = Command::new("openssl")
        .args(["s_client", "-connect", &format!("127.0.0.1:{port}"), "-CAfile", "device.pem"])
        .args(["-verify_return_error", "-servername", "mbio-test.local"])
        .args(args)
        .current_dir(&fixtures)
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap_or_else(|e| panic!("openssl s_client (scripts/setup installs openssl): {e}"));
    let mut stdin = client.stdin.take().unwrap_or_else(|| panic!("s_client's stdin"));
    // s_client sends its stdin once the handshake is done, and closes on its end.
    let writer = std::thread::spawn(move || {
        let _ = stdin.write_all(b"read coils\n");
        std::thread::sleep(std::time::Duration::from_millis(300));
        let _ = stdin.write_all(b"\x00\x01\x00\x00\x00\x06\x01\x01\x00\x00\x00\x10\n");
        std::thread::sleep(std::time::Duration::from_millis(300));
    });
    let (socket, _) = listener.accept().unwrap_or_else(|e| panic!("accepting s_client: {e}"));
    socket.set_read_timeout(Some(std::time::Duration::from_secs(10))).unwrap_or_else(|e| panic!("{e}"));
    let server = SERVER.with(|server| *server);
    assert!(tls::rng::init(fixed_entropy), "the generator starts from the fixed seed");
    let mut recording = Recording { socket, read: Vec::new() };
    let outcome = {
        let mut session = Session::new(server, &mut recording).unwrap_or_else(|e| panic!("a session: {e}"));
        let len = usize::MAX / 4;
        embassy_futures::block_on(exchange(&mut session, len))
    };
    drop(recording.socket);
    let _ = writer.join();
    let _ = client.wait();
    (recording.read, outcome)
}

/// A blocking socket as an `embedded-io-async` stream, keeping what it read.
struct Recording {
    socket: std::net::TcpStream,
    read: Vec<u8>,
}

impl embedded_io_async::ErrorType for Recording {
    type Error = embedded_io_async::ErrorKind;
}

impl Read for Recording {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let n = std::io::Read::read(&mut self.socket, buf).map_err(|_| embedded_io_async::ErrorKind::Other)?;
        self.read.extend_from_slice(buf.get(..n).unwrap_or(&[]));
        Ok(n)
    }
}

impl Write for Recording {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        std::io::Write::write(&mut self.socket, buf).map_err(|_| embedded_io_async::ErrorKind::Other)
    }

    async fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}
