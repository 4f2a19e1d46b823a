//! The endpoints (docs/http-api.md): routing, who may change things, and
//! the JSON documents each one reads and writes, each change a call of the
//! settings service ([`crate::control::Controller`]).

use embassy_time::{Instant, Timer};
use embedded_storage_async::nor_flash::NorFlash;

use super::auth::{self, Credentials, MAX_CREDENTIALS_LEN};
use super::json::{Malformed, Out, Reader, Str, Value};
use super::page;
use super::request::{Incoming, Request};
use super::response::{Response, Status};
use super::site::{self, Scheme};
use super::{AUTH_FAILURE_DELAY, Action, Http, LOCATE_DURATION, MAX_PASSWORD_LEN, MIN_PASSWORD_LEN, REALM_HEADER};
use crate::control::{Controller, Platform, Refusal, RobotSource};
use crate::io::AnalogType;
use crate::map::Image;
use crate::map::table::reg;
use crate::settings::{Field, Kind, Settings};
use crate::text;

const JSON: &str = "application/json";

/// The longest text any setting takes: an allow-list of 8 networks of 18
/// characters and 7 commas is 151.
const MAX_VALUE_LEN: usize = 160;

/// Unknown keys listed in one 400 (more are refused all the same).
const MAX_UNKNOWN_LISTED: usize = 8;

/// The group of the admin password, which `PUT /api/settings` does not set.
const ADMIN: &str = "admin";

/// Why a change is refused while no admin password is set.
const NO_PASSWORD_YET: &str =
    "no admin password is set: set one first (PUT /api/password); until then no other change is taken";
/// Why the first password is refused after the window.
const FIRST_PASSWORD_CLOSED: &str = "the first password may be set only within 10 minutes of power-up or of a \
     short press of the device's button: press it (or restart the device), then set it";

/// What a request asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Endpoint {
    Page,
    Status,
    Telemetry,
    GetSettings,
    PutSettings,
    PutPassword,
    Reboot,
    FactoryReset,
    Locate,
    /// `POST /api/firmware` (feature `update`).
    #[cfg(feature = "update")]
    Firmware,
    /// `GET /api/tls` (feature `tls`).
    #[cfg(feature = "tls")]
    Tls,
    /// `PUT` and `DELETE /api/tls/client-ca` (feature `tls`).
    #[cfg(feature = "tls")]
    PutClientCa,
    #[cfg(feature = "tls")]
    DeleteClientCa,
    /// `PUT` and `DELETE /api/tls/certificate` (feature `tls`).
    #[cfg(feature = "tls")]
    PutCertificate,
    #[cfg(feature = "tls")]
    DeleteCertificate,
}

/// Why a request has no endpoint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Miss {
    NotFound,
    /// The path exists; these methods are allowed on it.
    MethodNotAllowed(&'static str),
}

/// The endpoint for `method` on `path` (the path without its query).
pub(super) fn route(method: &str, path: &str) -> Result<Endpoint, Miss> {
    let (allowed, endpoint) = match (path, method) {
        ("/", "GET") => ("", Some(Endpoint::Page)),
        ("/", _) => ("GET", None),
        ("/api/status", "GET") => ("", Some(Endpoint::Status)),
        ("/api/status", _) => ("GET", None),
        ("/api/telemetry", "GET") => ("", Some(Endpoint::Telemetry)),
        ("/api/telemetry", _) => ("GET", None),
        ("/api/settings", "GET") => ("", Some(Endpoint::GetSettings)),
        ("/api/settings", "PUT") => ("", Some(Endpoint::PutSettings)),
        ("/api/settings", _) => ("GET, PUT", None),
        ("/api/password", "PUT") => ("", Some(Endpoint::PutPassword)),
        ("/api/password", _) => ("PUT", None),
        ("/api/reboot", "POST") => ("", Some(Endpoint::Reboot)),
        ("/api/factory-reset", "POST") => ("", Some(Endpoint::FactoryReset)),
        ("/api/locate", "POST") => ("", Some(Endpoint::Locate)),
        ("/api/reboot" | "/api/factory-reset" | "/api/locate", _) => ("POST", None),
        #[cfg(feature = "update")]
        ("/api/firmware", "POST") => ("", Some(Endpoint::Firmware)),
        #[cfg(feature = "update")]
        ("/api/firmware", _) => ("POST", None),
        // /api/events comes later (and /api/firmware without updates): 404.
        #[cfg(feature = "tls")]
        ("/api/tls", "GET") => ("", Some(Endpoint::Tls)),
        #[cfg(feature = "tls")]
        ("/api/tls", _) => ("GET", None),
        #[cfg(feature = "tls")]
        ("/api/tls/client-ca", "PUT") => ("", Some(Endpoint::PutClientCa)),
        #[cfg(feature = "tls")]
        ("/api/tls/client-ca", "DELETE") => ("", Some(Endpoint::DeleteClientCa)),
        #[cfg(feature = "tls")]
        ("/api/tls/client-ca", _) => ("PUT, DELETE", None),
        #[cfg(feature = "tls")]
        ("/api/tls/certificate", "PUT") => ("", Some(Endpoint::PutCertificate)),
        #[cfg(feature = "tls")]
        ("/api/tls/certificate", "DELETE") => ("", Some(Endpoint::DeleteCertificate)),
        #[cfg(feature = "tls")]
        ("/api/tls/certificate", _) => ("PUT, DELETE", None),
        _ => return Err(Miss::NotFound),
    };
    endpoint.ok_or(Miss::MethodNotAllowed(allowed))
}

