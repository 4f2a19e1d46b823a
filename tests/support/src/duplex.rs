//! An in-memory duplex that implements embedded-io-async, for driving a
//! session without a network.
//!
//! The code under test owns the [`ServerEnd`]; the test keeps the [`Wire`]:
//! it feeds bytes in, closes its side or resets the connection, takes what
//! the server wrote, and shapes the traffic (how many bytes each read
//! returns, how many each write takes, whether each operation is `Pending`
//! once first). Futures are polled by hand with [`poll_once`], so a test
//! decides exactly what has arrived before each step.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::future::Future;
use std::pin::Pin;
use std::rc::Rc;
use std::task::{Context, Poll, Waker};

use embedded_io_async::{ErrorKind, ErrorType, Read, Write};

#[derive(Debug, Default)]
struct State {
    to_server: VecDeque<u8>,
    from_server: Vec<u8>,
    /// The client closed its side: reads return 0 once `to_server` is empty.
    closed: bool,
    /// The connection was reset: reads and writes fail.
    reset: bool,
    /// Most bytes each read returns, in turn (0 or none: no limit).
    read_sizes: Vec<usize>,
    reads: usize,
    /// Most bytes each write takes, in turn (0 or none: all of them).
    write_sizes: Vec<usize>,
    writes: usize,
    stall_reads: bool,
    stall_writes: bool,
    /// The current read or write has already been `Pending` once.
    stalled: bool,
    stalls: usize,
    /// The read waiting for bytes.
    reader: Option<Waker>,
}

impl State {
    /// `Pending` once per operation when `enabled`.
    fn stall(&mut self, enabled: bool, cx: &mut Context<'_>) -> bool {
        if enabled && !self.stalled {
            self.stalled = true;
            self.stalls += 1;
            cx.waker().wake_by_ref();
            return true;
        }
        self.stalled = false;
        false
    }

    fn wake_reader(&mut self) {
        if let Some(waker) = self.reader.take() {
            waker.wake();
        }
    }
}

/// The `index`th of `sizes`, in turn; `usize::MAX` for no limit.
fn limit(sizes: &[usize], index: usize) -> usize {
    match sizes.get(index.checked_rem(sizes.len()).unwrap_or(0)) {
        None | Some(0) => usize::MAX,
        Some(&n) => n,
    }
}

/// The test's side of the connection (the client).
#[derive(Debug, Clone, Default)]
pub struct Wire(Rc<RefCell<State>>);

/// The server's side of the connection: what the code under test reads
/// from and writes to.
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
        let mut state = self.0.borrow_mut();
        state.to_server.extend(bytes);
        state.wake_reader();
    }

    /// The client closes its side: once the server has read everything, its
    /// reads return 0.
    pub fn close(&self) {
        let mut state = self.0.borrow_mut();
        state.closed = true;
        state.wake_reader();
    }

    /// The connection is reset under the server: its reads and writes fail
    /// with `ConnectionReset`.
    pub fn reset(&self) {
        let mut state = self.0.borrow_mut();
        state.reset = true;
        state.wake_reader();
    }

    /// Each server read returns at most the next of `sizes` bytes, in turn
    /// and round again (0: all that is there and fits). No sizes: no limit.
    pub fn read_sizes(&self, sizes: impl IntoIterator<Item = usize>) {
        let mut state = self.0.borrow_mut();
        state.read_sizes = sizes.into_iter().collect();
        state.reads = 0;
    }

    /// Each server write takes at most the next of `sizes` bytes, in turn and
    /// round again (0: all of them). No sizes: writes take everything.
    pub fn write_sizes(&self, sizes: impl IntoIterator<Item = usize>) {
        let mut state = self.0.borrow_mut();
        state.write_sizes = sizes.into_iter().collect();
        state.writes = 0;
    }

    /// Every server read that has bytes (or the end) to return is `Pending`
    /// once first.
    pub fn stall_reads(&self, on: bool) {
        self.0.borrow_mut().stall_reads = on;
    }

    /// Every server write is `Pending` once first.
    pub fn stall_writes(&self, on: bool) {
        self.0.borrow_mut().stall_writes = on;
    }

    /// How many times a read or write was `Pending` because of
    /// [`stall_reads`](Self::stall_reads) or
    /// [`stall_writes`](Self::stall_writes).
    pub fn stalls(&self) -> usize {
        self.0.borrow().stalls
    }

    /// Takes everything the server has written so far.
    pub fn take_replies(&self) -> Vec<u8> {
        std::mem::take(&mut self.0.borrow_mut().from_server)
    }
}

