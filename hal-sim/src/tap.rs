//! The simulated device's Ethernet port: a Linux TAP as an embassy-net driver.
//!
//! One frame buffer each way, allocated when the TAP is opened: `receive`
//! reads a frame into the receive buffer and lends it to the stack,
//! `transmit` lends the transmit buffer and writes the frame out. No heap
//! allocation per frame, and no read system call while the TAP is known to be
//! empty: after a read says `WouldBlock`, the runtime's loop waits on the
//! descriptor in its `ppoll(2)` ([`crate::runtime::poll_readable`]).
//!
//! At most one frame is read per round of the runtime's loop
//! ([`crate::runtime::round`]). smoltcp's `poll` takes every frame waiting
//! before it sends anything, then sends in the order of its sockets: with
//! several requests read at once, the replies on the first sockets always
//! went out first, their clients came back first, and at 8 connections at
//! full rate the connection on the last socket got 0.7 of the requests of
//! the one on the first (bench-net's fairness). One frame a round, the
//! replies go out in the order the requests came, and each connection gets
//! its turn (fairness 1.00), for no more system calls: a read that finds the
//! TAP empty was made once per batch before, and is made once per frame only
//! when frames come one at a time anyway.

use std::io;
use std::os::fd::{AsFd, AsRawFd, FromRawFd, OwnedFd};
use std::task::Context;

use embassy_net_driver::{Capabilities, Driver, HardwareAddress, LinkState};

use crate::runtime;

/// Ethernet header: destination, source, EtherType.
const ETHERNET_HEADER_LEN: usize = 14;
/// The frame size when the TAP's MTU cannot be read (1500 + header).
const DEFAULT_FRAME_LEN: usize = 1500 + ETHERNET_HEADER_LEN;

/// A TAP interface opened for Ethernet frames (no packet information header).
#[derive(Debug)]
pub struct TunTapDevice {
    fd: OwnedFd,
    /// Largest frame, header included (smoltcp's MTU for Ethernet).
    frame_len: usize,
    rx: Box<[u8]>,
    tx: Box<[u8]>,
    /// False after a read found the TAP empty, until `ppoll(2)` says otherwise.
    readable: bool,
    /// The loop's round in which the last frame was read.
    read_in: u64,
    mac: [u8; 6],
}

fn ifreq(name: &str) -> io::Result<libc::ifreq> {
    // SAFETY: ifreq is plain old data; all zeroes is a valid value.
    let mut ifreq: libc::ifreq = unsafe { std::mem::zeroed() };
    if name.is_empty() || name.len() >= ifreq.ifr_name.len() || name.contains('\0') {
        return Err(io::Error::new(io::ErrorKind::InvalidInput, "a TAP name is 1 to 15 bytes"));
    }
    for (dst, src) in ifreq.ifr_name.iter_mut().zip(name.bytes()) {
        *dst = src as libc::c_char;
    }
    Ok(ifreq)
}

impl TunTapDevice {
    /// Opens (as root: creates) the TAP `name`, non-blocking.
    pub fn new(name: &str) -> io::Result<Self> {
        let mut request = ifreq(name)?;
        // SAFETY: a NUL-terminated path; the descriptor returned is owned below.
        let fd = unsafe { libc::open(c"/dev/net/tun".as_ptr(), libc::O_RDWR | libc::O_NONBLOCK | libc::O_CLOEXEC) };
        if fd < 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: `fd` is a new descriptor that nothing else owns.
        let fd = unsafe { OwnedFd::from_raw_fd(fd) };
        request.ifr_ifru.ifru_flags = (libc::IFF_TAP | libc::IFF_NO_PI) as libc::c_short;
        // SAFETY: TUNSETIFF reads and writes one ifreq, which `request` is.
        if unsafe { libc::ioctl(fd.as_raw_fd(), libc::TUNSETIFF, &raw mut request) } < 0 {
            return Err(io::Error::last_os_error());
        }
        let frame_len = ip_mtu(name).map_or(DEFAULT_FRAME_LEN, |mtu| mtu + ETHERNET_HEADER_LEN);
        Ok(Self {
            fd,
            frame_len,
            rx: vec![0; frame_len].into_boxed_slice(),
            tx: vec![0; frame_len].into_boxed_slice(),
            readable: true,
            read_in: u64::MAX,
            mac: [0x02, 0, 0, 0, 0, 0x01],
        })
    }

