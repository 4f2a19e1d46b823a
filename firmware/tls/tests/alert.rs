//! A record that fails its check gets a whole bad_record_mac alert back,
//! even when the alert does not fit what is left of the session's pipe
//! (found by the tls fuzz target, docs/fuzzing.md).
//!
//! Mbed TLS sends that alert and returns the error whether or not the alert
//! went out whole; the session hands the rest to the stream before it
//! returns. To get there, a TLS 1.3 client flight with a corrupt first
//! encrypted record is given all at once: the server writes its flight, reads
//! the record and answers with the alert in one call, with no wait (and so
//! no flush) in between. The flight (after a HelloRetryRequest) is about
//! 990 bytes, so the alert crosses the pipe's 1 KiB.
//!
//! The client's bytes are recorded from `openssl s_client` over TCP with a
//! generator started from a fixed seed, then replayed in memory with the
//! same start, so the server draws the same numbers and takes the client's
//! flight. The signature's length (and so the flight's) depends on the
//! seed: a few seeds are tried until one puts the alert across the end of
//! the pipe. One process, one arena (this file is its own test binary).
//!
//! Needs `openssl` on the PATH (scripts/setup installs it).

#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::indexing_slicing,
    clippy::panic,
    reason = "a failed step is a failed test"
)]

mod common;

use std::io::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};

use common::{Blocking, fixture, listener, s_client};
use embedded_io_async::{ErrorType, Read, Write};
use tls::{Credentials, Server, Session, TX_LEN};

const ARENA_LEN: usize = 96 * 1024;

/// The seed [`fixed_entropy`] draws from.
static SEED: AtomicU64 = AtomicU64::new(0);

/// The same bytes on every call for one seed (SplitMix64).
fn fixed_entropy(buf: &mut [u8]) -> bool {
    let mut state = SEED.load(Ordering::SeqCst);
    for byte in buf {
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        *byte = (z ^ (z >> 31)) as u8;
    }
    true
}

/// A socket that keeps what it read.
struct Recording {
    socket: Blocking,
    read: Vec<u8>,
}

impl ErrorType for Recording {
    type Error = embedded_io_async::ErrorKind;
}

impl Read for Recording {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let n = self.socket.read(buf).await?;
        self.read.extend_from_slice(&buf[..n]);
        Ok(n)
    }
}

impl Write for Recording {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.socket.write(buf).await
    }

    async fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// A client whose bytes are all there at once; what the server writes is kept.
struct Memory {
    input: Vec<u8>,
    at: usize,
    output: Vec<u8>,
}

impl ErrorType for Memory {
    type Error = embedded_io_async::ErrorKind;
}

impl Read for Memory {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let n = buf.len().min(self.input.len() - self.at);
        buf[..n].copy_from_slice(&self.input[self.at..self.at + n]);
        self.at += n;
        Ok(n)
    }
}

impl Write for Memory {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.output.extend_from_slice(buf);
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// The records of `bytes`: (offset, type, length), the last perhaps cut short.
fn records(bytes: &[u8]) -> Vec<(usize, u8, usize)> {
    let mut out = Vec::new();
    let mut at = 0;
    while at + 5 <= bytes.len() {
        let len = usize::from(u16::from_be_bytes([bytes[at + 3], bytes[at + 4]]));
        out.push((at, bytes[at], len));
        at += 5 + len;
    }
    out
}

/// What `s_client -tls1_3` with the operator's certificate sends a server
/// whose generator starts from the current seed; its handshake completes.
fn capture(server: &Server) -> Vec<u8> {
    let (listener, port) = listener();
    let mut client = s_client(port, &["-tls1_3", "-cert", "operator.pem", "-key", "operator.key"]);
    let mut stdin = client.stdin.take().unwrap();
    let writer = std::thread::spawn(move || {
        let _ = stdin.write_all(b"read coils\n");
        std::thread::sleep(std::time::Duration::from_millis(300));
    });
    let (socket, _) = listener.accept().unwrap();
    socket.set_read_timeout(Some(std::time::Duration::from_secs(10))).unwrap();
    assert!(tls::rng::init(fixed_entropy));
    let mut recording = Recording { socket: Blocking(socket), read: Vec::new() };
    {
        let mut session = Session::new(server, &mut recording).unwrap();
        embassy_futures::block_on(session.handshake()).unwrap();
        let mut buf = [0u8; 64];
        let _ = embassy_futures::block_on(session.read(&mut buf));
    }
    drop(recording.socket);
    writer.join().unwrap();
    let _ = client.wait();
    recording.read
}

#[test]
fn a_bad_record_after_the_servers_flight_gets_a_whole_alert() {
    let arena = Box::leak(vec![0u8; ARENA_LEN].into_boxed_slice());
    tls::init([arena], fixed_entropy).unwrap();
    let (certificate, key, ca) = (fixture("device.der"), fixture("device.key.der"), fixture("client-ca.der"));
    let server = Server::new(&Credentials { certificate: &certificate, key: &key, client_ca: Some(&ca) }).unwrap();
    let before = tls::arena::usage().used;
    for seed in 1..=8 {
        SEED.store(seed, Ordering::SeqCst);
        let mut input = capture(&server);
        // The client's first encrypted record (its Certificate), its tag spoilt.
        let (at, _, len) =
            *records(&input).iter().find(|(_, kind, _)| *kind == 23).expect("an encrypted record from the client");
        input[at + 4 + len] ^= 0x01;

        assert!(tls::rng::init(fixed_entropy));
        let mut memory = Memory { input, at: 0, output: Vec::new() };
        let handshake = {
            let mut session = Session::new(&server, &mut memory).unwrap();
            embassy_futures::block_on(session.handshake())
        };
        assert_eq!(handshake, Err(tls::Error::Mbedtls(-0x7180)), "seed {seed}: MBEDTLS_ERR_SSL_INVALID_MAC");
        assert_eq!(tls::arena::usage().used, before, "seed {seed}: the arena as it was");
        let output = &memory.output;
        let written = records(output);
        let &(last, kind, len) = written.last().unwrap();
        if !(last < TX_LEN && TX_LEN < last + 5 + len) {
            // The alert fits the pipe with this seed's flight: another seed.
            continue;
        }
        assert_eq!(last + 5 + len, output.len(), "seed {seed}: the alert whole ({} bytes written)", output.len());
        assert_eq!(kind, 23, "seed {seed}: the alert, encrypted");
        return;
    }
    panic!("no seed put the alert across the end of the pipe: the scenario needs another client flight");
}
