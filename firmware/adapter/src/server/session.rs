//! One client connection: frames in, replies out, over any
//! `embedded-io-async` stream (an embassy-net socket, or a test pipe).

use core::fmt;
use core::future::{Future, poll_fn};
use core::pin::{Pin, pin};
use core::task::Poll;

use embassy_time::{Instant, Timer};
use embedded_io_async::{Read, Write};

use super::{Outcome, Server, Service, SlotId, Stats};
use crate::modbus::be_u16;
use crate::modbus::mbap::{self, HEADER_LEN, MAX_ADU_LEN};

/// Where a request's first address sits in its frame (after the function code).
const ADDRESS: usize = HEADER_LEN + 1;

/// Receive buffer of a session: one whole ADU always fits behind a partial one
/// once the consumed bytes are dropped.
pub const SESSION_BUFFER_LEN: usize = MAX_ADU_LEN;

/// Why a session ended (other than the client closing it cleanly).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error<E> {
    /// The transport failed (reset, aborted).
    Transport(E),
    /// A length field outside 2..=254: the stream is lost.
    BadLength(u16),
    /// No complete request for the configured idle time.
    IdleTimeout,
    /// A frame started and did not complete in time.
    FrameTimeout,
    /// Closed to make room for a new client.
    Evicted,
    /// The transport accepted no bytes of a reply.
    WriteZero,
    /// A length the session computed fell outside its buffer, or the
    /// transport claimed to take more bytes than it was given: a bug, so the
    /// connection is closed rather than answered with what the slice missed.
    Internal,
}

impl<E: fmt::Debug> fmt::Display for Error<E> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Transport(e) => write!(f, "transport error: {e:?}"),
            Self::BadLength(len) => write!(f, "bad MBAP length {len}: stream lost"),
            Self::IdleTimeout => f.write_str("idle timeout"),
            Self::FrameTimeout => f.write_str("frame not completed in time"),
            Self::Evicted => f.write_str("closed to make room for a new client"),
            Self::WriteZero => f.write_str("transport accepted no bytes"),
            Self::Internal => f.write_str("internal length error"),
        }
    }
}

impl<E: fmt::Debug> core::error::Error for Error<E> {}

/// Serves one connection until the client closes it (`Ok`) or it must end (`Err`).
///
/// Every whole frame in the buffer is answered in order before reading more,
/// so pipelined requests each get a reply; a frame split across reads waits
/// for its remaining bytes, at most `frame_timeout`.
///
/// The client's rights come from its slot ([`super::Slots::open`]); bad
/// lengths and timeouts are counted in the service's [`Stats`].
pub async fn serve<T: Read + Write, S: Service>(
    stream: &mut T,
    server: &Server<'_, S>,
    slot: SlotId,
) -> Result<(), Error<T::Error>> {
    let result = run(stream, server, slot).await;
    let stats = server.stats();
    match result {
        Err(Error::BadLength(_)) => Stats::count(&stats.bad_length),
        Err(Error::IdleTimeout | Error::FrameTimeout) => Stats::count(&stats.timeouts),
        _ => {}
    }
    result
}

