//! An in-memory connection for one session: the client's bytes are all
//! there from the start and the client has closed its side, so a session
//! must answer everything and end without waiting for time to pass.

use core::cell::Cell;
use core::future::Future;
use core::pin::Pin;
use core::task::{Context, Poll, Waker};

use embedded_io_async::{ErrorKind, ErrorType, Read, Write};

use crate::input::{PARTIAL_WRITES, STALL_READS, SessionInput};

/// The server's end: reads come from the input's stream, cut as it says;
/// writes are collected in `sent`.
#[derive(Debug)]
pub struct Connection<'a> {
    incoming: &'a [u8],
    cuts: &'a [u8],
    reads: usize,
    writes: usize,
    stall_reads: bool,
    partial_writes: bool,
    /// The current read or write has already been `Pending` once.
    stalled: bool,
    /// Counts every `Pending` this end returns (the driver checks that the
    /// session only waits on the connection).
    stalls: &'a Cell<usize>,
    pub sent: Vec<u8>,
}

impl<'a> Connection<'a> {
    pub fn new(input: &SessionInput<'a>, stalls: &'a Cell<usize>) -> Self {
        Self {
            incoming: input.stream,
            cuts: input.cuts,
            reads: 0,
            writes: 0,
            stall_reads: input.flags & STALL_READS != 0,
            partial_writes: input.flags & PARTIAL_WRITES != 0,
            stalled: false,
            stalls,
            sent: Vec::new(),
        }
    }

    /// `Pending` once per operation when `enabled`.
    fn stall(&mut self, enabled: bool) -> bool {
        if enabled && !self.stalled {
            self.stalled = true;
            self.stalls.set(self.stalls.get() + 1);
            return true;
        }
        self.stalled = false;
        false
    }

    fn cut(&self, index: usize) -> Option<u8> {
        match self.cuts.len() {
            0 => None,
            n => Some(self.cuts[index % n]),
        }
    }
}

impl ErrorType for Connection<'_> {
    type Error = ErrorKind;
}

impl Read for Connection<'_> {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, ErrorKind> {
        assert!(!buf.is_empty(), "the session reads into an empty buffer (a 0 would mean the end of the stream)");
        core::future::poll_fn(|_| {
            if self.stall(self.stall_reads) {
                return Poll::Pending;
            }
            let limit = match self.cut(self.reads) {
                None | Some(0) => usize::MAX,
                Some(n) => usize::from(n),
            };
            self.reads += 1;
            let n = buf.len().min(self.incoming.len()).min(limit);
            let (now, later) = self.incoming.split_at(n);
            buf[..n].copy_from_slice(now);
            self.incoming = later;
            Poll::Ready(Ok(n))
        })
        .await
    }
}

impl Write for Connection<'_> {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, ErrorKind> {
        core::future::poll_fn(|_| {
            if self.stall(self.partial_writes) {
                return Poll::Pending;
            }
            let n = if self.partial_writes {
                let take = 1 + usize::from(self.cut(self.writes).unwrap_or(0) % 16);
                self.writes += 1;
                buf.len().min(take)
            } else {
                buf.len()
            };
            self.sent.extend_from_slice(&buf[..n]);
            Poll::Ready(Ok(n))
        })
        .await
    }

    async fn flush(&mut self) -> Result<(), ErrorKind> {
        Ok(())
    }
}

/// Polls `future` once, as an executor would after a wake-up.
pub fn poll_once<F: Future + ?Sized>(future: Pin<&mut F>) -> Poll<F::Output> {
    future.poll(&mut Context::from_waker(Waker::noop()))
}
