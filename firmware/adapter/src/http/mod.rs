//! The HTTP JSON API and the device's page (DEVICE.md section 2), behind
//! the `http` feature: `GET /` (the page, [`page`]), `GET /api/status`,
//! `GET` and `PUT /api/settings`, `PUT /api/password`, `POST /api/reboot`,
//! `/api/factory-reset` and `/api/locate` (docs/http-api.md has every
//! request and response).
//!
//! - [`Backend`] is what a program (a board, hal-sim) gives the API: the
//!   Modbus server and device, the settings store, the password, reboot.
//! - [`Http`] is the shared state of the API: the backend, and the lock
//!   that makes changes one at a time.
//! - [`serve`] answers one connection over any `embedded-io-async` reader
//!   and writer; [`listen`] accepts connections on an embassy-net stack
//!   and serves them, one task per connection ([`MAX_HTTP_CONNECTIONS`]).
//!
//! HTTP/1.1 framing is picoserve's, over this module's limits: a head of
//! at most [`MAX_HEAD_LEN`] bytes (431), a body of at most [`MAX_BODY_LEN`]
//! (413), the whole request within [`REQUEST_TIMEOUT`] of the connection
//! (408), the response within [`WRITE_TIMEOUT`]. One request per
//! connection (`Connection: close`): a client holds a connection for
//! a bounded time, so two slow ones cannot hold the API for long, and the
//! Modbus sessions never wait for it (no blocking lock is held across an
//! `.await`, and each request's work is bounded by its size).
//!
//! Nothing here panics on any input: the head is checked byte by byte
//! before picoserve parses it ([`head`]), JSON is read by a checked reader
//! ([`json`]), and a change is parsed into a copy, validated whole, and
//! only then saved: a rejected change changes nothing.

mod api;
mod auth;
mod backend;
mod control;
pub mod head;
pub mod json;
mod listener;
pub mod page;
mod stream;

use core::cell::Cell;
use core::fmt;

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embassy_time::Duration;
use embedded_io_async::{ErrorKind, Read, Write};
use picoserve::Router;

pub use backend::{Backend, NetworkStatus, Refusal, RobotLinkStatus, RobotSource, StorageStatus};
pub use control::{Controller, Platform};
pub use head::Limit;
pub use listener::{SOCKET_RX_LEN, SOCKET_TX_LEN, listen};

use self::api::Api;
use self::json::Out;
use self::stream::{Clock, Guarded, Paced, Stream, StreamError};
use crate::server::SOCKET_POOL;

/// The HTTP port (hal-sim: `--http-port`).
pub const HTTP_PORT: u16 = 80;

/// Connections served at once: each board runs this many [`listen`] tasks.
pub const MAX_HTTP_CONNECTIONS: usize = 2;

/// Longest request head: the request line and the header fields, up to and
/// including the empty line (a browser's `PUT` with credentials is about
/// 700 bytes). Over it: 431 and the connection closes.
pub const MAX_HEAD_LEN: usize = 1024;

/// Longest request body (the whole settings document with two full
/// allow-lists is about 800 bytes). A `Content-Length` over it: 413 and
/// the connection closes, before any of the body is read.
pub const MAX_BODY_LEN: usize = 1024;

/// The request buffer: a head and a body at their limits.
pub const REQUEST_BUFFER_LEN: usize = MAX_HEAD_LEN + MAX_BODY_LEN;

/// Longest response body: the status document at its largest (every
/// session slot open, every number at its widest: about 900 bytes and 90 a
/// session with its peer's address) and a 400 listing every setting (about
/// 1250 bytes) fit, which a test checks.
pub const MAX_RESPONSE_LEN: usize = {
    let status = 960 + 100 * SOCKET_POOL;
    if status > 1344 { status } else { 1344 }
};

/// The whole request (head and body) must have arrived this long after the
/// connection was accepted: 408, and the connection closes.
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(5);

/// The whole response must have been taken by the client this long after
/// its first byte was written; then the connection closes.
pub const WRITE_TIMEOUT: Duration = Duration::from_secs(5);

/// A request with wrong credentials is answered (401) after this long, so
/// a password is guessed at no more than one try per connection per second.
pub const AUTH_FAILURE_DELAY: Duration = Duration::from_secs(1);

/// How long `POST /api/locate` blinks the status LED.
pub const LOCATE_DURATION: Duration = Duration::from_secs(10);

/// The admin password's length in bytes (DEVICE.md section 1).
pub const MIN_PASSWORD_LEN: usize = 8;
pub const MAX_PASSWORD_LEN: usize = 64;

/// The one user name HTTP Basic authentication takes.
pub const USER: &str = "admin";

/// The `WWW-Authenticate` challenge of a 401.
const REALM_HEADER: &str = "Basic realm=\"mbio\"";

/// picoserve's own timeouts, a backstop behind this module's deadlines
/// (which always end first).
const PICOSERVE: picoserve::Config = {
    let backstop = REQUEST_TIMEOUT.as_millis() + WRITE_TIMEOUT.as_millis();
    let backstop = picoserve::time::Duration::from_millis(backstop);
    picoserve::Config::new(picoserve::Timeouts {
        start_read_request: backstop,
        persistent_start_read_request: backstop,
        read_request: backstop,
        write: backstop,
    })
    .close_connection_after_response()
};

/// What an accepted request left to do once its response went out and
/// its connection closed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Action {
    /// `POST /api/reboot`.
    Reboot,
    /// `POST /api/factory-reset`.
    FactoryReset,
}