async fn run<T: Read + Write, S: Service>(
    stream: &mut T,
    server: &Server<'_, S>,
    slot: SlotId,
) -> Result<(), Error<T::Error>> {
    let rights = server.slots().rights(slot);
    let mut rx = [0u8; SESSION_BUFFER_LEN];
    let mut reply = [0u8; MAX_ADU_LEN];
    let mut filled = 0;
    let mut last_request = Instant::now();
    let mut frame_started = None;

    loop {
        let mut consumed = 0;
        loop {
            let Some(pending) = rx.get(consumed..filled) else { return Err(Error::Internal) };
            let len = match mbap::next_frame_len(pending) {
                Ok(Some(len)) => len,
                Ok(None) => break,
                Err(mbap::Error::BadLength(len)) => return Err(Error::BadLength(len)),
                Err(mbap::Error::Truncated) => break,
            };
            let Some(frame) = pending.get(..len) else { return Err(Error::Internal) };
            // The configuration in force for each request: a change applies at once.
            let (outcome, idle_timeout) = server.answer(frame, &mut reply, rights);
            match outcome {
                Outcome::Reply { len, function, write, exception, .. } => {
                    // The address is read only when a line is logged (the
                    // log macros evaluate their arguments only then).
                    let address = || be_u16(frame, ADDRESS).unwrap_or(0);
                    if let Some(exception) = exception {
                        debug!("slot {}: function {:#x} at {}: {}", slot, u8::from(function), address(), exception);
                    } else if write {
                        debug!("slot {}: function {:#x} wrote at {}", slot, u8::from(function), address());
                    }
                    let Some(out) = reply.get(..len) else { return Err(Error::Internal) };
                    let deadline = || idle_timeout.map(|t| Instant::now() + t);
                    guarded(write_all(stream, out), deadline, server, slot).await??;
                }
                Outcome::Discard { protocol_id } => warn!("slot {}: discarded protocol id {}", slot, protocol_id),
                Outcome::NotWhole => return Err(Error::Internal),
            }
            consumed += len;
            last_request = Instant::now();
            server.slots().touch(slot, last_request);
        }
        if consumed > 0 {
            rx.copy_within(consumed..filled, 0);
            filled -= consumed;
            frame_started = None;
        }
        if filled > 0 && frame_started.is_none() {
            frame_started = Some(Instant::now());
        }

        let deadline = || {
            server.with_config(|config| match frame_started {
                Some(started) => Some(started + config.frame_timeout),
                None => config.idle_timeout.map(|t| last_request + t),
            })
        };
        let Some(free) = rx.get_mut(filled..) else { return Err(Error::Internal) };
        match guarded(stream.read(free), deadline, server, slot).await {
            Ok(Ok(0)) => return Ok(()),
            Ok(Ok(n)) => filled += n,
            Ok(Err(e)) => return Err(Error::Transport(e)),
            Err(Error::IdleTimeout) if frame_started.is_some() => return Err(Error::FrameTimeout),
            Err(e) => return Err(e),
        }
    }
}

/// Runs `io` until the deadline `deadline()` gives (`None`: none) or until
/// the slot is evicted.
///
/// One future polling the three in turn (the I/O first, then the deadline,
/// then the eviction), all pinned where they are: nested `select`s and
/// `with_deadline` moved each future several times per call, a few hundred
/// instructions a request on the Cortex-M4 (scripts/bench-mcu). `deadline`
/// is called, and the timer armed, only when the I/O does not complete on
/// its first poll (a reply's write almost always does).
async fn guarded<T, E, F: Future<Output = T>, S: Service>(
    io: F,
    deadline: impl FnOnce() -> Option<Instant>,
    server: &Server<'_, S>,
    slot: SlotId,
) -> Result<T, Error<E>> {
    let mut io = pin!(io);
    let mut deadline = Some(deadline);
    let mut timer = None;
    let mut evicted = pin!(server.slots().evicted(slot));
    poll_fn(|cx| {
        if let Poll::Ready(result) = io.as_mut().poll(cx) {
            return Poll::Ready(Ok(result));
        }
        if let Some(at) = deadline.take().and_then(|deadline| deadline()) {
            timer = Some(Timer::at(at));
        }
        if let Some(timer) = timer.as_mut()
            && Pin::new(timer).poll(cx).is_ready()
        {
            return Poll::Ready(Err(Error::IdleTimeout));
        }
        if evicted.as_mut().poll(cx).is_ready() {
            return Poll::Ready(Err(Error::Evicted));
        }
        Poll::Pending
    })
    .await
}

/// `write_all` that reports a zero-length write instead of panicking.
async fn write_all<S: Write>(stream: &mut S, mut bytes: &[u8]) -> Result<(), Error<S::Error>> {
    while !bytes.is_empty() {
        match stream.write(bytes).await {
            Ok(0) => return Err(Error::WriteZero),
            Ok(n) => match bytes.get(n..) {
                Some(rest) => bytes = rest,
                None => return Err(Error::Internal),
            },
            Err(e) => return Err(Error::Transport(e)),
        }
    }
    Ok(())
}

#[cfg(test)]
mod properties;
#[cfg(test)]
mod tests;
