//! Reaching a device: its name through mDNS (or an IPv4 address), its HTTP
//! API (ureq) and the admin password (a file, the environment, a prompt).

use std::io::Read as _;
use std::net::Ipv4Addr;
use std::path::PathBuf;
use std::sync::OnceLock;
use std::time::Duration;

use base64::Engine as _;
use serde_json::Value;

use crate::{Cli, Failure, Outcome};

/// The environment variable that may hold the admin password.
pub const PASSWORD_ENV: &str = "MBIO_PASSWORD";
/// The environment variable that may hold a new admin password (`mbio password`).
pub const NEW_PASSWORD_ENV: &str = "MBIO_NEW_PASSWORD";

/// A password from the first line of `file`, else `$env`, else a prompt.
pub fn read_password(file: Option<&std::path::Path>, env: &str, prompt: &str) -> Result<String, String> {
    if let Some(path) = file {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        return Ok(text.lines().next().unwrap_or_default().to_owned());
    }
    if let Ok(password) = std::env::var(env) {
        return Ok(password);
    }
    rpassword::prompt_password(prompt)
        .map_err(|e| format!("no password: none in a file or ${env}, and no prompt ({e})"))
}
/// How long one API request may take (the device answers within its own 5 s limits).
const REQUEST_TIMEOUT: Duration = Duration::from_secs(15);
/// How long an upload may take (the device takes one within 120 s).
const UPLOAD_TIMEOUT: Duration = Duration::from_secs(150);

/// What every command needs: ports, the resolver's wait, the password once asked.
#[derive(Debug)]
pub struct Context {
    pub http_port: u16,
    pub modbus_port: u16,
    resolve_wait: Duration,
    password_file: Option<PathBuf>,
    password: OnceLock<Result<String, String>>,
}

/// A device as a command reaches it.
#[derive(Debug, Clone)]
pub struct Device {
    /// What the user typed (a name or an address).
    pub label: String,
    pub ip: Ipv4Addr,
}

/// A response of the API: its status and its JSON body (`Null` when the body is not JSON).
#[derive(Debug)]
pub struct Reply {
    pub status: u16,
    pub body: Value,
}

impl Context {
    pub fn new(cli: &Cli) -> Self {
        let wait = if cli.resolve_wait.is_finite() && cli.resolve_wait > 0.0 { cli.resolve_wait } else { 3.0 };
        Self {
            http_port: cli.http_port,
            modbus_port: cli.modbus_port,
            resolve_wait: Duration::from_secs_f64(wait.min(600.0)),
            password_file: cli.password_file.clone(),
            password: OnceLock::new(),
        }
    }

    /// `NAME`, `NAME.local` (through mDNS) or an IPv4 address.
    pub fn resolve(&self, target: &str) -> Outcome<Device> {
        if let Ok(ip) = target.parse::<Ipv4Addr>() {
            return Ok(Device { label: target.to_owned(), ip });
        }
        let name = target.trim_end_matches('.').trim_end_matches(".local");
        let valid = !name.is_empty()
            && name.len() <= 63
            && name.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-')
            && !name.starts_with('-');
        if !valid {
            return Err(Failure::Usage(format!("{target:?} is neither a device name nor an IPv4 address")));
        }
        match crate::discover::resolve_name(name, self.resolve_wait) {
            Some(ip) => Ok(Device { label: name.to_owned(), ip }),
            None => Err(Failure::Unreachable(format!(
                "{name}.local did not resolve within {:.1} s (mDNS); give its address instead",
                self.resolve_wait.as_secs_f64()
            ))),
        }
    }

    /// The admin password: `--password-file`, `$MBIO_PASSWORD`, or a prompt; asked once.
    pub fn password(&self) -> Outcome<String> {
        let found = self
            .password
            .get_or_init(|| read_password(self.password_file.as_deref(), PASSWORD_ENV, "admin password: "));
        match found {
            Ok(password) if !password.is_empty() => Ok(password.clone()),
            Ok(_) => Err(Failure::Denied("the password is empty".into())),
            Err(message) => Err(Failure::Denied(message.clone())),
        }
    }

    fn agent(&self, timeout: Duration) -> ureq::Agent {
        let config = ureq::Agent::config_builder()
            .http_status_as_error(false)
            .timeout_global(Some(timeout))
            .timeout_connect(Some(Duration::from_secs(5)))
            // The device answers one request per connection, then closes it.
            .max_idle_connections(0)
            .build();
        ureq::Agent::new_with_config(config)
    }

    fn url(&self, device: &Device, path: &str) -> String {
        // The Host field is then the IPv4 literal, which the device takes
        // (docs/http-api.md, "What a page of another site cannot do").
        format!("http://{}:{}{path}", device.ip, self.http_port)
    }

