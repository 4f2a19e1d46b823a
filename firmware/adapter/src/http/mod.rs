//! The HTTP JSON API and the device's page, behind the `http` feature:
//! `GET /` (the page, [`page`]), `GET /api/status`, `GET` and `PUT
//! /api/settings`, `PUT /api/password`, `POST /api/reboot`,
//! `/api/factory-reset` and `/api/locate`, and with `update` `POST
//! /api/firmware` (docs/http-api.md has every request and response).
//!
//! The API is a front end: it reads the device and the server, and makes
//! every change through the settings service ([`Controller`]), which a
//! program (a board, hal-sim) builds over its own platform.
//!
//! - [`Http`] is the shared state of the API: the service, the port, and
//!   the lock that makes changes one at a time.
//! - [`serve`] answers one connection over any `embedded-io-async` reader
//!   and writer; [`listen`] accepts connections on an embassy-net stack
//!   and serves them, one task per connection ([`MAX_HTTP_CONNECTIONS`]).
//! - With `tls`, [`listen_secure`] serves HTTPS on [`HTTPS_PORT`] with the
//!   device's certificate, request after request on a connection
//!   ([`serve_kept`]); port 80 then serves in plain too, or, with
//!   `tls.plain_http` off, only redirects to HTTPS (308).
//!
//! HTTP/1.1 framing is this module's own ([`request`], [`response`]): a
//! head of at most [`MAX_HEAD_LEN`] bytes (431), a body of at most
//! [`MAX_BODY_LEN`] (413), the whole request within [`REQUEST_TIMEOUT`] of
//! the connection (408), the response within [`WRITE_TIMEOUT`]. In plain
//! HTTP, one request per connection (`Connection: close`): a client holds a
//! connection for a bounded time, so two slow ones cannot hold the API for
//! long (HTTPS keeps a connection while it is used and no other client
//! waits: [`serve_kept`]), and the
//! Modbus sessions never wait for it (no blocking lock is held across an
//! `.await`, and each request's work is bounded by its size).
//!
//! Nothing here panics on any input: the request is read by length into
//! one buffer and parsed by checked slicing ([`request`]), JSON by a checked reader
//! ([`json`]), and a change is parsed into a copy, validated whole, and
//! only then saved: a rejected change changes nothing.

mod api;
mod auth;
pub mod json;
mod listener;
pub mod page;
pub mod request;
mod response;
mod site;
#[cfg(feature = "tls")]
mod tls;

use core::fmt;

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embassy_time::{Duration, Instant};
use embedded_io_async::{ErrorKind, Read, Write};
use embedded_storage_async::nor_flash::NorFlash;

#[cfg(feature = "tls")]
pub use listener::{HTTPS_SOCKETS, MAX_HTTPS_SESSIONS, listen_secure};
pub use listener::{SOCKET_RX_LEN, SOCKET_TX_LEN, listen};
pub use request::Limit;
pub use response::Status;
pub use site::Scheme;

use self::api::Api;
use self::json::Out;
use crate::control::{Controller, Platform};
use crate::server::SLOT_COUNT;

/// The HTTP port (hal-sim: `--http-port`), which `modbus.port` may not take.
pub const HTTP_PORT: u16 = 80;

/// The HTTPS port (hal-sim: `--https-port`), with `tls`.
pub const HTTPS_PORT: u16 = 443;

/// Connections served at once: each board runs this many [`listen`] tasks.
pub const MAX_HTTP_CONNECTIONS: usize = 2;

/// Longest request head: the request line and the header fields, up to and
/// including the empty line (a browser's `PUT` with credentials is about
/// 700 bytes). Over it: 431 and the connection closes.
pub const MAX_HEAD_LEN: usize = 1024;

/// Longest request body (the whole settings document with two full
/// allow-lists is about 800 bytes). A `Content-Length` over it: 413 and
/// the connection closes, before any of the body is read.
pub const MAX_BODY_LEN: usize = if cfg!(feature = "tls") { 2048 } else { 1024 };

/// The request buffer: a head and a body at their limits.
pub const REQUEST_BUFFER_LEN: usize = MAX_HEAD_LEN + MAX_BODY_LEN;

/// Longest response body: the status document at its largest (every
/// session slot open, every number at its widest: about 900 bytes and 90 a
/// session with its peer's address) and a 400 listing every setting (about
/// 1250 bytes) fit, which a test checks.
pub const MAX_RESPONSE_LEN: usize = {
    let status = 960 + 100 * SLOT_COUNT;
    if status > 1344 { status } else { 1344 }
};

