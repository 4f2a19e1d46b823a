//! The descriptor waits: a task names a non-blocking descriptor it waits to
//! read or write, and the loop's `ppoll(2)` wakes it when the descriptor is
//! ready (or has hung up or failed, so that the next read or write says so).
//!
//! The waits are a short list on the loop's thread (the TAP, the control
//! listener, a few control connections). `ppoll(2)` is level-triggered: a
//! task that tried its read, got `WouldBlock` and then waits loses nothing
//! that came in between.

use std::cell::RefCell;
use std::io;
use std::os::fd::{AsFd, AsRawFd, BorrowedFd, RawFd};
use std::pin::Pin;
use std::task::{Context, Poll, Waker};

/// What a task waits for its descriptor to be.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Interest {
    Readable,
    Writable,
}

impl Interest {
    fn events(self) -> libc::c_short {
        match self {
            Self::Readable => libc::POLLIN,
            Self::Writable => libc::POLLOUT,
        }
    }
}

#[derive(Debug)]
enum State {
    /// Not ready when last polled; `ppoll(2)` wakes this waker.
    Waiting(Waker),
    /// `ppoll(2)` found it ready; the next poll of the wait completes.
    Ready,
}

/// One descriptor waited on, one way. At most one task waits on each
/// descriptor each way: a second one takes the first one's place.
#[derive(Debug)]
struct Wait {
    fd: RawFd,
    interest: Interest,
    state: State,
}

thread_local! {
    /// The waits of the loop's tasks (the loop's thread only).
    static WAITS: RefCell<Vec<Wait>> = const { RefCell::new(Vec::new()) };
}

/// Ready once `ppoll(2)` has found `fd` ready `interest`-wise; until then the
/// wait is kept with `waker`, which is woken then.
fn poll_ready(fd: RawFd, interest: Interest, waker: &Waker) -> Poll<()> {
    WAITS.with_borrow_mut(|waits| {
        let Some(index) = waits.iter().position(|w| w.fd == fd && w.interest == interest) else {
            waits.push(Wait { fd, interest, state: State::Waiting(waker.clone()) });
            return Poll::Pending;
        };
        match waits.get_mut(index).map(|w| &mut w.state) {
            Some(State::Waiting(waiting)) => {
                if !waiting.will_wake(waker) {
                    waiting.clone_from(waker);
                }
                Poll::Pending
            }
            Some(State::Ready) => {
                waits.swap_remove(index);
                Poll::Ready(())
            }
            None => Poll::Pending,
        }
    })
}

/// Forgets the wait on `fd`, `interest`-wise, if there is one.
fn cancel(fd: RawFd, interest: Interest) {
    WAITS.with_borrow_mut(|waits| waits.retain(|w| w.fd != fd || w.interest != interest));
}

/// Ready once the loop has found `fd` readable since the wait began; if not,
/// `cx`'s waker is woken when it is. For a driver polled by embassy (the
/// TAP): call it after a read said `WouldBlock`, and read only once it is
/// ready. The wait stays until it is found ready.
pub fn poll_readable(fd: BorrowedFd<'_>, cx: &mut Context<'_>) -> Poll<()> {
    poll_ready(fd.as_raw_fd(), Interest::Readable, cx.waker())
}

/// A wait for a descriptor to be ready one way; dropping it ends the wait.
#[derive(Debug)]
#[must_use = "a wait does nothing unless awaited"]
pub struct Readiness<'fd> {
    fd: BorrowedFd<'fd>,
    interest: Interest,
    /// A wait of ours is in the list.
    waiting: bool,
}

impl Future for Readiness<'_> {
    type Output = ();

    fn poll(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<()> {
        let ready = poll_ready(self.fd.as_raw_fd(), self.interest, cx.waker());
        self.waiting = ready.is_pending();
        ready
    }
}

impl Drop for Readiness<'_> {
    fn drop(&mut self) {
        if self.waiting {
            cancel(self.fd.as_raw_fd(), self.interest);
        }
    }
}

