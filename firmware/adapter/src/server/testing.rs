//! What only this crate's tests share: a lock around embassy-time's mock
//! clock, and output pins that record what they are told. The in-memory
//! duplex, the hand poll and the reference framer they use with it are
//! test-support's (`test_support::duplex`, `test_support::framer`).

use std::sync::{Mutex, MutexGuard};

use embassy_time::{Duration, MockDriver};

/// The mock clock is one global: tests that read or advance it hold this.
pub struct Clock {
    _guard: MutexGuard<'static, ()>,
}

impl Clock {
    /// Takes the clock and sets it back to 0.
    pub fn take() -> Self {
        static CLOCK: Mutex<()> = Mutex::new(());
        let guard = CLOCK.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        MockDriver::get().reset();
        Self { _guard: guard }
    }

    /// Moves time forward.
    pub fn advance(&self, by: Duration) {
        MockDriver::get().advance(by);
    }
}

/// Output pins that remember what they were last told to drive.
#[derive(Debug, Default)]
pub struct RecordingPins {
    pub last: std::sync::Mutex<Option<crate::io::Outputs>>,
    pub calls: std::sync::atomic::AtomicUsize,
}

impl crate::io::OutputPins for RecordingPins {
    fn drive(&self, outputs: &crate::io::Outputs) {
        *self.last.lock().unwrap() = Some(*outputs);
        self.calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    }
}

/// The board the tests' devices say they are.
pub const MODEL: &str = "test-board";

/// A server over a fresh device with recording pins (both leaked: tests only).
pub fn server_with(
    config: super::Config,
    watchdog: crate::device::Watchdog,
) -> (&'static super::Server<'static, crate::device::Device<'static>>, &'static RecordingPins) {
    let pins: &'static RecordingPins = Box::leak(Box::default());
    let device = Box::leak(Box::new(crate::device::Device::new(watchdog, MODEL, pins)));
    (Box::leak(Box::new(super::Server::new(config, device))), pins)
}