/// Why a connection ended without a whole request answered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// The transport failed (reset, or closed under the response).
    Io(ErrorKind),
    /// The request was not whole within [`REQUEST_TIMEOUT`] (answered 408),
    /// or the response not taken within [`WRITE_TIMEOUT`].
    Timeout,
    /// The request broke a limit (answered 431 or 413).
    Limit(Limit),
    /// The request was not HTTP (answered 400 by picoserve).
    BadRequest,
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Io(kind) => write!(f, "transport error: {kind:?}"),
            Self::Timeout => f.write_str("timed out"),
            Self::Limit(Limit::HeadTooLarge) => f.write_str("request head over its limit"),
            Self::Limit(Limit::BodyTooLarge) => f.write_str("request body over its limit"),
            Self::BadRequest => f.write_str("not an HTTP request"),
        }
    }
}

impl core::error::Error for Error {}

/// The API's shared state: the backend, and the lock that makes changes
/// one at a time (an async lock among the HTTP tasks only: waiting for it
/// never blocks the executor or a Modbus session).
pub struct Http<'a, B: Backend> {
    backend: &'a B,
    changes: Mutex<CriticalSectionRawMutex, ()>,
}

impl<B: Backend> fmt::Debug for Http<'_, B> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Http").finish_non_exhaustive()
    }
}

impl<'a, B: Backend> Http<'a, B> {
    pub const fn new(backend: &'a B) -> Self {
        Self { backend, changes: Mutex::new(()) }
    }

    /// The backend.
    pub fn backend(&self) -> &B {
        self.backend
    }

    /// Does what an accepted request left to do ([`serve`] returns it).
    pub async fn perform(&self, action: Action) {
        match action {
            Action::Reboot => self.backend.reboot(),
            Action::FactoryReset => self.backend.factory_reset().await,
        }
    }
}

/// One connection's buffers: the request (head and body) and the response
/// body. Each [`listen`] task keeps one in its static storage.
#[derive(Debug)]
pub struct Buffers {
    request: [u8; REQUEST_BUFFER_LEN],
    response: [u8; MAX_RESPONSE_LEN],
}

impl Default for Buffers {
    fn default() -> Self {
        Self::new()
    }
}

impl Buffers {
    pub const fn new() -> Self {
        Self { request: [0; REQUEST_BUFFER_LEN], response: [0; MAX_RESPONSE_LEN] }
    }
}

/// Serves one connection from `peer` (its IPv4 address; `None`: never
/// allowed to change anything): reads one request from `reader`, writes
/// its response to `writer`. The caller closes the connection afterwards,
/// then does the [`Action`] returned, if any ([`Http::perform`]): a
/// reboot only once its response has gone out.
///
/// A request that breaks a limit or its deadline is answered here (431,
/// 413, 408) and returns the [`Error`]; so does a transport error.
pub async fn serve<B: Backend, R: Read, W: Write>(
    http: &Http<'_, B>,
    peer: Option<[u8; 4]>,
    reader: R,
    writer: W,
    buffers: &mut Buffers,
) -> Result<Option<Action>, Error> {
    let Buffers { request, response } = buffers;
    let api = Api { http, peer, response: Cell::new(Some(response)), action: Cell::new(None) };
    let router = Router::from_service(&api);
    let mut stream = Stream { reader: Guarded::new(reader), writer: Paced::new(writer) };
    let served = picoserve::Server::custom(&router, Clock, &PICOSERVE, request).serve(&mut stream).await;
    let error = match served {
        Ok(_) => return Ok(api.action.take()),
        Err(picoserve::Error::BadRequest) => return Err(Error::BadRequest),
        Err(picoserve::Error::Read(StreamError::Limit(limit))) => Error::Limit(limit),
        Err(picoserve::Error::Read(StreamError::Timeout) | picoserve::Error::ReadTimeout(_)) => Error::Timeout,
        Err(picoserve::Error::Write(StreamError::Timeout) | picoserve::Error::WriteTimeout(_)) => {
            return Err(Error::Timeout);
        }
        Err(picoserve::Error::Read(StreamError::Io(kind)) | picoserve::Error::Write(StreamError::Io(kind))) => {
            return Err(Error::Io(kind));
        }
        Err(picoserve::Error::Write(StreamError::Limit(limit))) => return Err(Error::Limit(limit)),
    };
    // The request broke a limit or its deadline before it was whole:
    // answer for picoserve, which has written nothing.
    let (status, what, limit, unit) = match error {
        Error::Limit(Limit::HeadTooLarge) => ("431", "head", MAX_HEAD_LEN as u64, "bytes"),
        Error::Limit(Limit::BodyTooLarge) => ("413", "body", MAX_BODY_LEN as u64, "bytes"),
        _ => ("408", "", REQUEST_TIMEOUT.as_secs(), "s"),
    };
    let mut body = [0u8; 80];
    let mut out = Out::new(&mut body);
    out.text("{\"errors\":{\"request\":\"");
    if what.is_empty() {
        out.text("not complete within ");
    } else {
        out.text(what);
        out.text(" over ");
    }
    out.number(limit);
    out.text(" ");
    out.text(unit);
    out.text("\"}}");
    refuse(&mut stream.writer, status, out.as_bytes()).await;
    Err(error)
}

/// Writes a whole JSON response of `status` with `body` (best effort: the
/// connection closes next whatever happens).
async fn refuse<W: Write>(writer: &mut Paced<W>, status: &str, body: &[u8]) {
    let mut head = [0u8; 112];
    let mut out = Out::new(&mut head);
    out.text("HTTP/1.1 ");
    out.text(status);
    out.text(" \r\nContent-Type: application/json\r\nContent-Length: ");
    out.number(body.len());
    out.text("\r\nConnection: close\r\n\r\n");
    let _ = writer.write_all(out.as_bytes()).await;
    let _ = writer.write_all(body).await;
    let _ = writer.flush().await;
}

#[cfg(test)]
mod testing;
#[cfg(test)]
mod tests;