/// A response's status, the one header it may add, and whether its body
/// is the page (from flash) rather than the JSON written into the response
/// buffer. (A flag, not the body itself: a reply lives across `.await`s,
/// in every connection's future, where each byte more is static RAM.)
#[derive(Clone, Copy, Debug)]
pub(super) struct Reply {
    status: Status,
    header: Option<(&'static str, &'static str)>,
    page: bool,
    /// The response buffer holds a `Location` (a redirect), not a body.
    location: bool,
}

impl Reply {
    pub(super) const fn new(status: Status) -> Self {
        Self { status, header: None, page: false, location: false }
    }

    /// The response: the page, or the JSON in `out` (a 500 if it did not fit).
    pub(super) fn response<'o>(mut self, out: &'o mut Out<'_>) -> Response<'o> {
        if out.overflowed() {
            self = refusal(out, Status::INTERNAL_SERVER_ERROR, "response", "too large");
            if out.overflowed() {
                out.clear();
            }
        }
        let (content_type, body) = if self.page { (page::CONTENT_TYPE, page::PAGE) } else { (JSON, out.as_bytes()) };
        let (location, body) = if self.location { (Some(body), &[][..]) } else { (None, body) };
        Response { status: self.status, content_type, header: self.header, location, body, keep_alive: false }
    }
}

/// `{"errors": {key: message}}` with one request-level key.
pub(super) fn refusal(out: &mut Out<'_>, status: Status, key: &str, message: &str) -> Reply {
    out.clear();
    out.text("{\"errors\":{");
    out.string(key);
    out.text(":");
    out.string(message);
    out.text("}}");
    Reply::new(status)
}

/// One request's view of the API: who is asking, and how.
pub(super) struct Api<'h, 'b, F: NorFlash, P: Platform> {
    pub(super) http: &'h Http<'b, F, P>,
    /// The client's IPv4 address (`None`: not IPv4, never allowed to change things).
    pub(super) peer: Option<[u8; 4]>,
    pub(super) scheme: Scheme,
}

/// A request taken: its reply, what is left to do once the reply has gone
/// out, and whether the connection may carry another request (the request
/// was read exactly, and the client did not ask to close).
pub(super) struct Taken {
    pub(super) reply: Reply,
    pub(super) action: Option<Action>,
    pub(super) reusable: bool,
}