impl ServerEnd {
    /// Splits the server's end into a read half and a write half over the
    /// same connection, as embassy-net's `TcpSocket::split` does, for code
    /// that holds the two apart.
    pub fn split(self) -> (ReadHalf, WriteHalf) {
        (ReadHalf(self.0.clone()), WriteHalf(self.0))
    }
}

/// The reading half of a [`ServerEnd`].
#[derive(Debug)]
pub struct ReadHalf(Rc<RefCell<State>>);

/// The writing half of a [`ServerEnd`].
#[derive(Debug)]
pub struct WriteHalf(Rc<RefCell<State>>);

/// Waits for bytes (or the client's close); panics on an empty `buf`,
/// where a 0 would say the stream has ended.
async fn read(state: &RefCell<State>, buf: &mut [u8]) -> Result<usize, ErrorKind> {
    assert!(!buf.is_empty(), "a read into an empty buffer (its 0 would mean the end of the stream)");
    std::future::poll_fn(|cx| {
        let mut state = state.borrow_mut();
        if state.reset {
            return Poll::Ready(Err(ErrorKind::ConnectionReset));
        }
        if state.to_server.is_empty() && !state.closed {
            state.reader = Some(cx.waker().clone());
            return Poll::Pending;
        }
        let stall = state.stall_reads;
        if state.stall(stall, cx) {
            return Poll::Pending;
        }
        let n = buf.len().min(state.to_server.len()).min(limit(&state.read_sizes, state.reads));
        state.reads += 1;
        for (dst, src) in buf.iter_mut().zip(state.to_server.drain(..n)) {
            *dst = src;
        }
        Poll::Ready(Ok(n))
    })
    .await
}

async fn write(state: &RefCell<State>, buf: &[u8]) -> Result<usize, ErrorKind> {
    std::future::poll_fn(|cx| {
        let mut state = state.borrow_mut();
        if state.reset {
            return Poll::Ready(Err(ErrorKind::ConnectionReset));
        }
        let stall = state.stall_writes;
        if state.stall(stall, cx) {
            return Poll::Pending;
        }
        let n = buf.len().min(limit(&state.write_sizes, state.writes));
        state.writes += 1;
        state.from_server.extend_from_slice(&buf[..n]);
        Poll::Ready(Ok(n))
    })
    .await
}

fn flush(state: &RefCell<State>) -> Result<(), ErrorKind> {
    if state.borrow().reset { Err(ErrorKind::ConnectionReset) } else { Ok(()) }
}

macro_rules! io {
    (read $($ty:ty),*) => {$(
        impl ErrorType for $ty {
            type Error = ErrorKind;
        }

        impl Read for $ty {
            /// Waits for bytes (or the client's close); panics on an empty
            /// `buf`, where a 0 would say the stream has ended.
            async fn read(&mut self, buf: &mut [u8]) -> Result<usize, ErrorKind> {
                read(&self.0, buf).await
            }
        }
    )*};
    (write $($ty:ty),*) => {$(
        impl Write for $ty {
            async fn write(&mut self, buf: &[u8]) -> Result<usize, ErrorKind> {
                write(&self.0, buf).await
            }

            async fn flush(&mut self) -> Result<(), ErrorKind> {
                flush(&self.0)
            }
        }
    )*};
}

io!(read ServerEnd, ReadHalf);
io!(write ServerEnd, WriteHalf);

impl ErrorType for WriteHalf {
    type Error = ErrorKind;
}

/// Polls `future` once, as an executor would after a wake-up.
pub fn poll_once<F: Future + ?Sized>(future: Pin<&mut F>) -> Poll<F::Output> {
    future.poll(&mut Context::from_waker(Waker::noop()))
}

#[cfg(test)]
mod tests {
    use core::pin::pin;

    use embedded_io_async::{Read, Write};

    use super::*;

    /// One read of up to `n` bytes, polled once.
    fn read(end: &mut ServerEnd, n: usize) -> Poll<Result<Vec<u8>, ErrorKind>> {
        let mut buf = vec![0; n];
        let polled = poll_once(pin!(end.read(&mut buf)));
        polled.map(|r| r.map(|len| buf[..len].to_vec()))
    }

