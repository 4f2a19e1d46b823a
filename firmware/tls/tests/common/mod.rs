//! What both test binaries share: the fixtures, the arena's set-up, a
//! blocking socket as an `embedded-io-async` stream, `s_client`.
#![allow(dead_code, reason = "each test binary uses its part")]

use std::io::{Read as _, Write as _};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Mutex, MutexGuard, Once};

use embedded_io_async::{ErrorType, Read, Write};

pub fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures")
}

pub fn fixture(name: &str) -> Vec<u8> {
    std::fs::read(fixtures().join(name)).unwrap()
}

/// The host's entropy, as hal-sim takes it.
pub fn os_entropy(buf: &mut [u8]) -> bool {
    getrandom::fill(buf).is_ok()
}

/// `tls::init` once per process, with an arena of `arena_len` bytes;
/// the tests of one binary take the arena one at a time.
pub fn init(arena_len: usize) -> MutexGuard<'static, ()> {
    init_regions(&[arena_len])
}

/// [`init`] with an arena of separate regions of these lengths.
pub fn init_regions(lens: &[usize]) -> MutexGuard<'static, ()> {
    static INIT: Once = Once::new();
    static SERIAL: Mutex<()> = Mutex::new(());
    INIT.call_once(|| {
        let regions = lens.iter().map(|&len| -> &'static mut [u8] { Box::leak(vec![0u8; len].into_boxed_slice()) });
        tls::init(regions, os_entropy).unwrap();
    });
    SERIAL.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// A blocking std socket as an `embedded-io-async` stream (the tests'
/// executor is `block_on`, one connection at a time).
pub struct Blocking(pub TcpStream);

impl ErrorType for Blocking {
    type Error = embedded_io_async::ErrorKind;
}

impl Read for Blocking {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        self.0.read(buf).map_err(|_| embedded_io_async::ErrorKind::Other)
    }
}

impl Write for Blocking {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.0.write(buf).map_err(|_| embedded_io_async::ErrorKind::Other)
    }

    async fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// `openssl s_client` to `port` with `args`, its stdin open until dropped.
pub fn s_client(port: u16, args: &[&str]) -> Child {
    Command::new("openssl")
        .args(["s_client", "-connect", &format!("127.0.0.1:{port}"), "-CAfile"])
        .arg(fixtures().join("device.pem"))
        .args(["-verify_return_error", "-servername", "mbio-test.local"])
        .args(args)
        .current_dir(fixtures())
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("openssl s_client (scripts/setup installs openssl)")
}

/// A listener on 127.0.0.1 and its port.
pub fn listener() -> (TcpListener, u16) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    (listener, port)
}