impl<'b, F: NorFlash, P: Platform> Api<'_, 'b, F, P> {
    fn control(&self) -> &'b Controller<'b, F, P> {
        self.http.control
    }

    /// Takes the rest of `incoming` from `reader` by `deadline` and answers
    /// it into `out`: the reply, and what is left to do once it has gone
    /// out. An update file is streamed; any other body is read whole first.
    pub(super) async fn take<R: embedded_io_async::Read>(
        &self,
        incoming: Incoming<'_>,
        reader: &mut R,
        deadline: Instant,
        out: &mut Out<'_>,
    ) -> Result<Taken, super::Error> {
        let reusable = incoming.is_exact() && !incoming.request.close && !incoming.request.http10;
        // Before anything else: the request names this device, and does
        // not come from a page of another site.
        let name = crate::net::DeviceName::device_name(self.control());
        // Only plain HTTP may redirect: HTTPS never reads the setting.
        let redirect_to = if self.scheme == Scheme::Http { self.http.redirect_port() } else { None };
        let checked = site::check_host(&incoming.request, &name).and_then(|()| match redirect_to {
            Some(port) => Err(redirect(&incoming.request, port, out)),
            None => site::check_origin(&incoming.request, self.scheme),
        });
        if let Err((status, message)) = checked {
            let reply = if status == Status::PERMANENT_REDIRECT {
                Reply { location: true, ..Reply::new(status) }
            } else {
                refusal(out, status, "request", message)
            };
            return Ok(Taken { reply, action: None, reusable: false });
        }
        let routed = route(incoming.request.method, incoming.request.path);
        #[cfg(feature = "update")]
        if routed == Ok(Endpoint::Firmware) {
            let (reply, action) = self.upload(incoming, reader, out).await?;
            return Ok(Taken { reply, action, reusable: false });
        }
        let request = incoming.body(reader, deadline).await?;
        let mut action = None;
        let reply = self.answer(routed, &request, out, &mut action).await;
        Ok(Taken { reply, action, reusable })
    }

    /// `POST /api/firmware`: the body streamed to the updater, which checks
    /// it whole before it arms anything; then a reboot into it.
    #[cfg(feature = "update")]
    async fn upload<R: embedded_io_async::Read>(
        &self,
        mut incoming: Incoming<'_>,
        reader: &mut R,
        out: &mut Out<'_>,
    ) -> Result<(Reply, Option<Action>), super::Error> {
        use crate::update::boot::Refused;
        let capacity = self.control().platform().firmware_capacity();
        if capacity == 0 {
            return Ok((no_updates(out), None));
        }
        if !site::has_content_type(&incoming.request, b"application/octet-stream") {
            let message = "an update file must be sent as Content-Type: application/octet-stream";
            return Ok((refusal(out, Status::UNSUPPORTED_MEDIA_TYPE, "request", message), None));
        }
        if incoming.content_length > capacity as u64 {
            out.text("{\"errors\":{\"firmware\":\"over ");
            out.number(capacity);
            out.text(" bytes\"}}");
            return Ok((Reply::new(Status::CONTENT_TOO_LARGE), None));
        }
        if let Err(reply) = self.authorize(&incoming.request, out, false).await {
            return Ok((reply, None));
        }
        let _change = self.http.changes.lock().await;
        let mut body = incoming.stream(reader, Instant::now() + super::UPLOAD_TIMEOUT);
        let reply = match self.control().receive_firmware(&mut body).await {
            Ok(version) => {
                out.text("{\"firmware\":{\"version\":");
                out.string_with(|w| text::write_version(w, version));
                out.text(",\"rebooting\":true}}");
                return Ok((Reply::new(Status::ACCEPTED), Some(Action::Reboot)));
            }
            Err(Refused::Source(error)) => {
                warn!("update: refused: the upload broke off: {:?}", error);
                return Err(error);
            }
            Err(Refused::Update(error)) => {
                let refused = super::update_refusal(error);
                warn!("update: refused: {:?}", refused);
                match refused {
                    super::FirmwareRefusal::Invalid(message) => refusal(out, Status::BAD_REQUEST, "firmware", message),
                    super::FirmwareRefusal::Storage => refusal(
                        out,
                        Status::INTERNAL_SERVER_ERROR,
                        "firmware",
                        "the update partition failed; nothing changed",
                    ),
                    super::FirmwareRefusal::Unsupported => no_updates(out),
                }
            }
            Err(Refused::Unsupported) => {
                warn!("update: refused: {:?}", super::FirmwareRefusal::Unsupported);
                no_updates(out)
            }
        };
        Ok((reply, None))
    }

    /// Answers `request`, routed to `routed`, into `out`; `action` is what
    /// is left to do once the reply has gone out.
    async fn answer(
        &self,
        routed: Result<Endpoint, Miss>,
        request: &Request<'_>,
        out: &mut Out<'_>,
        action: &mut Option<Action>,
    ) -> Reply {
        let endpoint = match routed {
            Ok(endpoint) => endpoint,
            Err(Miss::NotFound) => return refusal(out, Status::NOT_FOUND, "request", "no such resource"),
            Err(Miss::MethodNotAllowed(allowed)) => {
                let reply = refusal(out, Status::METHOD_NOT_ALLOWED, "request", "method not allowed here");
                return Reply { header: Some(("Allow", allowed)), ..reply };
            }
        };
        match endpoint {
            Endpoint::Page => {
                if !page::accepts_gzip(request.accept_encoding) {
                    return refusal(out, Status::NOT_ACCEPTABLE, "request", page::NOT_ACCEPTABLE);
                }
                let reply = Reply::new(Status::OK);
                return Reply { header: Some(("Content-Encoding", page::ENCODING)), page: true, ..reply };
            }
            Endpoint::Status => {
                self.status(out);
                return Reply::new(Status::OK);
            }
            Endpoint::Telemetry => {
                let values = self.control().server().service().read(telemetry);
                telemetry_document(out, &values);
                return Reply::new(Status::OK);
            }
            Endpoint::GetSettings => {
                settings_document(out, &self.control().settings(), self.control().password_set(), None);
                return Reply::new(Status::OK);
            }
            #[cfg(feature = "tls")]
            Endpoint::Tls => return super::tls::document(self.control(), out).await,
            _ => {}
        }
        // A change (bodyless POSTs too) says it is JSON: a page of another
        // site cannot, without a preflight the device never grants.
        if !site::has_content_type(request, b"application/json") {
            let message = "a change must be sent as Content-Type: application/json";
            return refusal(out, Status::UNSUPPORTED_MEDIA_TYPE, "request", message);
        }
        if let Err(reply) = self.authorize(request, out, endpoint == Endpoint::PutPassword).await {
            return reply;
        }
        match endpoint {
            Endpoint::PutSettings => self.put_settings(request.body, out).await,
            Endpoint::PutPassword => self.put_password(request.body, out).await,
            Endpoint::Reboot => {
                *action = Some(Action::Reboot);
                out.text("{\"rebooting\":true}");
                Reply::new(Status::ACCEPTED)
            }
            Endpoint::FactoryReset => {
                *action = Some(Action::FactoryReset);
                out.text("{\"factory_reset\":true,\"rebooting\":true}");
                Reply::new(Status::ACCEPTED)
            }
            Endpoint::Locate => {
                self.control().locate(LOCATE_DURATION);
                out.text("{\"locating_s\":");
                out.number(LOCATE_DURATION.as_secs());
                out.text("}");
                Reply::new(Status::OK)
            }
            #[cfg(feature = "tls")]
            Endpoint::PutClientCa => {
                let _change = self.http.changes.lock().await;
                match super::tls::put_client_ca(self.control(), request.body, out).await {
                    Ok(reply) => reply,
                    Err(malformed) => malformed_refusal(out, malformed),
                }
            }
            #[cfg(feature = "tls")]
            Endpoint::DeleteClientCa => {
                let _change = self.http.changes.lock().await;
                super::tls::delete_client_ca(self.control(), out).await
            }
            #[cfg(feature = "tls")]
            Endpoint::PutCertificate => {
                let _change = self.http.changes.lock().await;
                match super::tls::put_certificate(self.control(), request.body, out).await {
                    Ok(reply) => reply,
                    Err(malformed) => malformed_refusal(out, malformed),
                }
            }
            #[cfg(feature = "tls")]
            Endpoint::DeleteCertificate => {
                let _change = self.http.changes.lock().await;
                super::tls::delete_certificate(self.control(), out).await
            }
            // Answered above.
            Endpoint::Page | Endpoint::Status | Endpoint::Telemetry | Endpoint::GetSettings => {
                Reply::new(Status::INTERNAL_SERVER_ERROR)
            }
            #[cfg(feature = "tls")]
            Endpoint::Tls => Reply::new(Status::INTERNAL_SERVER_ERROR),
            // Streamed before `respond` (`take`).
            #[cfg(feature = "update")]
            Endpoint::Firmware => Reply::new(Status::INTERNAL_SERVER_ERROR),
        }
    }

    /// Every change comes from an address `modbus.allow_write` admits (403),
    /// with the admin password once one is set (401); until one is set, the
    /// only change taken is setting it (`first_password`; 403 for any
    /// other), within the settings service's window for it.
    async fn authorize(&self, request: &Request<'_>, out: &mut Out<'_>, first_password: bool) -> Result<(), Reply> {
        let control = self.control();
        let may_write = self.peer.is_some_and(|peer| control.server().with_config(|c| c.access.may_write(peer)));
        if !may_write {
            let message = "this address may not change the device (modbus.allow_write)";
            return Err(refusal(out, Status::FORBIDDEN, "request", message));
        }
        if !control.password_set() {
            if first_password {
                return Ok(());
            }
            return Err(refusal(out, Status::FORBIDDEN, "request", NO_PASSWORD_YET));
        }
        let mut buf = [0u8; MAX_CREDENTIALS_LEN];
        let header = request.authorization;
        let verdict = match auth::credentials(header, &mut buf) {
            Credentials::Admin(password) => control.verify_password(password).await,
            Credentials::Missing => false,
            Credentials::Invalid => false,
        };
        if verdict {
            return Ok(());
        }
        if header.is_some() {
            // Wrong credentials: slow down guessing (at most one try per
            // connection per delay, and few connections).
            Timer::after(AUTH_FAILURE_DELAY).await;
        }
        let message = "the admin password is required (HTTP Basic, user admin)";
        let reply = refusal(out, Status::UNAUTHORIZED, "request", message);
        Err(Reply { header: Some(("WWW-Authenticate", REALM_HEADER)), ..reply })
    }

    /// `PUT /api/settings`: any subset, grouped; all or nothing.
    async fn put_settings(&self, body: &[u8], out: &mut Out<'_>) -> Reply {
        let _change = self.http.changes.lock().await;
        let control = self.control();
        let old = control.settings();
        let mut new = old;
        let mut report = Report::new(out);
        if let Err(malformed) = patch(body, &mut new, &mut report) {
            return malformed_refusal(out, malformed);
        }
        if report.is_empty()
            && let Err(errors) = new.validate()
        {
            for &(field, rule) in errors.iter() {
                report.add(Key::Field(field), rule);
            }
        }
        if report.is_empty() && new.modbus.port == self.http.port {
            // The settings alone cannot know it: the program's rule.
            report.add(Key::Field(Field::ModbusPort), "must not be the HTTP port");
        }
        if !report.is_empty() {
            report.finish();
            return Reply::new(Status::BAD_REQUEST);
        }
        let reboot_required = if new == old {
            false
        } else {
            match control.apply(&new).await {
                Ok(reboot_required) => reboot_required,
                Err(refused) => return refused_change(out, refused, "the settings were not saved; nothing changed"),
            }
        };
        settings_document(out, &control.settings(), control.password_set(), Some(reboot_required));
        Reply::new(Status::OK)
    }

    /// `PUT /api/password`: `{"password": "..."}`, 8-64 bytes, no control character.
    async fn put_password(&self, body: &[u8], out: &mut Out<'_>) -> Reply {
        let _change = self.http.changes.lock().await;
        let mut password = [0u8; MAX_PASSWORD_LEN];
        let mut report = Report::new(out);
        let len = match read_password(body, &mut password, &mut report) {
            Ok(len) => len,
            Err(malformed) => return malformed_refusal(out, malformed),
        };
        let rule = "8-64 bytes";
        match len {
            _ if !report.is_empty() => {}
            None => report.add(Key::Name("password"), "required"),
            Some(len) if !(MIN_PASSWORD_LEN..=MAX_PASSWORD_LEN).contains(&len) => {
                report.add(Key::Name("password"), rule)
            }
            Some(len) if crate::storage::check_password(password.get(..len).unwrap_or_default()).is_err() => {
                report.add(Key::Name("password"), "no control characters (NUL, tab, newline, DEL)")
            }
            Some(_) => {}
        }
        if !report.is_empty() {
            report.finish();
            return Reply::new(Status::BAD_REQUEST);
        }
        let password = password.get(..len.unwrap_or(0)).unwrap_or_default();
        match self.control().set_password(password).await {
            Ok(()) => {}
            Err(Refusal::FirstPasswordClosed) => {
                return refusal(out, Status::FORBIDDEN, "password", FIRST_PASSWORD_CLOSED);
            }
            Err(refused) => return refused_change(out, refused, "the password was not saved; nothing changed"),
        }
        out.text("{\"admin\":{\"password_set\":true}}");
        Reply::new(Status::OK)
    }

    /// `GET /api/status`.
    fn status(&self, out: &mut Out<'_>) {
        let control = self.control();
        let platform = control.platform();
        let server = control.server();
        let device = server.service();
        let now = Instant::now();
        let settings = control.settings();
        let mac = platform.mac();
        let io = device.read(Io::of);
        let sessions = server.slots().sessions();
        let counters = server.stats().snapshot();
        let watchdog = device.watchdog();
        let tripped = device.watchdog_tripped();
        let network = platform.network();

        out.text("{\"device\":{\"name\":");
        out.string(settings.device.name.or_default(mac).as_str());
        out.text(",\"model\":");
        out.string(platform.model());
        out.text(",\"firmware\":");
        out.string_with(|w| text::write_version(w, crate::VERSION));
        out.text(",\"uptime_s\":");
        out.number(now.as_secs());
        out.text(",\"cpu_load_percent\":");
        // What the program's executor loop reported (none in the tests).
        optional(out, crate::cpu_load::CPU_LOAD.percent(), |out, load| out.number(load));
        out.text(",\"mac\":");
        out.string_with(|w| text::write_mac(w, mac));
        out.text(",\"reset_reason\":");
        optional(out, platform.reset_reason(), |out, reason| out.string(reason));

        out.text("},\"network\":{\"mode\":");
        out.string(network.mode.as_str());
        out.text(",\"address\":");
        optional(out, network.address, |out, address| out.string_with(|w| address.write_to(w)));
        out.text(",\"gateway\":");
        optional(out, network.gateway, |out, gateway| out.string_with(|w| gateway.write_to(w)));
        out.text(",\"link\":");
        out.boolean(network.link);

        io.write(out, control.robot_source());
        out.text(",\"link\":");
        #[cfg(feature = "robot-link")]
        optional(out, control.robot_link(), |out, link| {
            // `connected`: the link is up (connected, and polls succeeding).
            out.text("{\"connected\":");
            out.boolean(link.up);
            out.text(",\"polls\":");
            out.number(link.polls);
            out.text(",\"errors\":");
            out.number(link.errors);
            out.text(",\"last_ok_ms\":");
            let last_ok_ms = link.last_ok.map(|at| u32::try_from(at.elapsed().as_millis()).unwrap_or(u32::MAX));
            optional(out, last_ok_ms, |out, ms| out.number(ms));
            out.text("}");
        });
        #[cfg(not(feature = "robot-link"))]
        out.text("null");

        out.text("},\"connections\":[");
        for (i, session) in sessions.iter().flatten().enumerate() {
            out.text(if i == 0 { "{" } else { ",{" });
            out.text("\"peer\":\"");
            for (i, octet) in session.peer.into_iter().enumerate() {
                if i > 0 {
                    out.text(".");
                }
                out.number(octet);
            }
            // Requests per session are not counted yet: null until they are.
            out.text("\",\"requests\":null,\"idle_ms\":");
            let idle = now.checked_duration_since(session.last).map_or(0, |idle| idle.as_millis());
            out.number(idle);
            out.text(",\"read_only\":");
            out.boolean(session.rights == crate::access::Rights::Read);
            out.text("}");
        }
        out.text("],\"counters\":{");
        let mut first = true;
        counters.for_each(|name, value| {
            out.text(if first { "\"" } else { ",\"" });
            first = false;
            out.text(name);
            out.text("\":");
            out.number(value);
        });
        out.text("},\"watchdog\":{\"timeout_ms\":");
        out.number(watchdog.timeout.map_or(0, |timeout| timeout.as_millis()));
        out.text(",\"tripped\":");
        out.boolean(tripped);
        let storage = control.storage();
        out.text("},\"storage\":{\"ok\":");
        out.boolean(storage.ok);
        out.text(",\"records\":");
        out.number(storage.records);
        out.text(",\"erases\":");
        out.number(storage.erases);
        out.text("}");
        #[cfg(feature = "update")]
        {
            out.text(",\"update\":");
            optional(out, device.firmware_update(), |out, update| {
                out.text("{\"state\":");
                out.string(update.state.as_str());
                out.text(",\"previous\":");
                optional(out, update.previous, |out, previous| out.string_with(|w| text::write_version(w, previous)));
                out.text(",\"capacity\":");
                out.number(update.capacity);
                out.text("}");
            });
        }
        out.text(",\"admin\":{\"password_set\":");
        out.boolean(control.password_set());
        out.text(",\"first_password_open\":");
        out.boolean(control.first_password_open());
        out.text("}}");
    }
}

