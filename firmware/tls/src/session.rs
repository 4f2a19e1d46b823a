//! One TLS connection over any `embedded-io-async` stream.
//!
//! Mbed TLS is synchronous: it reads and writes through two callbacks.
//! Here they only move bytes between Mbed TLS and two small buffers
//! ([`Pipe`]); when Mbed TLS wants bytes that have not come yet, or room
//! that has not been sent yet, it says so (`WANT_READ`, `WANT_WRITE`), and
//! the session awaits the stream and calls it again. No callback blocks, and
//! the stream is touched only by the async code.

use core::ffi::{c_int, c_uchar, c_void};
use core::marker::PhantomData;
use core::mem::size_of;
use core::ptr::{self, NonNull};

use embedded_io_async::{ErrorType, Read, Write};
use mbedtls_rs_sys as sys;

use crate::{Error, Server, arena, check};

/// Bytes read from the stream and not yet taken by Mbed TLS.
pub const RX_LEN: usize = 1024;
/// Bytes Mbed TLS wrote and not yet sent.
pub const TX_LEN: usize = 1024;

/// The buffers between Mbed TLS's callbacks and the stream.
#[derive(Debug)]
struct Pipe {
    rx: [u8; RX_LEN],
    rx_start: usize,
    rx_end: usize,
    /// The peer closed its side of the stream.
    eof: bool,
    tx: [u8; TX_LEN],
    tx_len: usize,
}

impl Pipe {
    const fn new() -> Self {
        Self { rx: [0; RX_LEN], rx_start: 0, rx_end: 0, eof: false, tx: [0; TX_LEN], tx_len: 0 }
    }
}

unsafe extern "C" fn send(context: *mut c_void, data: *const c_uchar, len: usize) -> c_int {
    // SAFETY: the context is the session's pipe, set before every call
    // into Mbed TLS; `data` holds `len` bytes.
    let (pipe, data) = unsafe { (&mut *context.cast::<Pipe>(), core::slice::from_raw_parts(data, len)) };
    let Some(room) = pipe.tx.get_mut(pipe.tx_len..).filter(|room| !room.is_empty()) else {
        return sys::MBEDTLS_ERR_SSL_WANT_WRITE;
    };
    let n = room.len().min(data.len());
    let (Some(to), Some(from)) = (room.get_mut(..n), data.get(..n)) else { return sys::MBEDTLS_ERR_SSL_INTERNAL_ERROR };
    to.copy_from_slice(from);
    pipe.tx_len += n;
    c_int::try_from(n).unwrap_or(sys::MBEDTLS_ERR_SSL_INTERNAL_ERROR)
}

unsafe extern "C" fn recv(context: *mut c_void, data: *mut c_uchar, len: usize) -> c_int {
    // SAFETY: as `send`; `data` has room for `len` bytes.
    let (pipe, data) = unsafe { (&mut *context.cast::<Pipe>(), core::slice::from_raw_parts_mut(data, len)) };
    let Some(pending) = pipe.rx.get(pipe.rx_start..pipe.rx_end) else { return sys::MBEDTLS_ERR_SSL_INTERNAL_ERROR };
    if pending.is_empty() {
        // Zero is the end of the stream to Mbed TLS.
        return if pipe.eof { 0 } else { sys::MBEDTLS_ERR_SSL_WANT_READ };
    }
    let n = pending.len().min(data.len());
    let (Some(to), Some(from)) = (data.get_mut(..n), pending.get(..n)) else {
        return sys::MBEDTLS_ERR_SSL_INTERNAL_ERROR;
    };
    to.copy_from_slice(from);
    pipe.rx_start += n;
    c_int::try_from(n).unwrap_or(sys::MBEDTLS_ERR_SSL_INTERNAL_ERROR)
}

/// A server-side TLS session over `stream`.
#[derive(Debug)]
pub struct Session<'s, S> {
    ssl: NonNull<sys::mbedtls_ssl_context>,
    pipe: Pipe,
    stream: S,
    _server: PhantomData<&'s Server>,
}

impl<'s, S: Read + Write> Session<'s, S> {
    /// A session of `server` over `stream`; [`Session::handshake`] next.
    /// Fails when the arena has no room for it (Mbed TLS's record buffers).
    pub fn new(server: &'s Server, stream: S) -> Result<Self, Error> {
        // SAFETY: a zeroed context is what `mbedtls_ssl_init` starts from;
        // it is freed by Drop, set up or not.
        let ssl = unsafe { arena::calloc(1, size_of::<sys::mbedtls_ssl_context>()) }.cast();
        let ssl = NonNull::new(ssl).ok_or(Error::OutOfMemory)?;
        let session = Self { ssl, pipe: Pipe::new(), stream, _server: PhantomData };
        // SAFETY: the configuration outlives the session ('s).
        unsafe {
            sys::mbedtls_ssl_init(ssl.as_ptr());
            check(sys::mbedtls_ssl_setup(ssl.as_ptr(), server.config()))?;
        }
        Ok(session)
    }

