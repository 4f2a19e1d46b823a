//! python-zeroconf as the mDNS client of the system tests
//! (`tests/mdns/zeroconf-client.py`): inside a test's namespace, on its
//! TAP's host side ([`resolve`], [`browse`]), or on this machine's
//! interface toward a device on the LAN ([`Client`]: the board tests).

use std::net::Ipv4Addr;
use std::path::Path;
use std::process::Command;

use crate::netns::Namespace;

/// Where the client runs (a namespace, or this machine's network) and on
/// which interface it asks (the TAP's host side, or the one toward a
/// device).
#[derive(Debug, Clone, Copy)]
pub struct Client<'a> {
    ns: Option<&'a Namespace>,
    toward: Option<Ipv4Addr>,
}

impl<'a> Client<'a> {
    /// In `ns` (or this machine's network), asking on the interface the
    /// route to `device` leaves from.
    pub fn toward(ns: Option<&'a Namespace>, device: Ipv4Addr) -> Self {
        Self { ns, toward: Some(device) }
    }

    /// In `ns`, on its TAP's host side (198.18.0.1).
    pub fn in_namespace(ns: &'a Namespace) -> Self {
        Self { ns: Some(ns), toward: None }
    }

    /// The IPv4 addresses `name` (`NAME.local.`) resolves to within `timeout_s`.
    pub fn resolve(&self, name: &str, timeout_s: u32) -> Vec<String> {
        let result = self.run(&["resolve", name, &timeout_s.to_string()]);
        result["addresses"]
            .as_array()
            .map(|addresses| addresses.iter().filter_map(|a| a.as_str().map(str::to_owned)).collect())
            .unwrap_or_default()
    }

    /// The instances of `service` (`_modbus._tcp.local.`) found within
    /// `timeout_s`, each resolved: name, port, server, addresses, txt.
    /// With `instance`, browses until that one is found (a LAN may have
    /// others), else until a first one is.
    pub fn browse(&self, service: &str, instance: Option<&str>, timeout_s: u32) -> Vec<serde_json::Value> {
        let timeout = timeout_s.to_string();
        let mut args = vec!["browse", service, &timeout];
        if let Some(instance) = instance {
            args.extend(["--wait-for", instance]);
        }
        let result = self.run(&args);
        result["instances"].as_array().cloned().unwrap_or_default()
    }

    /// Runs the client with `args` and reads its JSON line.
    fn run(&self, args: &[&str]) -> serde_json::Value {
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("mdns").join("zeroconf-client.py");
        let mut command = match self.ns {
            Some(ns) => ns.command("timeout"),
            None => Command::new("timeout"),
        };
        command.arg("60").arg("python3").arg(&script).args(args);
        if let Some(device) = self.toward {
            command.args(["--toward", &device.to_string()]);
        }
        let output = command.output().expect("python3 runs");
        let stdout = String::from_utf8_lossy(&output.stdout);
        assert!(
            output.status.success(),
            "zeroconf-client {args:?} failed ({}): {stdout}\n{}",
            output.status,
            String::from_utf8_lossy(&output.stderr)
        );
        serde_json::from_str(stdout.trim())
            .unwrap_or_else(|e| panic!("zeroconf-client {args:?} printed no JSON ({e}): {stdout}"))
    }
}

/// The IPv4 addresses `name` (`NAME.local.`) resolves to within `timeout_s`,
/// asked inside `ns`.
pub fn resolve(ns: &Namespace, name: &str, timeout_s: u32) -> Vec<String> {
    Client::in_namespace(ns).resolve(name, timeout_s)
}

/// The instances of `service` (`_modbus._tcp.local.`) found within
/// `timeout_s` inside `ns`, each resolved: name, port, server, addresses, txt.
pub fn browse(ns: &Namespace, service: &str, timeout_s: u32) -> Vec<serde_json::Value> {
    Client::in_namespace(ns).browse(service, None, timeout_s)
}