/// 501 for an update on a device that takes none.
#[cfg(feature = "update")]
fn no_updates(out: &mut Out<'_>) -> Reply {
    refusal(out, Status::NOT_IMPLEMENTED, "firmware", "this device takes no updates")
}

/// `null`, or the value as `write` writes it.
fn optional<T>(out: &mut Out<'_>, value: Option<T>, write: impl FnOnce(&mut Out<'_>, T)) {
    match value {
        Some(value) => write(out, value),
        None => out.text("null"),
    }
}

/// The I/O and robot points of the status document, read under one lock.
#[derive(Clone, Copy, Debug)]
struct Io {
    di: u16,
    do_: u16,
    tool_di: u16,
    tool_do: u16,
    ai: [u16; 2],
    ao: [u16; 2],
    ai_types: [AnalogType; 2],
    ao_types: [AnalogType; 2],
    /// Registers 259-264.
    robot: [u16; 6],
}

impl Io {
    fn of(image: &Image) -> Self {
        let outputs = image.outputs();
        Self {
            di: image.register(reg::DIGITAL_INPUTS),
            do_: outputs.digital,
            tool_di: image.register(reg::TOOL_INPUTS),
            tool_do: u16::from(outputs.tool),
            ai: [image.analog_input(0), image.analog_input(1)],
            ao: outputs.analog.map(|output| output.value),
            ai_types: outputs.analog_input_types,
            ao_types: outputs.analog.map(|output| output.kind),
            robot: [0, 1, 2, 3, 4, 5].map(|i| image.register(reg::ROBOT_STATE + i)),
        }
    }

