//! The connection as picoserve sees it: any `embedded-io-async` reader and
//! writer (an embassy-net socket's halves, test-support's duplex), with the
//! API's limits and deadlines in between.
//!
//! - [`Guarded`] reads: every read ends by [`super::REQUEST_TIMEOUT`] after
//!   the connection started, and the head goes through [`Head`] (431, 413).
//! - [`Paced`] writes: every write ends by [`super::WRITE_TIMEOUT`] after
//!   the first one.
//! - [`Stream`] joins them as a `picoserve::io::Socket`; closing is the
//!   caller's (the listener closes the socket, a test the duplex).

use embassy_time::{Instant, with_deadline};
use embedded_io_async::{ErrorKind, ErrorType, Read, Write};
use picoserve::io::Socket;
use picoserve::mem::{BorrowedBuffer, BorrowedCursor};

use super::head::{Head, Limit};
use super::{REQUEST_TIMEOUT, WRITE_TIMEOUT};

/// Why a connection's stream stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StreamError {
    /// The transport failed (reset, closed under a write).
    Io(ErrorKind),
    /// The request was not whole by its deadline, or the response not taken by its.
    Timeout,
    /// The request broke a limit.
    Limit(Limit),
}

impl embedded_io_async::Error for StreamError {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::Io(kind) => *kind,
            Self::Timeout => ErrorKind::TimedOut,
            Self::Limit(_) => ErrorKind::InvalidData,
        }
    }
}

impl core::fmt::Display for StreamError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Io(kind) => write!(f, "transport error: {kind:?}"),
            Self::Timeout => f.write_str("timed out"),
            Self::Limit(Limit::HeadTooLarge) => f.write_str("request head over its limit"),
            Self::Limit(Limit::BodyTooLarge) => f.write_str("request body over its limit"),
        }
    }
}

impl core::error::Error for StreamError {}

/// The reading half: a deadline on every read, and the head watched.
#[derive(Debug)]
pub struct Guarded<R> {
    inner: R,
    deadline: Instant,
    head: Head,
}

impl<R> Guarded<R> {
    /// Reads from `inner` until [`REQUEST_TIMEOUT`] from now.
    pub fn new(inner: R) -> Self {
        Self { inner, deadline: Instant::now() + REQUEST_TIMEOUT, head: Head::new() }
    }
}

impl<R: Read> ErrorType for Guarded<R> {
    type Error = StreamError;
}

impl<R: Read> Read for Guarded<R> {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, StreamError> {
        if buf.is_empty() {
            // embedded-io's contract: no wait, and not the end of the stream.
            return Ok(0);
        }
        // A broken limit stays broken, without another read.
        self.head.scan(&[]).map_err(StreamError::Limit)?;
        let n = match with_deadline(self.deadline, self.inner.read(buf)).await {
            Err(_) => return Err(StreamError::Timeout),
            Ok(Err(e)) => return Err(StreamError::Io(embedded_io_async::Error::kind(&e))),
            Ok(Ok(n)) => n,
        };
        self.head.scan(buf.get(..n).unwrap_or_default()).map_err(StreamError::Limit)?;
        Ok(n)
    }
}

/// Bytes picoserve formats a response head into before they are written
/// (one header line; a longer one is formatted again in pieces).
const WRITE_CHUNK_LEN: usize = 64;

/// The writing half: every write ends by [`WRITE_TIMEOUT`] after the first.
#[derive(Debug)]
pub struct Paced<W> {
    inner: W,
    deadline: Option<Instant>,
}

impl<W> Paced<W> {
    pub fn new(inner: W) -> Self {
        Self { inner, deadline: None }
    }

    fn deadline(&mut self) -> Instant {
        *self.deadline.get_or_insert_with(|| Instant::now() + WRITE_TIMEOUT)
    }
}

impl<W: Write> ErrorType for Paced<W> {
    type Error = StreamError;
}

impl<W: Write> Write for Paced<W> {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, StreamError> {
        if buf.is_empty() {
            return Ok(0);
        }
        let deadline = self.deadline();
        match with_deadline(deadline, self.inner.write(buf)).await {
            Err(_) => Err(StreamError::Timeout),
            Ok(Err(e)) => Err(StreamError::Io(embedded_io_async::Error::kind(&e))),
            // embedded-io-async's `write_all` panics on a write of 0 bytes.
            Ok(Ok(0)) => Err(StreamError::Io(ErrorKind::WriteZero)),
            Ok(Ok(n)) => Ok(n),
        }
    }

    async fn flush(&mut self) -> Result<(), StreamError> {
        let deadline = self.deadline();
        match with_deadline(deadline, self.inner.flush()).await {
            Err(_) => Err(StreamError::Timeout),
            Ok(Err(e)) => Err(StreamError::Io(embedded_io_async::Error::kind(&e))),
            Ok(Ok(())) => Ok(()),
        }
    }
}

impl<W: Write> picoserve::io::Write for Paced<W> {
    async fn write_with<F: FnOnce(BorrowedCursor<'_>) -> T, T>(&mut self, f: F) -> Result<T, StreamError> {
        let mut chunk = [0u8; WRITE_CHUNK_LEN];
        let mut buffer = BorrowedBuffer::new(&mut chunk);
        let output = f(buffer.unfilled());
        self.write_all(buffer.filled()).await?;
        Ok(output)
    }
}

/// picoserve's clock: embassy-time (the boards' driver, or the mock clock in tests).
#[derive(Clone, Copy, Debug, Default)]
pub struct Clock;

/// This crate's picoserve runtime: embassy-time and a [`Stream`].
#[derive(Clone, Copy, Debug)]
pub enum Runtime {}

impl picoserve::Timer<Runtime> for Clock {
    async fn delay(&self, duration: picoserve::time::Duration) {
        embassy_time::Timer::after_millis(duration.as_millis()).await;
    }
}

/// One connection's two halves, as picoserve takes them.
#[derive(Debug)]
pub struct Stream<R, W> {
    pub reader: Guarded<R>,
    pub writer: Paced<W>,
}

impl<R: Read, W: Write> Socket<Runtime> for &mut Stream<R, W> {
    type Error = StreamError;
    type ReadHalf<'a>
        = &'a mut Guarded<R>
    where
        Self: 'a;
    type WriteHalf<'a>
        = &'a mut Paced<W>
    where
        Self: 'a;

    fn split(&mut self) -> (Self::ReadHalf<'_>, Self::WriteHalf<'_>) {
        (&mut self.reader, &mut self.writer)
    }

    /// Nothing to do here: the caller closes the connection.
    async fn abort<T: picoserve::Timer<Runtime>>(
        self,
        _timeouts: &picoserve::Timeouts,
        _timer: &T,
    ) -> Result<(), picoserve::Error<StreamError>> {
        Ok(())
    }

    /// Sends what is left; the caller closes the connection.
    async fn shutdown<T: picoserve::Timer<Runtime>>(
        self,
        _timeouts: &picoserve::Timeouts,
        _timer: &T,
    ) -> Result<(), picoserve::Error<StreamError>> {
        self.writer.flush().await.map_err(picoserve::Error::Write)
    }
}
