//! mDNS and DNS-SD (docs/discovery.md) as an integrator's tools see
//! them: python-zeroconf in hal-sim's namespace resolves the name and
//! browses the services (tests/mdns/zeroconf-client.py).

use serde_json::{Value, json};
use system_tests::hal_sim::HalSim;
use system_tests::mdns::{browse, resolve};
use system_tests::netns::DEVICE_IP;

/// The workspace's version, which TXT `version=` carries.
const VERSION: &str = env!("CARGO_PKG_VERSION");

/// The one instance of a browse, checked for `name`, `port` and the TXT.
fn instance(instances: &[Value], name: &str, service: &str, port: u16) {
    assert_eq!(instances.len(), 1, "{instances:#?}");
    let found = &instances[0];
    assert_eq!(found["name"], format!("{name}.{service}"), "{found}");
    assert_eq!(found["port"], port, "{found}");
    assert_eq!(found["server"], format!("{name}.local."), "{found}");
    assert_eq!(found["addresses"], json!([DEVICE_IP]), "{found}");
    assert_eq!(found["txt"], json!({"name": name, "model": "hal-sim", "version": VERSION}), "{found}");
}

#[test]
fn the_name_resolves_and_both_services_are_found_with_their_ports_and_text() {
    let sim = HalSim::start(&["--robot", "idle"]);
    // Past the two announcements (at start and a second later): every
    // answer below answers a query.
    std::thread::sleep(std::time::Duration::from_millis(2500));
    assert_eq!(resolve(sim.ns(), "mbio-53494d.local.", 5), [DEVICE_IP]);
    instance(&browse(sim.ns(), "_modbus._tcp.local.", 5), "mbio-53494d", "_modbus._tcp.local.", 502);
    instance(&browse(sim.ns(), "_http._tcp.local.", 5), "mbio-53494d", "_http._tcp.local.", 80);
}

#[test]
fn a_new_name_is_answered_and_the_old_one_no_longer() {
    let sim = HalSim::start(&["--robot", "idle", "--port", "1502"]);
    assert_eq!(resolve(sim.ns(), "mbio-53494d.local.", 5), [DEVICE_IP]);
    let reply = sim.put("/api/settings", r#"{"device": {"name": "press-7"}}"#, Some(sim.claim()));
    assert_eq!(reply.status, 200, "{}", reply.body);
    assert_eq!(resolve(sim.ns(), "press-7.local.", 5), [DEVICE_IP]);
    instance(&browse(sim.ns(), "_modbus._tcp.local.", 5), "press-7", "_modbus._tcp.local.", 1502);
    assert!(resolve(sim.ns(), "mbio-53494d.local.", 2).is_empty(), "the old name is not answered");
}

#[test]
fn without_http_only_modbus_is_advertised() {
    let sim = HalSim::start_with(None, 0, &["--robot", "idle"]);
    assert!(browse(sim.ns(), "_http._tcp.local.", 3).is_empty());
    instance(&browse(sim.ns(), "_modbus._tcp.local.", 5), "mbio-53494d", "_modbus._tcp.local.", 502);
}

#[test]
fn another_http_port_is_advertised() {
    let sim = HalSim::start_with(None, 8080, &["--robot", "idle"]);
    instance(&browse(sim.ns(), "_http._tcp.local.", 5), "mbio-53494d", "_http._tcp.local.", 8080);
}