    /// `,"io":{...},"robot":{...` (the robot object left open for its link).
    fn write(&self, out: &mut Out<'_>, source: RobotSource) {
        let pair = |out: &mut Out<'_>, [a, b]: [u16; 2]| {
            out.text("[");
            out.number(a);
            out.text(",");
            out.number(b);
            out.text("]");
        };
        let types = |out: &mut Out<'_>, [a, b]: [AnalogType; 2]| {
            let name = |kind| match kind {
                AnalogType::Current => "\"current\"",
                AnalogType::Voltage => "\"voltage\"",
            };
            out.text("[");
            out.text(name(a));
            out.text(",");
            out.text(name(b));
            out.text("]");
        };
        out.text("},\"io\":{\"di\":");
        out.number(self.di);
        out.text(",\"do\":");
        out.number(self.do_);
        out.text(",\"tool_di\":");
        out.number(self.tool_di);
        out.text(",\"tool_do\":");
        out.number(self.tool_do);
        out.text(",\"ai\":");
        pair(out, self.ai);
        out.text(",\"ao\":");
        pair(out, self.ao);
        out.text(",\"ai_types\":");
        types(out, self.ai_types);
        out.text(",\"ao_types\":");
        types(out, self.ao_types);
        out.text("},\"robot\":{\"source\":");
        out.string(match source {
            RobotSource::None => "none",
            RobotSource::Sim => "sim",
            RobotSource::Link => "link",
        });
        let [state, servo_on, emergency_stop, safety_stop, direct_teach, power_button] = self.robot;
        out.text(",\"state\":");
        out.string(crate::map::names::robot_state_name(state));
        out.text(",\"state_code\":");
        out.number(state);
        out.text(",\"servo_on\":");
        out.boolean(servo_on != 0);
        out.text(",\"emergency_stop\":");
        out.boolean(emergency_stop != 0);
        out.text(",\"safety_stop\":");
        out.number(safety_stop);
        out.text(",\"direct_teach\":");
        out.boolean(direct_teach != 0);
        out.text(",\"power_button\":");
        out.boolean(power_button != 0);
    }
}