    #[test]
    fn bytes_sent_are_read_and_bytes_written_are_taken() {
        let (wire, mut end) = Wire::new();
        assert!(read(&mut end, 8).is_pending(), "nothing sent yet");
        wire.send(&[1, 2, 3]);
        assert_eq!(read(&mut end, 2), Poll::Ready(Ok(vec![1, 2])));
        assert_eq!(poll_once(pin!(end.write(&[9, 8]))), Poll::Ready(Ok(2)));
        assert_eq!(wire.take_replies(), [9, 8]);
        assert!(wire.take_replies().is_empty());
        wire.close();
        assert_eq!(read(&mut end, 8), Poll::Ready(Ok(vec![3])));
        assert_eq!(read(&mut end, 8), Poll::Ready(Ok(vec![])), "the end of the stream");
    }

    #[test]
    fn reads_and_writes_take_the_sizes_in_turn() {
        let (wire, mut end) = Wire::new();
        wire.read_sizes([1, 0, 2]);
        wire.write_sizes([3, 1]);
        wire.send(&[0, 1, 2, 3, 4, 5, 6, 7, 8]);
        assert_eq!(read(&mut end, 8), Poll::Ready(Ok(vec![0])));
        assert_eq!(read(&mut end, 4), Poll::Ready(Ok(vec![1, 2, 3, 4])));
        assert_eq!(read(&mut end, 8), Poll::Ready(Ok(vec![5, 6])));
        assert_eq!(read(&mut end, 8), Poll::Ready(Ok(vec![7])));
        assert_eq!(poll_once(pin!(end.write(&[1; 10]))), Poll::Ready(Ok(3)));
        assert_eq!(poll_once(pin!(end.write(&[2; 10]))), Poll::Ready(Ok(1)));
        assert_eq!(poll_once(pin!(end.write(&[3; 10]))), Poll::Ready(Ok(3)));
        assert_eq!(wire.take_replies(), [1, 1, 1, 2, 3, 3, 3]);
    }

    #[test]
    fn stalled_operations_are_pending_once_each() {
        let (wire, mut end) = Wire::new();
        wire.stall_reads(true);
        wire.stall_writes(true);
        assert!(read(&mut end, 8).is_pending(), "waiting for bytes is no stall");
        assert_eq!(wire.stalls(), 0);
        wire.send(&[1, 2]);
        let mut buf = [0; 8];
        {
            let mut reading = pin!(end.read(&mut buf));
            assert!(poll_once(reading.as_mut()).is_pending());
            assert_eq!(poll_once(reading.as_mut()), Poll::Ready(Ok(2)));
        }
        let mut writing = pin!(end.write(&[7]));
        assert!(poll_once(writing.as_mut()).is_pending());
        assert_eq!(poll_once(writing.as_mut()), Poll::Ready(Ok(1)));
        assert_eq!((wire.stalls(), wire.take_replies()), (2, vec![7]));
    }

    #[test]
    fn a_reset_fails_reads_and_writes() {
        let (wire, mut end) = Wire::new();
        wire.send(&[1]);
        wire.reset();
        assert_eq!(read(&mut end, 8), Poll::Ready(Err(ErrorKind::ConnectionReset)));
        assert_eq!(poll_once(pin!(end.write(&[1]))), Poll::Ready(Err(ErrorKind::ConnectionReset)));
    }

    #[test]
    fn split_halves_share_the_connection() {
        let (wire, end) = Wire::new();
        let (mut reader, mut writer) = end.split();
        wire.send(&[4, 5]);
        let mut buf = [0; 8];
        assert_eq!(poll_once(pin!(reader.read(&mut buf))), Poll::Ready(Ok(2)));
        assert_eq!(poll_once(pin!(writer.write(&[6]))), Poll::Ready(Ok(1)));
        assert_eq!(wire.take_replies(), [6]);
        wire.reset();
        assert_eq!(poll_once(pin!(reader.read(&mut buf))), Poll::Ready(Err(ErrorKind::ConnectionReset)));
        assert_eq!(poll_once(pin!(writer.flush())), Poll::Ready(Err(ErrorKind::ConnectionReset)));
    }

    #[test]
    #[should_panic(expected = "empty buffer")]
    fn a_read_into_an_empty_buffer_fails() {
        let (wire, mut end) = Wire::new();
        wire.send(&[1]);
        let _ = read(&mut end, 0);
    }
}
