//! What a web page on another site cannot make the device do.
//!
//! A browser sends a page's request to any address the page names, and
//! without asking first when it is a "simple" one (`GET`, or a `POST` of
//! `text/plain` or a form). So, as routers and cameras do:
//!
//! - **Host** ([`check_host`]): every request, reads too, must name the
//!   device: an IPv4 literal (a port-forwarded device, QEMU's behind
//!   127.0.0.1, must keep working; a DNS rebinding attack needs a domain
//!   name), the device's name, or `NAME.local`, each with any port. Only an
//!   HTTP/1.0 request may leave `Host` out. Otherwise 421 (another host)
//!   or 400 (none, or not a host).
//! - **Origin** ([`check_origin`]): when a browser says where the request
//!   comes from, it must be the device itself: the connection's own scheme
//!   (`http://` on port 80, `https://` on 443) and the request's own
//!   `Host`. Otherwise 403.
//! - **Content type** ([`has_content_type`]): every change (`PUT`, `POST`,
//!   bodyless ones too) must say `application/json`
//!   (`application/octet-stream` for an update file), which a page on
//!   another site cannot send without asking first (a CORS preflight, which
//!   the device never grants). Otherwise 415.

use super::request::Request;
use super::response::Status;
use crate::name::Name;
use crate::settings::Ipv4;

/// Why a request is not answered: its status and the message.
pub(super) type Refused = (Status, &'static str);

/// How a request came: in plain HTTP, or in HTTPS.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Scheme {
    Http,
    Https,
}

impl Scheme {
    /// An origin's start, as a browser writes it.
    pub(super) const fn prefix(self) -> &'static [u8] {
        match self {
            Self::Http => b"http://",
            Self::Https => b"https://",
        }
    }

    /// The port the scheme means when none is written.
    const fn default_port(self) -> &'static [u8] {
        match self {
            Self::Http => b"80",
            Self::Https => b"443",
        }
    }
}

/// Whether the request's `Host` names this device (named `name`).
pub(super) fn check_host(request: &Request<'_>, name: &Name) -> Result<(), Refused> {
    let Some(host) = request.host else {
        return if request.http10 {
            Ok(())
        } else {
            Err((Status::BAD_REQUEST, "an HTTP/1.1 request must name the device in Host"))
        };
    };
    let Some((host, _port)) = split_port(host, Scheme::Http) else {
        return Err((Status::BAD_REQUEST, "Host is not a host name or address"));
    };
    if names_device(host, name) {
        Ok(())
    } else {
        Err((Status::MISDIRECTED_REQUEST, "Host must be this device: its address, its name or NAME.local"))
    }
}

/// Whether `host` (without its port) is an IPv4 literal, `name` or `name.local`.
fn names_device(host: &[u8], name: &Name) -> bool {
    if core::str::from_utf8(host).is_ok_and(|text| Ipv4::parse(text).is_ok()) {
        return true;
    }
    let host = host.strip_suffix(b".").unwrap_or(host);
    let label = match host.len().checked_sub(b".local".len()).and_then(|at| host.split_at_checked(at)) {
        Some((label, suffix)) if suffix.eq_ignore_ascii_case(b".local") => label,
        _ => host,
    };
    !label.is_empty() && label.eq_ignore_ascii_case(name.as_bytes())
}

/// `host[:port]` as the host and its port (`scheme`'s when none is
/// written); `None` for anything else (IPv6 literals included: the device
/// has none).
pub(super) fn split_port(value: &[u8], scheme: Scheme) -> Option<(&[u8], &[u8])> {
    let (host, port) = match value.iter().rposition(|&b| b == b':') {
        Some(colon) => (value.get(..colon)?, value.get(colon + 1..)?),
        None => (value, scheme.default_port()),
    };
    let port_ok = (1..=5).contains(&port.len()) && port.iter().all(u8::is_ascii_digit);
    let host_ok = !host.is_empty() && host.iter().all(|&b| b.is_ascii_alphanumeric() || b == b'.' || b == b'-');
    (port_ok && host_ok).then_some((host, port))
}

/// Whether the request's `Origin`, when it has one, is the device itself,
/// reached by `scheme`.
pub(super) fn check_origin(request: &Request<'_>, scheme: Scheme) -> Result<(), Refused> {
    const REFUSED: Refused = (Status::FORBIDDEN, "a page of another site may not use this device (Origin)");
    let Some(origin) = request.origin else { return Ok(()) };
    let (Some(site), Some(host)) = (origin.strip_prefix(scheme.prefix()), request.host) else { return Err(REFUSED) };
    match (split_port(site, scheme), split_port(host, scheme)) {
        (Some((a, a_port)), Some((b, b_port))) if a.eq_ignore_ascii_case(b) && same_port(a_port, b_port) => Ok(()),
        _ => Err(REFUSED),
    }
}

/// Two ports as written, the same number (`80` and `080` alike).
fn same_port(a: &[u8], b: &[u8]) -> bool {
    let number = |port: &[u8]| port.iter().fold(0u32, |n, &d| n * 10 + u32::from(d - b'0'));
    number(a) == number(b)
}