/// The whole request (head and body) must have arrived this long after the
/// connection was accepted: 408, and the connection closes.
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(5);

/// A kept-alive connection (HTTPS) closes when its next request has not
/// started this long after the last response (the page asks twice a second).
pub const KEEP_ALIVE_IDLE: Duration = Duration::from_secs(5);

/// The whole response must have been taken by the client this long after
/// its first byte was written; then the connection closes.
pub const WRITE_TIMEOUT: Duration = Duration::from_secs(5);

/// A request with wrong credentials is answered (401) after this long, so
/// a password is guessed at no more than one try per connection per second.
pub const AUTH_FAILURE_DELAY: Duration = Duration::from_secs(1);

/// The whole of an update file's body (`POST /api/firmware`) must have
/// arrived this long after its head: a few hundred KiB, at a slow client's pace.
#[cfg(feature = "update")]
pub const UPLOAD_TIMEOUT: Duration = Duration::from_secs(120);

/// How long `POST /api/locate` blinks the status LED.
pub const LOCATE_DURATION: Duration = Duration::from_secs(10);

/// The admin password's length in bytes (docs/http-api.md, `PUT /api/password`).
pub const MIN_PASSWORD_LEN: usize = 8;
pub const MAX_PASSWORD_LEN: usize = 64;

/// The one user name HTTP Basic authentication takes.
pub const USER: &str = "admin";

// The request's buffer holds the response's head once the request is done with.
const _: () = assert!(REQUEST_BUFFER_LEN >= response::RESPONSE_HEAD_LEN);

/// The `WWW-Authenticate` challenge of a 401.
const REALM_HEADER: &str = "Basic realm=\"mbio\"";

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
    /// The request was not HTTP/1.x, or the connection closed in its
    /// middle (answered 400).
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

/// The API's shared state: the settings service, the port the API listens
/// on, and the lock that makes changes one at a time (an async lock among
/// the HTTP tasks only: waiting for it never blocks the executor or a
/// Modbus session).
pub struct Http<'a, F: NorFlash, P: Platform> {
    control: &'a Controller<'a, F, P>,
    port: u16,
    changes: Mutex<CriticalSectionRawMutex, ()>,
    /// HTTPS's port, once its listeners serve (port 80 may then redirect).
    #[cfg(feature = "tls")]
    secure_port: Option<u16>,
    /// The HTTPS session, one at a time, and the connections waiting for it.
    #[cfg(feature = "tls")]
    session: Mutex<CriticalSectionRawMutex, ()>,
    #[cfg(feature = "tls")]
    waiting: core::sync::atomic::AtomicUsize,
    /// Raised when a connection starts waiting for the session.
    #[cfg(feature = "tls")]
    arrival: embassy_sync::signal::Signal<CriticalSectionRawMutex, ()>,
}

impl<F: NorFlash, P: Platform> fmt::Debug for Http<'_, F, P> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Http").field("port", &self.port).finish_non_exhaustive()
    }
}

impl<'a, F: NorFlash, P: Platform> Http<'a, F, P> {
    /// The API over `control`, listening on `port` ([`HTTP_PORT`] on the boards).
    pub const fn new(control: &'a Controller<'a, F, P>, port: u16) -> Self {
        Self {
            control,
            port,
            changes: Mutex::new(()),
            #[cfg(feature = "tls")]
            secure_port: None,
            #[cfg(feature = "tls")]
            session: Mutex::new(()),
            #[cfg(feature = "tls")]
            waiting: core::sync::atomic::AtomicUsize::new(0),
            #[cfg(feature = "tls")]
            arrival: embassy_sync::signal::Signal::new(),
        }
    }

    /// The API with HTTPS on `port` too ([`listen_secure`]'s).
    #[cfg(feature = "tls")]
    pub const fn with_secure_port(mut self, port: Option<u16>) -> Self {
        self.secure_port = port;
        self
    }

    /// HTTPS's port, when HTTPS serves.
    #[cfg(feature = "tls")]
    pub fn secure_port(&self) -> Option<u16> {
        self.secure_port
    }

    /// HTTPS's port when port 80 only redirects to it: HTTPS serves, and
    /// `tls.plain_http` is off.
    fn redirect_port(&self) -> Option<u16> {
        #[cfg(feature = "tls")]
        return self.secure_port.filter(|_| !self.control.settings().tls.plain_http);
        #[cfg(not(feature = "tls"))]
        None
    }

