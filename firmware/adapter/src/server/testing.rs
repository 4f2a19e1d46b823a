//! Test support: an in-memory duplex that implements embedded-io-async, a
//! one-step poll, and a lock around embassy-time's mock clock.
//!
//! The session under test owns a [`ServerEnd`]; the test keeps the
//! [`Wire`] and feeds bytes, closes the client side, or reads replies.
//! Futures are polled by hand with [`poll_once`], so a test decides exactly
//! what has arrived and how much time has passed before each step.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::future::Future;
use std::pin::Pin;
use std::rc::Rc;
use std::sync::{Mutex, MutexGuard};
use std::task::{Context, Poll, Waker};

use embassy_time::{Duration, MockDriver};
use embedded_io_async::{ErrorKind, ErrorType, Read, Write};

#[derive(Debug, Default)]
struct State {
    to_server: VecDeque<u8>,
    from_server: Vec<u8>,
    /// The client closed its side: reads return 0 once `to_server` is empty.
    closed: bool,
    /// The connection was reset: reads and writes fail.
    reset: bool,
    /// Most bytes one read returns (models TCP segments); 0 = no limit.
    max_read: usize,
}

/// The test's side of the connection.
#[derive(Debug, Clone, Default)]
pub struct Wire(Rc<RefCell<State>>);

/// The session's side of the connection.
#[derive(Debug)]
pub struct ServerEnd(Rc<RefCell<State>>);

impl Wire {
    /// A connection and the server's end of it.
    pub fn new() -> (Self, ServerEnd) {
        let wire = Self::default();
        let end = ServerEnd(wire.0.clone());
        (wire, end)
    }

    /// The client sends `bytes`.
    pub fn send(&self, bytes: &[u8]) {
        self.0.borrow_mut().to_server.extend(bytes);
    }

    /// Each server read returns at most `n` bytes (0: all that is there).
    pub fn segment(&self, n: usize) {
        self.0.borrow_mut().max_read = n;
    }

    /// The client closes its side.
    pub fn close(&self) {
        self.0.borrow_mut().closed = true;
    }

    /// The connection is reset under the server.
    pub fn reset(&self) {
        self.0.borrow_mut().reset = true;
    }

    /// Takes everything the server has written so far.
    pub fn take_replies(&self) -> Vec<u8> {
        std::mem::take(&mut self.0.borrow_mut().from_server)
    }
}

impl ErrorType for ServerEnd {
    type Error = ErrorKind;
}

impl Read for ServerEnd {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, ErrorKind> {
        std::future::poll_fn(|_| {
            let mut state = self.0.borrow_mut();
            if state.reset {
                return Poll::Ready(Err(ErrorKind::ConnectionReset));
            }
            if state.to_server.is_empty() {
                return if state.closed { Poll::Ready(Ok(0)) } else { Poll::Pending };
            }
            let limit = if state.max_read == 0 { usize::MAX } else { state.max_read };
            let n = buf.len().min(state.to_server.len()).min(limit);
            for (dst, src) in buf.iter_mut().zip(state.to_server.drain(..n)) {
                *dst = src;
            }
            Poll::Ready(Ok(n))
        })
        .await
    }
}

impl Write for ServerEnd {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, ErrorKind> {
        let mut state = self.0.borrow_mut();
        if state.reset {
            return Err(ErrorKind::ConnectionReset);
        }
        state.from_server.extend_from_slice(buf);
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), ErrorKind> {
        Ok(())
    }
}

/// Polls `future` once, as an executor would after a wake-up.
pub fn poll_once<F: Future + ?Sized>(future: Pin<&mut F>) -> Poll<F::Output> {
    future.poll(&mut Context::from_waker(Waker::noop()))
}

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

/// Splits a stream of reply ADUs into frames (by their length fields).
pub fn frames(mut bytes: &[u8]) -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    while let Ok(Some(len)) = crate::modbus::mbap::next_frame_len(bytes) {
        out.push(bytes[..len].to_vec());
        bytes = &bytes[len..];
    }
    assert!(bytes.is_empty(), "reply stream ends with a partial frame: {bytes:02x?}");
    out
}

/// An MBAP frame around `pdu`.
pub fn adu(transaction_id: u16, unit_id: u8, pdu: &[u8]) -> Vec<u8> {
    let mut frame = Vec::with_capacity(7 + pdu.len());
    frame.extend_from_slice(&transaction_id.to_be_bytes());
    frame.extend_from_slice(&[0, 0]);
    frame.extend_from_slice(&u16::try_from(pdu.len() + 1).unwrap().to_be_bytes());
    frame.push(unit_id);
    frame.extend_from_slice(pdu);
    frame
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

/// A server over a fresh device with recording pins (both leaked: tests only).
pub fn server_with(
    config: super::Config,
    watchdog: super::Watchdog,
) -> (&'static super::Server<'static, crate::device::Device<'static>>, &'static RecordingPins) {
    let pins: &'static RecordingPins = Box::leak(Box::default());
    let device = Box::leak(Box::new(crate::device::Device::new(watchdog, crate::VERSION, pins)));
    (Box::leak(Box::new(super::Server::new(config, device))), pins)
}