/// Completes once the loop finds `fd` readable (or hung up, or failed).
pub fn readable(fd: BorrowedFd<'_>) -> Readiness<'_> {
    Readiness { fd, interest: Interest::Readable, waiting: false }
}

/// Completes once the loop finds `fd` writable (or hung up, or failed).
pub fn writable(fd: BorrowedFd<'_>) -> Readiness<'_> {
    Readiness { fd, interest: Interest::Writable, waiting: false }
}

/// Runs `op` on the non-blocking `source` until it does not say
/// `WouldBlock`, waiting for `source` to be readable between tries:
/// `read_with(&listener, UnixListener::accept)`, `read_with(&stream, |mut s| s.read(buf))`.
pub async fn read_with<S: AsFd, T>(source: &S, mut op: impl FnMut(&S) -> io::Result<T>) -> io::Result<T> {
    loop {
        match op(source) {
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => readable(source.as_fd()).await,
            result => return result,
        }
    }
}

/// [`read_with`] for writes: waits for `source` to be writable between tries.
pub async fn write_with<S: AsFd, T>(source: &S, mut op: impl FnMut(&S) -> io::Result<T>) -> io::Result<T> {
    loop {
        match op(source) {
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => writable(source.as_fd()).await,
            result => return result,
        }
    }
}

/// Appends one `pollfd` per wait, in the list's order, for the loop's
/// `ppoll(2)`; a wait already found ready gets descriptor -1, which the
/// kernel skips.
pub(super) fn fill(pollfds: &mut Vec<libc::pollfd>) {
    WAITS.with_borrow(|waits| {
        pollfds.extend(waits.iter().map(|w| libc::pollfd {
            fd: if matches!(w.state, State::Waiting(_)) { w.fd } else { -1 },
            events: w.interest.events(),
            revents: 0,
        }));
    });
}

/// After `ppoll(2)` on what [`fill`] appended: marks each wait whose
/// descriptor is ready and wakes its task, which will read or write it.
pub(super) fn dispatch(pollfds: &[libc::pollfd]) {
    for (index, pollfd) in pollfds.iter().enumerate() {
        if pollfd.fd < 0 || pollfd.revents == 0 {
            continue;
        }
        let waker = WAITS.with_borrow_mut(|waits| {
            let wait = waits.get_mut(index).filter(|w| w.fd == pollfd.fd)?;
            match std::mem::replace(&mut wait.state, State::Ready) {
                State::Waiting(waker) => Some(waker),
                State::Ready => None,
            }
        });
        // Woken outside the borrow: a waker may do anything.
        if let Some(waker) = waker {
            waker.wake();
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::indexing_slicing, reason = "a failed step is a failed test")]
mod tests {
    use std::io::{Read as _, Write as _};
    use std::os::unix::net::UnixStream;
    use std::sync::Arc;
    use std::sync::atomic::Ordering;

    use super::*;

    use crate::runtime::WakeCount as Count;

    /// One turn of the loop's descriptor part, without sleeping.
    fn turn() {
        let mut pollfds = Vec::new();
        fill(&mut pollfds);
        // SAFETY: `pollfds` is a live array of `pollfds.len()` pollfd.
        let n = unsafe { libc::poll(pollfds.as_mut_ptr(), pollfds.len() as libc::nfds_t, 0) };
        assert!(n >= 0);
        dispatch(&pollfds);
    }

    fn waits() -> usize {
        WAITS.with_borrow(Vec::len)
    }

    #[test]
    fn a_read_wait_is_woken_once_data_comes_then_completes_and_is_gone() {
        let (mut near, far) = UnixStream::pair().unwrap();
        let count = Arc::new(Count::default());
        let waker = Waker::from(count.clone());
        let mut cx = Context::from_waker(&waker);

        assert!(poll_readable(far.as_fd(), &mut cx).is_pending());
        turn();
        assert_eq!(count.0.load(Ordering::SeqCst), 0, "nothing to read yet");
        assert!(poll_readable(far.as_fd(), &mut cx).is_pending(), "still waiting");
        assert_eq!(waits(), 1, "one wait, not two");

        near.write_all(b"x").unwrap();
        turn();
        assert_eq!(count.0.load(Ordering::SeqCst), 1);
        turn();
        assert_eq!(count.0.load(Ordering::SeqCst), 1, "woken once");
        assert!(poll_readable(far.as_fd(), &mut cx).is_ready());
        assert_eq!(waits(), 0);
    }

    #[test]
    fn a_dropped_wait_leaves_nothing_behind() {
        let (_near, far) = UnixStream::pair().unwrap();
        let waker = Waker::from(Arc::new(Count::default()));
        let mut cx = Context::from_waker(&waker);
        let mut wait = Box::pin(readable(far.as_fd()));
        assert!(wait.as_mut().poll(&mut cx).is_pending());
        assert_eq!(waits(), 1);
        drop(wait);
        assert_eq!(waits(), 0);
    }

    #[test]
    fn a_hang_up_wakes_a_reader() {
        let (near, far) = UnixStream::pair().unwrap();
        let count = Arc::new(Count::default());
        let waker = Waker::from(count.clone());
        let mut cx = Context::from_waker(&waker);
        assert!(poll_readable(far.as_fd(), &mut cx).is_pending());
        drop(near);
        turn();
        assert_eq!(count.0.load(Ordering::SeqCst), 1);
        assert!(poll_readable(far.as_fd(), &mut cx).is_ready());
    }

    #[test]
    fn read_with_waits_out_would_block() {
        let (mut near, far) = UnixStream::pair().unwrap();
        far.set_nonblocking(true).unwrap();
        let count = Arc::new(Count::default());
        let waker = Waker::from(count.clone());
        let mut cx = Context::from_waker(&waker);
        let mut buffer = [0u8; 4];
        let mut read = std::pin::pin!(read_with(&far, |mut s| s.read(&mut buffer)));

        assert!(read.as_mut().poll(&mut cx).is_pending());
        near.write_all(b"ab").unwrap();
        turn();
        assert_eq!(count.0.load(Ordering::SeqCst), 1);
        assert!(matches!(read.as_mut().poll(&mut cx), Poll::Ready(Ok(2))));
        assert_eq!(waits(), 0);
    }

    #[test]
    fn a_reader_and_a_writer_wait_on_one_descriptor_apart() {
        let (_near, far) = UnixStream::pair().unwrap();
        let waker = Waker::from(Arc::new(Count::default()));
        let mut cx = Context::from_waker(&waker);
        let mut write = std::pin::pin!(writable(far.as_fd()));
        assert!(poll_readable(far.as_fd(), &mut cx).is_pending());
        assert!(write.as_mut().poll(&mut cx).is_pending());
        turn();
        assert!(write.as_mut().poll(&mut cx).is_ready(), "an empty socket is writable");
        assert!(poll_readable(far.as_fd(), &mut cx).is_pending(), "but has nothing to read");
        cancel(far.as_raw_fd(), Interest::Readable);
        assert_eq!(waits(), 0);
    }
}