    /// Runs `step` on the context until it neither waits for bytes nor
    /// for room, moving bytes between the pipe and the stream meanwhile.
    async fn drive(&mut self, mut step: impl FnMut(*mut sys::mbedtls_ssl_context) -> c_int) -> Result<c_int, Error> {
        loop {
            let ssl = self.ssl.as_ptr();
            // SAFETY: the pipe lives in self, which is borrowed across the
            // call; the pointer is set again before every call, so a moved
            // session never leaves Mbed TLS a stale one.
            unsafe {
                sys::mbedtls_ssl_set_bio(ssl, ptr::from_mut(&mut self.pipe).cast(), Some(send), Some(recv), None)
            };
            let status = step(ssl);
            match status {
                sys::MBEDTLS_ERR_SSL_WANT_READ => {
                    self.flush_tx().await?;
                    self.fill_rx().await?;
                }
                sys::MBEDTLS_ERR_SSL_WANT_WRITE => self.flush_tx().await?,
                _ => {
                    self.flush_pending().await?;
                    return Ok(status);
                }
            }
        }
    }

    /// Hands everything Mbed TLS wrote to the stream, what it still holds
    /// included. On a record that fails its check (bad_record_mac) Mbed TLS
    /// sends the alert and returns the error whether or not the alert went
    /// out whole (ssl_msg.c ignores the alert's `WANT_WRITE`): when the pipe
    /// was nearly full, the rest of the alert would stay inside it and the
    /// peer would see a record cut short (found by the tls fuzz target).
    async fn flush_pending(&mut self) -> Result<(), Error> {
        loop {
            self.flush_tx().await?;
            let ssl = self.ssl.as_ptr();
            // SAFETY: a set-up context; `out_left` counts the bytes Mbed
            // TLS wrote and has not yet handed to `send`.
            if unsafe { (*ssl).private_out_left } == 0 {
                return Ok(());
            }
            // SAFETY: as in `drive`. With bytes pending, sending an alert
            // only flushes them (`mbedtls_ssl_send_alert_message` returns
            // `mbedtls_ssl_flush_output`'s status, the one public way to it)
            // and writes no alert of its own.
            let status = unsafe {
                sys::mbedtls_ssl_set_bio(ssl, ptr::from_mut(&mut self.pipe).cast(), Some(send), Some(recv), None);
                sys::mbedtls_ssl_send_alert_message(
                    ssl,
                    sys::MBEDTLS_SSL_ALERT_LEVEL_FATAL as u8,
                    sys::MBEDTLS_SSL_ALERT_MSG_CLOSE_NOTIFY as u8,
                )
            };
            match status {
                0 | sys::MBEDTLS_ERR_SSL_WANT_WRITE => {}
                _ => {
                    self.flush_tx().await?;
                    return Ok(());
                }
            }
        }
    }

    async fn fill_rx(&mut self) -> Result<(), Error> {
        let pipe = &mut self.pipe;
        if pipe.rx_start == pipe.rx_end {
            pipe.rx_start = 0;
            pipe.rx_end = 0;
        }
        let Some(room) = pipe.rx.get_mut(pipe.rx_end..).filter(|room| !room.is_empty()) else {
            // Mbed TLS asked for more while the pipe is full: it takes what
            // is there first, so this cannot happen; were it to, stop.
            return Err(Error::Internal);
        };
        match self.stream.read(room).await {
            Ok(0) => pipe.eof = true,
            Ok(n) => pipe.rx_end += n.min(room.len()),
            Err(e) => return Err(Error::Io(embedded_io_async::Error::kind(&e))),
        }
        Ok(())
    }

    /// Hands what Mbed TLS wrote to the stream. The stream is not flushed:
    /// an embassy-net socket's `flush` waits for the peer's acknowledgement,
    /// a delayed ACK's time (up to 40 ms on Linux) after every reply;
    /// [`Write::flush`] and [`Session::close`] flush it.
    async fn flush_tx(&mut self) -> Result<(), Error> {
        let pipe = &mut self.pipe;
        let mut sent = 0;
        while let Some(rest) = pipe.tx.get(sent..pipe.tx_len).filter(|rest| !rest.is_empty()) {
            match self.stream.write(rest).await {
                Ok(0) => return Err(Error::Io(embedded_io_async::ErrorKind::WriteZero)),
                Ok(n) => sent += n.min(rest.len()),
                Err(e) => return Err(Error::Io(embedded_io_async::Error::kind(&e))),
            }
        }
        pipe.tx_len = 0;
        Ok(())
    }