    /// A device over `fd`, a non-blocking descriptor that gives one frame per read.
    #[cfg(test)]
    fn from_fd(fd: OwnedFd) -> Self {
        Self {
            fd,
            frame_len: DEFAULT_FRAME_LEN,
            rx: vec![0; DEFAULT_FRAME_LEN].into_boxed_slice(),
            tx: vec![0; DEFAULT_FRAME_LEN].into_boxed_slice(),
            readable: true,
            read_in: u64::MAX,
            mac: [0x02, 0, 0, 0, 0, 0x01],
        }
    }

    /// Sets the MAC address the stack uses (unicast: the lowest bit of the first byte clear).
    pub fn set_hardware_address(&mut self, mac: [u8; 6]) {
        self.mac = mac;
    }
}

/// The interface's IP MTU (SIOCGIFMTU), if the kernel tells it.
fn ip_mtu(name: &str) -> Option<usize> {
    let mut request = ifreq(name).ok()?;
    // SAFETY: a datagram socket only to ask about the interface; closed below.
    let socket = unsafe { libc::socket(libc::AF_INET, libc::SOCK_DGRAM | libc::SOCK_CLOEXEC, 0) };
    if socket < 0 {
        return None;
    }
    // SAFETY: `socket` is a new descriptor that nothing else owns.
    let socket = unsafe { OwnedFd::from_raw_fd(socket) };
    // SAFETY: SIOCGIFMTU reads and writes one ifreq, which `request` is.
    if unsafe { libc::ioctl(socket.as_raw_fd(), libc::SIOCGIFMTU, &raw mut request) } < 0 {
        return None;
    }
    // SAFETY: SIOCGIFMTU filled the union's MTU member.
    usize::try_from(unsafe { request.ifr_ifru.ifru_mtu }).ok().filter(|&mtu| mtu >= 576)
}

impl Driver for TunTapDevice {
    type RxToken<'a> = RxToken<'a>;
    type TxToken<'a> = TxToken<'a>;

    fn receive(&mut self, cx: &mut Context) -> Option<(Self::RxToken<'_>, Self::TxToken<'_>)> {
        if !self.readable {
            if runtime::poll_readable(self.fd.as_fd(), cx).is_pending() {
                return None;
            }
            self.readable = true;
        }
        // One frame per round (see the module's documentation); the next
        // round reads on.
        let round = runtime::round();
        if self.read_in == round {
            cx.waker().wake_by_ref();
            return None;
        }
        let fd = self.fd.as_raw_fd();
        // SAFETY: reads at most `rx.len()` bytes into the live buffer `rx`.
        let n = unsafe { libc::read(fd, self.rx.as_mut_ptr().cast(), self.rx.len()) };
        match usize::try_from(n) {
            Ok(len) => {
                self.read_in = round;
                let frame = self.rx.get_mut(..len)?;
                Some((RxToken { frame }, TxToken { fd: &self.fd, buffer: &mut self.tx }))
            }
            Err(_) => {
                let e = io::Error::last_os_error();
                if e.kind() != io::ErrorKind::WouldBlock && e.kind() != io::ErrorKind::Interrupted {
                    log::warn!("tap: read failed: {e}");
                }
                self.readable = false;
                // Wait now: the frame may come before the loop sleeps.
                if runtime::poll_readable(self.fd.as_fd(), cx).is_ready() {
                    cx.waker().wake_by_ref();
                }
                None
            }
        }
    }