/// Whether the request's `Content-Type` is `media` (any case, parameters
/// such as `; charset=utf-8` allowed).
pub(super) fn has_content_type(request: &Request<'_>, media: &[u8]) -> bool {
    request.content_type.is_some_and(|value| {
        let essence = value.split(|&b| b == b';').next().unwrap_or_default();
        essence.trim_ascii().eq_ignore_ascii_case(media)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request<'a>(host: Option<&'a str>, origin: Option<&'a str>, http10: bool) -> Request<'a> {
        Request {
            method: "GET",
            path: "/",
            authorization: None,
            accept_encoding: None,
            host: host.map(str::as_bytes),
            content_type: None,
            origin: origin.map(str::as_bytes),
            http10,
            close: false,
            body: &[],
        }
    }

    #[test]
    fn the_host_names_the_device_by_address_name_or_local_name() {
        let name = Name::parse("press-4").unwrap();
        let host = |value| check_host(&request(Some(value), None, false), &name).map_err(|(status, _)| status.code);
        for good in [
            "198.18.0.2",
            "198.18.0.2:80",
            "127.0.0.1:8080",
            "10.0.2.15",
            "press-4",
            "PRESS-4:8080",
            "press-4.local",
            "press-4.LOCAL.",
            "press-4.local:80",
        ] {
            assert_eq!(host(good), Ok(()), "{good}");
        }
        for other in ["evil.example", "evil.example:80", "press-4.evil.example", "press-5", "local", "press-4.localx"] {
            assert_eq!(host(other), Err(421), "{other}");
        }
        for bad in ["", ":80", "198.18.0.2:", "198.18.0.2:123456", "[::1]:80", "a b", "198.18.0.2:8x"] {
            assert_eq!(host(bad), Err(400), "{bad:?}");
        }
        assert_eq!(host("198.018.0.2"), Err(421), "not an address (octal-looking): a name, and not ours");
        let none = |http10| check_host(&request(None, None, http10), &name).map_err(|(status, _)| status.code);
        assert_eq!(none(false), Err(400), "HTTP/1.1 needs Host");
        assert_eq!(none(true), Ok(()), "HTTP/1.0 may leave it out");
    }

    #[test]
    fn the_origin_is_the_device_itself_or_nothing() {
        let origin = |host, origin| {
            check_origin(&request(Some(host), Some(origin), false), Scheme::Http).map_err(|(s, _)| s.code)
        };
        assert_eq!(check_origin(&request(Some("198.18.0.2"), None, false), Scheme::Http), Ok(()), "no Origin");
        assert_eq!(origin("198.18.0.2", "http://198.18.0.2"), Ok(()));
        assert_eq!(origin("198.18.0.2:80", "http://198.18.0.2"), Ok(()), "the default port");
        assert_eq!(origin("127.0.0.1:8080", "http://127.0.0.1:8080"), Ok(()));
        assert_eq!(origin("press-4.local", "http://PRESS-4.local"), Ok(()));
        for (host, other) in [
            ("198.18.0.2", "http://evil.example"),
            ("198.18.0.2", "https://198.18.0.2"),
            ("198.18.0.2", "http://198.18.0.2:8080"),
            ("127.0.0.1:8080", "http://127.0.0.1"),
            ("198.18.0.2", "null"),
            ("198.18.0.2", "http://198.18.0.2.evil.example"),
            ("198.18.0.2", ""),
        ] {
            assert_eq!(origin(host, other), Err(403), "{host} from {other:?}");
        }
        assert_eq!(
            check_origin(&request(None, Some("http://198.18.0.2"), true), Scheme::Http),
            Err((Status::FORBIDDEN, "a page of another site may not use this device (Origin)"))
        );
    }

    #[test]
    fn over_https_the_origin_is_the_device_in_https() {
        let origin = |host, origin| {
            check_origin(&request(Some(host), Some(origin), false), Scheme::Https).map_err(|(s, _)| s.code)
        };
        assert_eq!(origin("198.18.0.2", "https://198.18.0.2"), Ok(()));
        assert_eq!(origin("198.18.0.2:443", "https://198.18.0.2"), Ok(()), "the default port");
        assert_eq!(origin("press-4.local:8443", "https://press-4.local:8443"), Ok(()));
        for (host, other) in [
            ("198.18.0.2", "http://198.18.0.2"),
            ("198.18.0.2:443", "https://198.18.0.2:80"),
            ("198.18.0.2", "https://evil.example"),
        ] {
            assert_eq!(origin(host, other), Err(403), "{host} from {other:?}");
        }
    }

    #[test]
    fn the_content_type_is_its_media_type_with_any_parameters() {
        let with = |value: Option<&'static str>| {
            let mut request = request(Some("10.0.0.1"), None, false);
            request.content_type = value.map(str::as_bytes);
            has_content_type(&request, b"application/json")
        };
        for good in ["application/json", "Application/JSON", "application/json; charset=utf-8", " application/json "] {
            assert!(with(Some(good)), "{good}");
        }
        for bad in [
            None,
            Some("text/plain"),
            Some("application/x-www-form-urlencoded"),
            Some("multipart/form-data"),
            Some("application/jsonx"),
            Some(""),
        ] {
            assert!(!with(bad), "{bad:?}");
        }
    }
}
