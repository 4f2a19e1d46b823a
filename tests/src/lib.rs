//! Shared helpers of the system tests: network namespaces and the programs
//! under test.

pub mod abuse;
pub mod board;
pub mod browser;
pub mod controller;
pub mod dhcp;
pub mod fleet;
pub mod hal_sim;
pub mod mdns;
pub mod netns;
pub mod qemu;
pub mod testssl;
pub mod tls;
pub mod tls_abuse;
pub mod update;

use std::future::Future;
use std::time::Duration;

use netns::Namespace;
use tokio_modbus::client::{Context, Reader as _};

/// The admin password the tests give a device first (a new device takes
/// no other change until one is set: docs/http-api.md, "The first password").
pub const OWNER_PASSWORD: &str = "correct-horse";
/// The `Authorization` field for `admin` and [`OWNER_PASSWORD`], as curl's
/// `-u admin:correct-horse` sends it (base64 of `admin:correct-horse`).
pub const OWNER_AUTHORIZATION: &str = "Authorization: Basic YWRtaW46Y29ycmVjdC1ob3JzZQ==";

/// One try at a Modbus server: connect to `addr` and read holding register
/// `register`, within `limit`. The connection once it answered, or why not.
pub async fn modbus_answers(addr: std::net::SocketAddr, register: u16, limit: Duration) -> Result<Context, String> {
    let attempt = async {
        let mut ctx = tokio_modbus::client::tcp::connect(addr).await.map_err(|e| e.to_string())?;
        match ctx.read_holding_registers(register, 1).await {
            Ok(Ok(_)) => Ok(ctx),
            Ok(Err(exception)) => Err(format!("exception {exception:?}")),
            Err(error) => Err(error.to_string()),
        }
    };
    tokio::time::timeout(limit, attempt).await.unwrap_or_else(|_| Err(format!("no answer in {limit:?}")))
}

/// The longest a test's client side may run before the test fails.
pub const TEST_TIMEOUT: Duration = Duration::from_secs(60);

/// Runs `test` on a new thread (inside `ns`, if given), on a current-thread
/// tokio runtime, and returns its result. A panic inside fails the test, and
/// so does running longer than [`TEST_TIMEOUT`] (a server stuck or dead).
pub fn run_client<T, F, Fut>(ns: Option<&Namespace>, test: F) -> T
where
    T: Send,
    F: FnOnce() -> Fut + Send,
    Fut: Future<Output = T>,
{
    std::thread::scope(|scope| {
        let thread = scope.spawn(|| {
            if let Some(ns) = ns {
                ns.enter().expect("the test thread enters the namespace");
            }
            let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("a tokio runtime");
            match runtime.block_on(async { tokio::time::timeout(TEST_TIMEOUT, test()).await }) {
                Ok(value) => value,
                Err(_) => panic!("the client side did not finish in {TEST_TIMEOUT:?} (server stuck or dead?)"),
            }
        });
        match thread.join() {
            Ok(value) => value,
            Err(panic) => std::panic::resume_unwind(panic),
        }
    })
}

/// A host program of this workspace the tests run: the path in `variable`,
/// or `target/debug/NAME` (of `CARGO_TARGET_DIR` if set); fails, saying how
/// to build it, when it is not there.
pub fn host_binary(variable: &str, name: &str) -> std::path::PathBuf {
    use std::path::{Path, PathBuf};
    if let Some(path) = std::env::var_os(variable) {
        let path = PathBuf::from(path);
        assert!(path.is_file(), "{variable}={} is not a file", path.display());
        return path;
    }
    let target = match std::env::var_os("CARGO_TARGET_DIR") {
        Some(dir) => PathBuf::from(dir),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join("target"),
    };
    let path = target.join("debug").join(name);
    assert!(
        path.is_file(),
        "{name} is not built ({} is missing): run `cargo build -p {name}` first, or set {variable}",
        path.display()
    );
    path
}