    fn transmit(&mut self, _cx: &mut Context) -> Option<Self::TxToken<'_>> {
        Some(TxToken { fd: &self.fd, buffer: &mut self.tx })
    }

    fn link_state(&mut self, _cx: &mut Context) -> LinkState {
        LinkState::Up
    }

    fn capabilities(&self) -> Capabilities {
        let mut caps = Capabilities::default();
        caps.max_transmission_unit = self.frame_len;
        caps
    }

    fn hardware_address(&self) -> HardwareAddress {
        HardwareAddress::Ethernet(self.mac)
    }
}

/// A received frame, lent from the device's receive buffer.
#[derive(Debug)]
pub struct RxToken<'a> {
    frame: &'a mut [u8],
}

impl embassy_net_driver::RxToken for RxToken<'_> {
    fn consume<R, F: FnOnce(&mut [u8]) -> R>(self, f: F) -> R {
        f(self.frame)
    }
}

/// Room for one frame to send, lent from the device's transmit buffer.
#[derive(Debug)]
pub struct TxToken<'a> {
    fd: &'a OwnedFd,
    buffer: &'a mut [u8],
}

impl embassy_net_driver::TxToken for TxToken<'_> {
    fn consume<R, F: FnOnce(&mut [u8]) -> R>(self, len: usize, f: F) -> R {
        let len = len.min(self.buffer.len());
        let frame = self.buffer.get_mut(..len).unwrap_or_default();
        let result = f(frame);
        // SAFETY: writes the `frame.len()` initialised bytes of `frame`.
        let n = unsafe { libc::write(self.fd.as_raw_fd(), frame.as_ptr().cast(), frame.len()) };
        if n < 0 {
            // A full TAP queue drops the frame, as a busy link would; TCP sends it again.
            log::warn!("tap: frame of {len} bytes not sent: {}", io::Error::last_os_error());
        }
        result
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "a failed step is a failed test")]
mod tests {
    use std::os::unix::net::UnixDatagram;
    use std::sync::Arc;
    use std::sync::atomic::Ordering;
    use std::task::Waker;

    use embassy_net_driver::RxToken as _;

    use super::*;

    use crate::runtime::WakeCount as Count;

    /// The frame `receive` gives, if any.
    fn receive(device: &mut TunTapDevice, cx: &mut Context) -> Option<Vec<u8>> {
        device.receive(cx).map(|(rx, _)| rx.consume(|frame| frame.to_vec()))
    }

    #[test]
    fn one_frame_is_read_per_round_and_the_stack_is_woken_for_the_next() {
        // A datagram socket keeps each write one frame, as a TAP does.
        let (near, far) = UnixDatagram::pair().unwrap();
        far.set_nonblocking(true).unwrap();
        let mut device = TunTapDevice::from_fd(OwnedFd::from(far));
        let count = Arc::new(Count::default());
        let waker = Waker::from(count.clone());
        let mut cx = Context::from_waker(&waker);
        for frame in [&b"first"[..], b"second", b"third"] {
            near.send(frame).unwrap();
        }

        runtime::next_round_for_test();
        assert_eq!(receive(&mut device, &mut cx).as_deref(), Some(&b"first"[..]));
        assert_eq!(receive(&mut device, &mut cx), None, "the second frame waits for the next round");
        assert_eq!(count.0.load(Ordering::SeqCst), 1, "and the stack is woken for it");

        runtime::next_round_for_test();
        assert_eq!(receive(&mut device, &mut cx).as_deref(), Some(&b"second"[..]));
        runtime::next_round_for_test();
        assert_eq!(receive(&mut device, &mut cx).as_deref(), Some(&b"third"[..]));
        runtime::next_round_for_test();
        assert_eq!(receive(&mut device, &mut cx), None, "empty");
        assert_eq!(count.0.load(Ordering::SeqCst), 1, "not woken again: the loop's ppoll(2) waits for the TAP now");
        near.send(b"fourth").unwrap();
        assert_eq!(receive(&mut device, &mut cx), None, "not read before ppoll(2) says it is readable");
    }
}