    async fn flush_stream(&mut self) -> Result<(), Error> {
        self.stream.flush().await.map_err(|e| Error::Io(embedded_io_async::Error::kind(&e)))
    }

    /// The TLS handshake: on success the session carries application data,
    /// and, when the server verifies clients, the client's certificate has
    /// chained to the CA.
    pub async fn handshake(&mut self) -> Result<(), Error> {
        // SAFETY: a set-up context (new).
        let status = self.drive(|ssl| unsafe { sys::mbedtls_ssl_handshake(ssl) }).await?;
        check(status)
    }

    /// The client's certificate (DER), once the handshake verified it.
    pub fn peer_certificate(&self) -> Option<&[u8]> {
        // SAFETY: the certificate belongs to the context, which lives as
        // long as self; its `raw` buffer holds `len` bytes.
        unsafe {
            let certificate = sys::mbedtls_ssl_get_peer_cert(self.ssl.as_ptr()).as_ref()?;
            let raw = certificate.raw;
            if raw.p.is_null() {
                return None;
            }
            Some(core::slice::from_raw_parts(raw.p, raw.len))
        }
    }

    /// The protocol in use once the handshake is done: `TLSv1.2` or `TLSv1.3`.
    pub fn version(&self) -> &'static str {
        // SAFETY: a set-up context; the field is what Mbed TLS's own
        // (inline, so unbound) `mbedtls_ssl_get_version_number` reads.
        match unsafe { (*self.ssl.as_ptr()).private_tls_version } {
            sys::mbedtls_ssl_protocol_version_MBEDTLS_SSL_VERSION_TLS1_2 => "TLSv1.2",
            sys::mbedtls_ssl_protocol_version_MBEDTLS_SSL_VERSION_TLS1_3 => "TLSv1.3",
            _ => "unknown",
        }
    }

    /// Sends close_notify. The stream stays open: closing it is its owner's.
    pub async fn close(&mut self) -> Result<(), Error> {
        // SAFETY: a set-up context.
        let status = self.drive(|ssl| unsafe { sys::mbedtls_ssl_close_notify(ssl) }).await?;
        check(status)?;
        self.flush_stream().await
    }

    /// The stream under the session.
    pub fn stream(&mut self) -> &mut S {
        &mut self.stream
    }
}

impl<S> Drop for Session<'_, S> {
    fn drop(&mut self) {
        // SAFETY: initialized in `new`; `mbedtls_ssl_free` takes a context
        // set up or not.
        unsafe {
            sys::mbedtls_ssl_free(self.ssl.as_ptr());
            arena::free(self.ssl.as_ptr().cast());
        }
    }
}

impl<S> ErrorType for Session<'_, S> {
    type Error = Error;
}

impl<S: Read + Write> Read for Session<'_, S> {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Error> {
        if buf.is_empty() {
            return Ok(0);
        }
        let (data, len) = (buf.as_mut_ptr(), buf.len());
        // SAFETY: `buf` has room for `len` bytes for the whole call.
        let status = self.drive(|ssl| unsafe { sys::mbedtls_ssl_read(ssl, data, len) }).await?;
        match status {
            n @ 1.. => Ok(usize::try_from(n).unwrap_or(0).min(len)),
            0 | sys::MBEDTLS_ERR_SSL_PEER_CLOSE_NOTIFY | sys::MBEDTLS_ERR_SSL_CONN_EOF => Ok(0),
            error => Err(Error::Mbedtls(error)),
        }
    }
}

impl<S: Read + Write> Write for Session<'_, S> {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Error> {
        if buf.is_empty() {
            return Ok(0);
        }
        let (data, len) = (buf.as_ptr(), buf.len());
        // SAFETY: `buf` holds `len` bytes for the whole call.
        let status = self.drive(|ssl| unsafe { sys::mbedtls_ssl_write(ssl, data, len) }).await?;
        match status {
            n @ 1.. => Ok(usize::try_from(n).unwrap_or(0).min(len)),
            error => Err(Error::Mbedtls(error)),
        }
    }

    async fn flush(&mut self) -> Result<(), Error> {
        self.flush_tx().await?;
        self.flush_stream().await
    }
}