/// How a telemetry register reads in its unit (docs/data-map.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Scale {
    /// Unsigned, as it is (mA, °C).
    Whole,
    /// Two's complement, as it is (N, N·m).
    Signed,
    /// Two's complement, in tenths (0.1 mm, 0.1 degree, and per second).
    Tenths,
}

/// The robot's telemetry (registers 270-435) in `GET /api/telemetry`: each
/// group's key (its unit in the name), first register, registers and scale.
pub(super) const TELEMETRY: [(&str, u16, u8, Scale); 13] = [
    ("joint_position_deg", reg::JOINT_POSITION, 6, Scale::Tenths),
    ("joint_velocity_deg_s", reg::JOINT_VELOCITY, 6, Scale::Tenths),
    ("joint_current_ma", reg::JOINT_CURRENT, 6, Scale::Whole),
    ("joint_temperature_c", reg::JOINT_TEMPERATURE, 6, Scale::Whole),
    ("joint_torque_nm", reg::JOINT_TORQUE, 6, Scale::Signed),
    ("task_position_mm", reg::TASK_POSITION, 3, Scale::Tenths),
    ("task_orientation_deg", reg::TASK_ORIENTATION, 3, Scale::Tenths),
    ("task_velocity_mm_s", reg::TASK_VELOCITY, 3, Scale::Tenths),
    ("task_angular_velocity_deg_s", reg::TASK_ANGULAR_VELOCITY, 3, Scale::Tenths),
    ("tool_offset_mm", reg::TOOL_OFFSET_LENGTH, 3, Scale::Tenths),
    ("tool_offset_deg", reg::TOOL_OFFSET_DEGREE, 3, Scale::Tenths),
    ("external_force_n", reg::EXTERNAL_FORCE, 3, Scale::Signed),
    ("external_moment_nm", reg::EXTERNAL_MOMENT, 3, Scale::Signed),
];

/// The registers [`TELEMETRY`] names, in its order.
const TELEMETRY_LEN: usize = {
    let mut total = 0;
    let mut rest: &[(&str, u16, u8, Scale)] = &TELEMETRY;
    while let [(_, _, count, _), tail @ ..] = rest {
        total += *count as usize;
        rest = tail;
    }
    total
};