    /// Whether a kept-alive connection should end after its response:
    /// another client waits for the HTTPS session, or a Modbus/TCP
    /// Security client for its seat in the TLS arena.
    fn yielding(&self) -> bool {
        #[cfg(feature = "tls")]
        return self.waiting.load(core::sync::atomic::Ordering::Relaxed) > 0 || crate::server::secure::modbus_waiting();
        #[cfg(not(feature = "tls"))]
        false
    }

    /// Returns once another client waits for the HTTPS session or its seat
    /// (never without `tls`): a kept-alive connection idle between
    /// requests then closes at once.
    async fn someone_waits(&self) {
        #[cfg(feature = "tls")]
        {
            let https = async {
                while !self.yielding() {
                    self.arrival.wait().await;
                }
            };
            embassy_futures::select::select(https, crate::server::secure::modbus_wants_a_seat()).await;
        }
        #[cfg(not(feature = "tls"))]
        core::future::pending::<()>().await;
    }

    /// The settings service the API makes its changes through.
    pub fn control(&self) -> &'a Controller<'a, F, P> {
        self.control
    }

    /// The port the API listens on.
    pub fn port(&self) -> u16 {
        self.port
    }

    /// Does what an accepted request left to do ([`serve`] returns it).
    pub async fn perform(&self, action: Action) {
        match action {
            Action::Reboot => self.control.reboot(),
            Action::FactoryReset => self.control.factory_reset().await,
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

/// Serves one plain HTTP connection from `peer` (its IPv4 address;
/// `None`: never allowed to change anything): reads one request from
/// `reader`, writes its response to `writer`. The caller closes the
/// connection afterwards, then does the [`Action`] returned, if any
/// ([`Http::perform`]): a reboot only once its response has gone out.
///
/// A request that breaks a limit, its deadline or HTTP's grammar is
/// answered here (431, 413, 408, 400) and returns the [`Error`]; so does a
/// transport error (with no answer).
pub async fn serve<F: NorFlash, P: Platform, R: Read, W: Write>(
    http: &Http<'_, F, P>,
    peer: Option<[u8; 4]>,
    reader: R,
    writer: W,
    buffers: &mut Buffers,
) -> Result<Option<Action>, Error> {
    let mut io = Duplex { reader, writer };
    exchange(http, peer, Scheme::Http, &mut io, buffers, None).await.map(|done| done.action)
}

/// Serves one connection over `io` as [`serve`] does, but request after
/// request (HTTP keep-alive), as HTTPS does: a handshake per request would
/// cost the device far more than the request. The connection ends (and
/// this returns) when the client closes it or asks to, sends nothing for
/// [`KEEP_ALIVE_IDLE`], breaks a limit, asks for an [`Action`], or when
/// another client waits for the session ([`Http::yielding`]).
pub async fn serve_kept<F: NorFlash, P: Platform, S: Read + Write>(
    http: &Http<'_, F, P>,
    peer: Option<[u8; 4]>,
    scheme: Scheme,
    io: &mut S,
    buffers: &mut Buffers,
) -> Result<Option<Action>, Error> {
    let mut idle = None;
    loop {
        let done = exchange(http, peer, scheme, io, buffers, idle).await?;
        if !done.kept {
            return Ok(done.action);
        }
        idle = Some(Instant::now() + KEEP_ALIVE_IDLE);
    }
}

/// How one request and its response went.
struct Exchange {
    /// What the request left to do.
    action: Option<Action>,
    /// Whether the connection stays open for another request.
    kept: bool,
}

/// One request and its response. `idle`: `None` for a connection's first
/// request (one request per connection); for a kept-alive connection's
/// next, by when it must start.
async fn exchange<F: NorFlash, P: Platform, S: Read + Write>(
    http: &Http<'_, F, P>,
    peer: Option<[u8; 4]>,
    scheme: Scheme,
    io: &mut S,
    buffers: &mut Buffers,
    idle: Option<Instant>,
) -> Result<Exchange, Error> {
    let Buffers { request: buffer, response: body } = buffers;
    let mut out = Out::new(body);
    let deadline = idle.unwrap_or_else(Instant::now) + REQUEST_TIMEOUT;
    let head = request::read_head(io, buffer, idle, deadline);
    let head = match idle {
        // Between requests, a client waiting for the session ends the wait.
        Some(_) => match embassy_futures::select::select(head, http.someone_waits()).await {
            embassy_futures::select::Either::First(head) => head,
            embassy_futures::select::Either::Second(()) => Ok(None),
        },
        None => head.await,
    };
    let answered = match head {
        Ok(None) => return Ok(Exchange { action: None, kept: false }),
        Ok(Some(incoming)) => Api { http, peer, scheme }.take(incoming, io, deadline, &mut out).await,
        Err(error) => Err(error),
    };
    let (reply, result, reusable) = match answered {
        Ok(taken) => (taken.reply, Ok(taken.action), taken.reusable),
        Err(error @ Error::Io(_)) => return Err(error),
        Err(error) => (refusal(&mut out, error), Err(error), false),
    };
    let kept = scheme == Scheme::Https && reusable && matches!(result, Ok(None)) && !http.yielding();
    let mut response = reply.response(&mut out);
    response.keep_alive = kept;
    // The request is done with: its buffer holds the response's head.
    response::write(io, &response, buffer).await?;
    result.map(|action| Exchange { action, kept })
}

/// A reader and a writer as one stream (a plain connection's two halves).
struct Duplex<R, W> {
    reader: R,
    writer: W,
}

impl<R, W> embedded_io_async::ErrorType for Duplex<R, W> {
    type Error = ErrorKind;
}

impl<R: Read, W> Read for Duplex<R, W> {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, ErrorKind> {
        self.reader.read(buf).await.map_err(|e| embedded_io_async::Error::kind(&e))
    }
}

impl<R, W: Write> Write for Duplex<R, W> {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, ErrorKind> {
        self.writer.write(buf).await.map_err(|e| embedded_io_async::Error::kind(&e))
    }

    async fn flush(&mut self) -> Result<(), ErrorKind> {
        self.writer.flush().await.map_err(|e| embedded_io_async::Error::kind(&e))
    }
}

/// The answer to a request that broke a limit, its deadline or HTTP's grammar.
fn refusal(out: &mut Out<'_>, error: Error) -> api::Reply {
    let (status, what, limit, unit) = match error {
        Error::Limit(Limit::HeadTooLarge) => {
            (Status::HEADER_FIELDS_TOO_LARGE, "head over ", MAX_HEAD_LEN as u64, " bytes")
        }
        Error::Limit(Limit::BodyTooLarge) => (Status::CONTENT_TOO_LARGE, "body over ", MAX_BODY_LEN as u64, " bytes"),
        Error::Timeout => (Status::REQUEST_TIMEOUT, "not complete within ", REQUEST_TIMEOUT.as_secs(), " s"),
        Error::BadRequest | Error::Io(_) => (Status::BAD_REQUEST, "", 0, ""),
    };
    out.clear();
    out.text("{\"errors\":{\"request\":\"");
    if what.is_empty() {
        out.text("not an HTTP/1.1 request");
    } else {
        out.text(what);
        out.number(limit);
        out.text(unit);
    }
    out.text("\"}}");
    api::Reply::new(status)
}

/// Why an update file was not taken (`POST /api/firmware`), as the API
/// answers it; the running image stays.
#[cfg(feature = "update")]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FirmwareRefusal {
    /// The file is not one this device takes: not an update file, another
    /// board's, a bad signature, cut off (400, with the message).
    Invalid(&'static str),
    /// The update partition failed (500).
    Storage,
    /// This program takes no updates (501).
    Unsupported,
}

/// An upload's body, chunk by chunk, as the updater takes it.
#[cfg(feature = "update")]
impl<R: Read> crate::update::boot::Source for request::Stream<'_, R> {
    type Error = Error;

    async fn chunk(&mut self) -> Result<Option<&[u8]>, Error> {
        request::Stream::chunk(self).await
    }
}

/// What the API answers for an update the core refused.
#[cfg(feature = "update")]
fn update_refusal(error: crate::update::Error) -> FirmwareRefusal {
    use crate::update::Error as E;
    match error {
        E::Format(_) => FirmwareRefusal::Invalid("not a valid update file"),
        E::WrongBoard(_) => FirmwareRefusal::Invalid("the image is for another board"),
        E::TooLarge { .. } => FirmwareRefusal::Invalid("the image is too large for this device"),
        E::TooLong => FirmwareRefusal::Invalid("more bytes than the image's header says"),
        E::CutOff { .. } => FirmwareRefusal::Invalid("the upload was cut off"),
        // Under a bootloader that serves no signature check: no update can be taken.
        E::Signature(crate::update::SignatureError::Unavailable) => FirmwareRefusal::Unsupported,
        E::Signature(_) => FirmwareRefusal::Invalid("the image's signature is not valid"),
        E::Armed => FirmwareRefusal::Invalid("an update is armed already and installs at the next reboot"),
        E::OnTrial => FirmwareRefusal::Invalid("the running firmware is on trial and not yet confirmed"),
        E::NotStarted | E::Flash(_) | E::Config => FirmwareRefusal::Storage,
    }
}

#[cfg(test)]
mod testing;
#[cfg(test)]
mod tests;
