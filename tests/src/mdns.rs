//! python-zeroconf as the mDNS client of the system tests
//! (`tests/mdns/zeroconf-client.py`), run inside a test's namespace.

use std::path::Path;

use crate::netns::Namespace;

/// Runs the client with `args` in `ns` and reads its JSON line.
fn client(ns: &Namespace, args: &[&str]) -> serde_json::Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("mdns").join("zeroconf-client.py");
    let output = ns.command("timeout").arg("60").arg("python3").arg(&script).args(args).output().expect("python3 runs");
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

/// The IPv4 addresses `name` (`NAME.local.`) resolves to within `timeout_s`.
pub fn resolve(ns: &Namespace, name: &str, timeout_s: u32) -> Vec<String> {
    let result = client(ns, &["resolve", name, &timeout_s.to_string()]);
    result["addresses"]
        .as_array()
        .map(|addresses| addresses.iter().filter_map(|a| a.as_str().map(str::to_owned)).collect())
        .unwrap_or_default()
}

/// The instances of `service` (`_modbus._tcp.local.`) found within
/// `timeout_s`, each resolved: name, port, server, addresses, txt.
pub fn browse(ns: &Namespace, service: &str, timeout_s: u32) -> Vec<serde_json::Value> {
    let result = client(ns, &["browse", service, &timeout_s.to_string()]);
    result["instances"].as_array().cloned().unwrap_or_default()
}
