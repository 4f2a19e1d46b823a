//! DHCP's hostname (docs/discovery.md): hal-sim in `dhcp` mode against a
//! real DHCP server (dnsmasq) on its namespace's TAP, which hands out
//! 198.18.0.2 alone; its lease file shows the name the device sent.

use std::path::PathBuf;
use std::time::Duration;

use system_tests::dhcp::DhcpServer;
use system_tests::hal_sim::{HTTP_PORT, HalSim};
use system_tests::netns::{DEVICE_IP, Namespace};

/// How long a lease may take: DHCP's exchange is a few round trips, but
/// smoltcp waits a little before its first DISCOVER.
const LEASE_WAIT: Duration = Duration::from_secs(15);

#[test]
fn the_lease_names_the_device_and_a_new_name_comes_with_the_next_lease() {
    let ns = Namespace::new().expect("a network namespace with a TAP");
    let dhcp = DhcpServer::start(&ns);
    let state = std::env::temp_dir().join(format!("hal-sim-dhcp-{}.state", std::process::id()));
    let _ = std::fs::remove_file(&state);
    let _state = Remove(state.clone());
    // A DHCP timeout longer than the test: the address can only be the lease's.
    let mut sim = HalSim::start_in(ns, Some(&state), HTTP_PORT, &["--mode", "dhcp", "--dhcp-timeout", "600"]);

    let lease = dhcp.wait_lease("mbio-53494d", LEASE_WAIT);
    assert_eq!(lease.mac, "02:4d:42:53:49:4d");
    assert_eq!(lease.address, DEVICE_IP);
    let status = sim.get("/api/status").json();
    assert_eq!(status["network"]["mode"], "dhcp", "{status}");
    assert_eq!(status["network"]["address"], format!("{DEVICE_IP}/24"), "{status}");

    // A new name is saved and in force at once (mDNS, the page), but DHCP
    // takes it at the next fresh exchange: here the next start.
    let reply = sim.put("/api/settings", r#"{"device": {"name": "press-7"}}"#, Some(sim.claim()));
    assert_eq!(reply.status, 200, "{}", reply.body);
    sim.restart();
    let lease = dhcp.wait_lease("press-7", LEASE_WAIT);
    assert_eq!(lease.address, DEVICE_IP);
    assert!(!sim.log().contains("no DHCP lease"), "the fallback never applied:\n{}", sim.log());
}

/// Removes a file on drop.
struct Remove(PathBuf);

impl Drop for Remove {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}