/// [`TELEMETRY`]'s registers, read from the image at once (under the one
/// lock of [`crate::device::Device::read`]: one 100 ms sample, not two).
fn telemetry(image: &Image) -> [u16; TELEMETRY_LEN] {
    let mut values = [0; TELEMETRY_LEN];
    let mut slots = values.iter_mut();
    for &(_, first, count, _) in &TELEMETRY {
        for (offset, slot) in (0..u16::from(count)).zip(slots.by_ref()) {
            *slot = image.register(first + offset);
        }
    }
    values
}

/// `GET /api/telemetry`: `{"joint_position_deg": [...], ...}`, each value
/// in the unit its key names.
pub(super) fn telemetry_document(out: &mut Out<'_>, values: &[u16; TELEMETRY_LEN]) {
    let mut values = values.iter();
    for (i, &(key, _, count, scale)) in TELEMETRY.iter().enumerate() {
        out.text(if i == 0 { "{\"" } else { "],\"" });
        out.text(key);
        out.text("\":[");
        for (j, &raw) in values.by_ref().take(usize::from(count)).enumerate() {
            if j > 0 {
                out.text(",");
            }
            match scale {
                Scale::Whole => out.number(raw),
                Scale::Signed => out.signed(i32::from(raw as i16), false),
                Scale::Tenths => out.signed(i32::from(raw as i16), true),
            }
        }
    }
    out.text("]}");
}

/// Every setting grouped as docs/settings.md's table, numbers unquoted, and the
/// admin group with only whether a password is set; with
/// `reboot_required` after a change.
pub(super) fn settings_document(
    out: &mut Out<'_>,
    settings: &Settings,
    password_set: bool,
    reboot_required: Option<bool>,
) {
    out.clear();
    let mut group = "";
    for &field in Field::ALL {
        if field.group() != group {
            out.text(if group.is_empty() { "{\"" } else { "},\"" });
            group = field.group();
            out.text(group);
            out.text("\":{\"");
        } else {
            out.text(",\"");
        }
        out.text(field.name());
        out.text("\":");
        match field.kind() {
            Kind::Number => {
                let _ = settings.show(field, out);
            }
            Kind::Text => out.string_with(|w| settings.show(field, w)),
        }
    }
    out.text("},\"admin\":{\"password_set\":");
    out.boolean(password_set);
    out.text("}");
    if let Some(reboot_required) = reboot_required {
        out.text(",\"reboot_required\":");
        out.boolean(reboot_required);
    }
    out.text("}");
}

/// An error's key in a 400's `errors`.
#[derive(Clone, Copy, Debug)]
enum Key<'a> {
    /// A setting: `group.name`.
    Field(Field),
    /// A key of the API's own: `password`.
    Name(&'static str),
    /// A key from the body that names nothing: `group`, or `group.name`.
    Unknown(Str<'a>, Option<Str<'a>>),
}

impl Key<'_> {
    fn same(&self, other: &Key<'_>) -> bool {
        match (self, other) {
            (Key::Field(a), Key::Field(b)) => a == b,
            (Key::Name(a), Key::Name(b)) => a == b,
            (Key::Unknown(a, None), Key::Unknown(b, None)) => a.same(b),
            (Key::Unknown(a, Some(x)), Key::Unknown(b, Some(y))) => a.same(b) && x.same(y),
            _ => false,
        }
    }
}

/// A 400's `{"errors": {...}}`, written as the errors are found: one
/// message per key (the first), as many as fit the response.
struct Report<'o, 'b, 'a> {
    out: &'o mut Out<'b>,
    /// Keys reported, but fields (a bit each in `fields`).
    keys: heapless::Vec<Key<'a>, MAX_UNKNOWN_LISTED>,
    fields: u32,
    /// Errors found; `listed` of them written.
    count: usize,
    listed: usize,
    /// The response is full: later errors are not listed.
    full: bool,
}

impl<'o, 'b, 'a> Report<'o, 'b, 'a> {
    fn new(out: &'o mut Out<'b>) -> Self {
        out.clear();
        Self { out, keys: heapless::Vec::new(), fields: 0, count: 0, listed: 0, full: false }
    }

    fn is_empty(&self) -> bool {
        self.count == 0
    }

    fn add(&mut self, key: Key<'a>, message: &str) {
        match key {
            Key::Field(field) => {
                let bit = Field::ALL.iter().position(|&f| f == field).map_or(0, |i| 1u32 << (i % 32));
                if self.fields & bit != 0 {
                    return;
                }
                self.fields |= bit;
            }
            _ if self.keys.iter().any(|k| k.same(&key)) => return,
            _ => {
                if self.keys.push(key).is_err() {
                    // Refused all the same; not listed.
                    self.count += 1;
                    return;
                }
            }
        }
        self.count += 1;
        if self.full {
            return;
        }
        if self.count == 1 {
            self.out.text("{\"errors\":{");
            // Room for the closing brackets, whatever comes.
            self.out.reserve(2);
        }
        let mark = self.out.mark();
        if self.listed > 0 {
            self.out.text(",");
        }
        match key {
            Key::Field(field) => self.out.string(field.key()),
            Key::Name(name) => self.out.string(name),
            Key::Unknown(group, None) => self.out.string_of(group.bytes()),
            Key::Unknown(group, Some(name)) => self.out.string_of(group.bytes().chain(*b".").chain(name.bytes())),
        }
        self.out.text(":");
        self.out.string(message);
        if self.out.overflowed() {
            self.out.truncate(mark);
            self.full = true;
        } else {
            self.listed += 1;
        }
    }

