//! Shared helpers of the system tests: network namespaces and the programs
//! under test.

pub mod abuse;
pub mod board;
pub mod browser;
pub mod controller;
pub mod dhcp;
pub mod hal_sim;
pub mod mdns;
pub mod netns;
pub mod qemu;
pub mod update;

use std::future::Future;
use std::time::Duration;

use netns::Namespace;

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