    fn authorization(&self) -> Outcome<String> {
        let password = self.password()?;
        Ok(format!("Basic {}", base64::engine::general_purpose::STANDARD.encode(format!("admin:{password}"))))
    }

    /// `GET path`: the JSON of a 200, or why not.
    pub fn get(&self, device: &Device, path: &str) -> Outcome<Value> {
        let response = self.agent(REQUEST_TIMEOUT).get(self.url(device, path)).call();
        let reply = read_reply(device, response)?;
        if reply.status == 200 { Ok(reply.body) } else { Err(refusal(device, &reply)) }
    }

    /// `PUT path` with the JSON `body` and the password: the reply, any status.
    pub fn put(&self, device: &Device, path: &str, body: &Value) -> Outcome<Reply> {
        self.put_as(device, path, body, true)
    }

    /// `PUT path` with the JSON `body`, with the password when `authorized`
    /// (the first password is set without one).
    pub fn put_as(&self, device: &Device, path: &str, body: &Value, authorized: bool) -> Outcome<Reply> {
        let mut request =
            self.agent(REQUEST_TIMEOUT).put(self.url(device, path)).header("Content-Type", "application/json");
        if authorized {
            request = request.header("Authorization", self.authorization()?);
        }
        read_reply(device, request.send(body.to_string()))
    }

    /// `POST /api/firmware` with `len` bytes from `body` (its Content-Length
    /// set, never chunked: the device takes no chunked body).
    pub fn upload(&self, device: &Device, len: u64, body: impl std::io::Read + 'static) -> Outcome<Reply> {
        let authorization = self.authorization()?;
        let response = self
            .agent(UPLOAD_TIMEOUT)
            .post(self.url(device, "/api/firmware"))
            .header("Content-Type", "application/octet-stream")
            .header("Content-Length", len.to_string())
            .header("Authorization", authorization)
            .send(ureq::SendBody::from_owned_reader(body));
        read_reply(device, response)
    }
}

fn read_reply(device: &Device, response: Result<ureq::http::Response<ureq::Body>, ureq::Error>) -> Outcome<Reply> {
    let mut response =
        response.map_err(|e| Failure::Unreachable(format!("{} ({}): no answer: {e}", device.label, device.ip)))?;
    let status = response.status().as_u16();
    let mut text = String::new();
    // The API's largest document is under 2 KiB; read at most 64 KiB.
    let read = response.body_mut().as_reader().take(64 * 1024).read_to_string(&mut text);
    if let Err(e) = read {
        return Err(Failure::Unreachable(format!("{} ({}): the answer broke off: {e}", device.label, device.ip)));
    }
    let body = serde_json::from_str(&text).unwrap_or(Value::Null);
    Ok(Reply { status, body })
}

/// The device's `{"errors": {key: message}}`, one `key: message` a line.
pub fn errors(body: &Value) -> Vec<String> {
    match body.get("errors").and_then(Value::as_object) {
        Some(errors) => errors.iter().map(|(key, message)| format!("{key}: {}", text(message))).collect(),
        None => Vec::new(),
    }
}

/// A refusal as a failure of its kind: 401 and 403 are about the password or the
/// address, the rest a refusal; each carries the device's own messages.
pub fn refusal(device: &Device, reply: &Reply) -> Failure {
    let mut message = format!("{} ({}) answered {}", device.label, device.ip, reply.status);
    for line in errors(&reply.body) {
        message.push_str("\n  ");
        message.push_str(&line);
    }
    match reply.status {
        401 => Failure::Denied(format!("{message}\n  (wrong or missing password: --password-file, ${PASSWORD_ENV})")),
        403 => Failure::Denied(message),
        _ => Failure::Refused(message),
    }
}

/// A JSON value as text: a string without its quotes, anything else as JSON.
pub fn text(value: &Value) -> String {
    match value {
        Value::String(s) => s.clone(),
        Value::Null => "-".to_owned(),
        other => other.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_are_listed_per_key_and_anything_else_is_none() {
        let body = serde_json::json!({"errors": {"modbus.unit_id": "any, or 1-247", "robot": "must be an object"}});
        assert_eq!(errors(&body), ["modbus.unit_id: any, or 1-247", "robot: must be an object"]);
        assert!(errors(&serde_json::json!({"errors": 7})).is_empty());
        assert!(errors(&Value::Null).is_empty());
        let device = Device { label: "x".into(), ip: Ipv4Addr::new(198, 18, 0, 2) };
        assert!(matches!(refusal(&device, &Reply { status: 401, body: Value::Null }), Failure::Denied(_)));
        assert!(
            matches!(refusal(&device, &Reply { status: 400, body: body.clone() }), Failure::Refused(m) if m.contains("1-247"))
        );
    }
}