    fn finish(self) {
        self.out.reserve(0);
        self.out.text("}}");
    }
}

/// Applies the settings `body` holds to `settings`, each by its own rule;
/// every problem goes to `report`. `Err` only when the body is not JSON.
fn patch<'a>(body: &'a [u8], settings: &mut Settings, report: &mut Report<'_, '_, 'a>) -> Result<(), Malformed> {
    let mut json = Reader::new(body);
    json.begin_object()?;
    let mut seen = 0u32;
    while let Some(group) = json.next_key()? {
        let name = Field::ALL.iter().map(|f| f.group()).chain([ADMIN]).find(|&name| group.is(name));
        let Some(name) = name else {
            json.value()?;
            report.add(Key::Unknown(group, None), "unknown group");
            continue;
        };
        if json.peek() != Some(b'{') {
            json.value()?;
            report.add(Key::Unknown(group, None), "must be an object");
            continue;
        }
        json.begin_object()?;
        while let Some(member) = json.next_key()? {
            let value = json.value()?;
            if name == ADMIN {
                // `password_set` is read-only (so a document from GET can be
                // sent back); the password has its own endpoint.
                if !member.is("password_set") {
                    let message =
                        if member.is("password") { "set it with PUT /api/password" } else { "unknown setting" };
                    report.add(Key::Unknown(group, Some(member)), message);
                }
                continue;
            }
            let found = Field::ALL.iter().enumerate().find(|(_, f)| f.group() == name && member.is(f.name()));
            let Some((index, &field)) = found else {
                report.add(Key::Unknown(group, Some(member)), "unknown setting");
                continue;
            };
            let bit = 1u32 << (index % 32);
            if seen & bit != 0 {
                report.add(Key::Field(field), "given more than once");
                continue;
            }
            seen |= bit;
            let mut text = [0u8; MAX_VALUE_LEN];
            let result = match value {
                Value::Number(number) => settings.set(field, number),
                Value::String(string) => match string.decode(&mut text) {
                    Some(string) => settings.set(field, string),
                    None => Err(field.rule()),
                },
                _ => Err("must be a number or a string"),
            };
            if let Err(message) = result {
                report.add(Key::Field(field), message);
            }
        }
    }
    json.end()
}

/// The password `body` holds, decoded into `password`: its length, `None`
/// when absent, or too long for `password` (then `Some(MAX + 1)`).
fn read_password<'a>(
    body: &'a [u8],
    password: &mut [u8; MAX_PASSWORD_LEN],
    report: &mut Report<'_, '_, 'a>,
) -> Result<Option<usize>, Malformed> {
    let mut json = Reader::new(body);
    json.begin_object()?;
    let mut len = None;
    while let Some(key) = json.next_key()? {
        let value = json.value()?;
        if !key.is("password") {
            report.add(Key::Unknown(key, None), "unknown field");
            continue;
        }
        if len.is_some() {
            report.add(Key::Name("password"), "given more than once");
            continue;
        }
        match value {
            Value::String(text) => {
                len = Some(text.decode(password).map_or(MAX_PASSWORD_LEN + 1, str::len));
            }
            _ => report.add(Key::Name("password"), "must be a string"),
        }
    }
    json.end()?;
    Ok(len)
}

/// 400 for a body that is not JSON.
fn malformed_refusal(out: &mut Out<'_>, malformed: Malformed) -> Reply {
    out.clear();
    out.text("{\"errors\":{\"body\":\"not valid JSON (at byte ");
    out.number(malformed.at);
    out.text(")\"}}");
    Reply::new(Status::BAD_REQUEST)
}

/// The answer to a change the settings service refused.
fn refused_change(out: &mut Out<'_>, refused: Refusal, message: &str) -> Reply {
    let status = match refused {
        Refusal::Storage => Status::INTERNAL_SERVER_ERROR,
        Refusal::Unsupported => Status::NOT_IMPLEMENTED,
        Refusal::FirstPasswordClosed => Status::FORBIDDEN,
    };
    refusal(out, status, "request", message)
}

/// Port 80's answer while `tls.plain_http` is off: 308 to the same path in
/// HTTPS on `port`, at the host the request named (checked to be this
/// device first: no redirect elsewhere). The `Location` is written into
/// `out`; without a `Host` (HTTP/1.0) there is no address to send the
/// client to, and it is refused (403).
fn redirect(request: &Request<'_>, port: u16, out: &mut Out<'_>) -> site::Refused {
    let Some((host, _)) = request.host.and_then(|host| site::split_port(host, Scheme::Http)) else {
        return (Status::FORBIDDEN, "plain HTTP is off (tls.plain_http): use HTTPS");
    };
    out.clear();
    out.text("https://");
    out.text(core::str::from_utf8(host).unwrap_or_default());
    if port != super::HTTPS_PORT {
        out.text(":");
        out.number(port);
    }
    out.text(request.path);
    (Status::PERMANENT_REDIRECT, "")
}
