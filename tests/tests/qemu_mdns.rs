//! mDNS from the firmware itself: the mps2-an386 image on a TAP inside a
//! network namespace (QEMU's slirp carries no multicast), python-zeroconf
//! on the host side. The LAN9118 must let the mDNS group in (its hash
//! filter) and the stack must join it. Needs root, like every namespace test.

use std::time::Duration;

use serde_json::json;
use system_tests::mdns::{browse, resolve};
use system_tests::netns::DEVICE_IP;
use system_tests::qemu::Qemu;

/// The name from QEMU's default MAC 52:54:00:12:34:56.
const NAME: &str = "mbio-123456";

#[test]
fn the_image_answers_its_name_and_advertises_modbus_on_a_tap() {
    let qemu = Qemu::tap();
    // No DHCP server in the namespace: the fallback address after 5 s.
    qemu.wait_for_log(&format!("Modbus TCP server at {DEVICE_IP}:502"), Duration::from_secs(30));
    // Past the two announcements (at once and a second later): every
    // answer below answers a query, which the LAN9118 had to let in.
    std::thread::sleep(Duration::from_millis(2500));
    let ns = qemu.ns().expect("a TAP QEMU has a namespace");
    assert_eq!(resolve(ns, &format!("{NAME}.local."), 5), [DEVICE_IP]);
    let instances = browse(ns, "_modbus._tcp.local.", 5);
    assert_eq!(instances.len(), 1, "{instances:#?}");
    let found = &instances[0];
    assert_eq!(found["name"], format!("{NAME}._modbus._tcp.local."));
    assert_eq!(found["port"], 502);
    assert_eq!(found["addresses"], json!([DEVICE_IP]));
    assert_eq!(
        found["txt"],
        json!({"name": NAME, "model": "mps2-an386", "version": env!("CARGO_PKG_VERSION")}),
        "{found}"
    );
    let http = browse(ns, "_http._tcp.local.", 5);
    assert_eq!(http.first().map(|i| i["port"].clone()), Some(json!(80)), "{http:#?}");
    let log = qemu.finish();
    assert!(log.contains(&format!("mdns: announcing {NAME}.local")), "{log}");
}
