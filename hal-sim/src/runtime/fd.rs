//! The descriptor waits: a task names a non-blocking descriptor it waits to
//! read, and the loop's `ppoll(2)` wakes it when the descriptor is readable
//! (or has hung up or failed, so that the next read says so).
//!
//! The waits are a short list on the loop's thread. `ppoll(2)` is
//! level-triggered: a task that tried its read, got `WouldBlock` and then
//! waits loses nothing that came in between.

use std::cell::RefCell;
use std::os::fd::{AsRawFd, BorrowedFd, RawFd};
use std::task::{Context, Poll, Waker};

#[derive(Debug)]
enum State {
    /// Not ready when last polled; `ppoll(2)` wakes this waker.
    Waiting(Waker),
    /// `ppoll(2)` found it ready; the next poll of the wait completes.
    Ready,
}

/// One descriptor waited on. At most one task waits on each descriptor: a
/// second one takes the first one's place.
#[derive(Debug)]
struct Wait {
    fd: RawFd,
    state: State,
}

thread_local! {
    /// The waits of the loop's tasks (the loop's thread only).
    static WAITS: RefCell<Vec<Wait>> = const { RefCell::new(Vec::new()) };
}

/// Ready once the loop has found `fd` readable since the wait began; if not,
/// `cx`'s waker is woken when it is. For a driver polled by embassy (the
/// TAP): call it after a read said `WouldBlock`, and read only once it is
/// ready. The wait stays until it is found ready.
pub fn poll_readable(fd: BorrowedFd<'_>, cx: &mut Context<'_>) -> Poll<()> {
    let fd = fd.as_raw_fd();
    let waker = cx.waker();
    WAITS.with_borrow_mut(|waits| {
        let Some(index) = waits.iter().position(|w| w.fd == fd) else {
            waits.push(Wait { fd, state: State::Waiting(waker.clone()) });
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

/// Appends one `pollfd` per wait, in the list's order, for the loop's
/// `ppoll(2)`; a wait already found ready gets descriptor -1, which the
/// kernel skips.
pub(super) fn fill(pollfds: &mut Vec<libc::pollfd>) {
    WAITS.with_borrow(|waits| {
        pollfds.extend(waits.iter().map(|w| libc::pollfd {
            fd: if matches!(w.state, State::Waiting(_)) { w.fd } else { -1 },
            events: libc::POLLIN,
            revents: 0,
        }));
    });
}

/// After `ppoll(2)` on what [`fill`] appended: marks each wait whose
/// descriptor is ready and wakes its task, which will read it.
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
#[allow(clippy::unwrap_used, reason = "a failed step is a failed test")]
mod tests {
    use std::io::Write as _;
    use std::os::fd::AsFd as _;
    use std::os::unix::net::UnixStream;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::task::Wake;

    use super::*;

    /// Counts its wakes.
    #[derive(Default)]
    struct Count(AtomicUsize);

    impl Wake for Count {
        fn wake(self: Arc<Self>) {
            self.0.fetch_add(1, Ordering::SeqCst);
        }
    }

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
}
