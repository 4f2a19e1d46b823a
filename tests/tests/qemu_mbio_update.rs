//! `mbio update`: a rollout to two QEMU images (the mps2-an386 bootloader
//! and the image with `update`, as tests/tests/qemu_update.rs boots them)
//! on one bridge in one namespace. A forged file stops the rollout at the
//! first device, and the second is never sent it; with `--keep-going` both
//! are tried and both refuse; the signed file then updates both, each one's
//! new version read back by mbio in 0x2B after its reboot.
//!
//! Needs root, `qemu-system-arm`, `defmt-print`, mbio, the bootloader and
//! the two images with `update` (`qemu::UPDATE_BUILD_COMMAND`,
//! `qemu::UPDATE_NEXT_BUILD_COMMAND`); fails loudly without them.

use std::net::Ipv4Addr;
use std::time::Duration;

use serde_json::Value;
use system_tests::fleet::{assert_exit, bridge, mbio_in};
use system_tests::netns::{DEVICE_IP, Namespace};
use system_tests::qemu::{self, Qemu};
use system_tests::update::{api_status, installed_state, signed, test_dir};

/// Where the second QEMU is moved to (the first keeps the image's fallback address, 198.18.0.2).
const SECOND_IP: Ipv4Addr = Ipv4Addr::new(198, 18, 0, 12);

fn stdout(output: &std::process::Output) -> String {
    String::from_utf8_lossy(&output.stdout).into_owned()
}

/// `GET /api/status` of `ip`, from inside `ns`.
fn status_in(ns: &Namespace, ip: Ipv4Addr) -> Value {
    let addr = std::net::SocketAddr::from((ip, qemu::HTTP_PORT));
    let value = std::thread::scope(|scope| {
        scope
            .spawn(|| {
                ns.enter().unwrap();
                api_status(addr, Duration::from_secs(30))
            })
            .join()
            .unwrap()
    });
    value.unwrap_or_else(|| panic!("{ip} does not answer /api/status"))
}

fn boot(
    ns: &Namespace,
    tap: &str,
    ip: Ipv4Addr,
    bootloader: &std::path::Path,
    image: &std::path::Path,
    state: &std::path::Path,
) -> Qemu {
    let qemu = Qemu::tap_booting_in(ns, tap, ip, bootloader, image, state);
    qemu.wait_for_log("update: boot state Confirmed", Duration::from_secs(30));
    qemu.wait_for_log("Modbus TCP server at", Duration::from_secs(30));
    qemu
}

/// Waits (at most 20 s) until `ip:port` takes a TCP connection from `ns`.
fn wait_reachable(ns: &Namespace, ip: &str, port: u16) {
    let probe = format!("until (exec 3<>/dev/tcp/{ip}/{port}) 2>/dev/null; do sleep 0.5; done");
    let status = ns.command("timeout").args(["20", "bash", "-c", &probe]).status().expect("bash runs");
    assert!(status.success(), "{ip}:{port} did not take a connection within 20 s");
}

#[test]
fn a_rollout_stops_at_a_forged_file_and_updates_both_with_the_signed_one() {
    let (bootloader, image) = qemu::update_images();
    let (next, next_version) = qemu::update_next_image();
    let old_version = qemu::firmware_version().map(|n| n.to_string()).join(".");
    let dir = test_dir("mbio-rollout");
    let file = signed(&dir, &qemu::flat_binary(&next), &next_version);
    let good = dir.join("next.update");
    std::fs::write(&good, &file).unwrap();
    let mut bad = file.clone();
    let last = bad.len() - 1;
    bad[last] ^= 0x01;
    let forged = dir.join("forged.update");
    std::fs::write(&forged, &bad).unwrap();

    let ns = Namespace::new().expect("a network namespace");
    let taps = bridge(&ns, 2);
    let first: Ipv4Addr = DEVICE_IP.parse().unwrap();
    let mbio = |args: &[&str]| mbio_in(&ns, args, "");

    // The second device first, alone at the image's address: claimed,
    // named, moved to its own address (a reboot: QEMU again on its state).
    let second_state = dir.join("second.state");
    std::fs::copy(installed_state(&dir, &image), &second_state).unwrap();
    let second = boot(&ns, &taps[1], first, &bootloader, &image, &second_state);
    assert_exit(&mbio(&["password", DEVICE_IP]), 0);
    let output = mbio(&[
        "set",
        DEVICE_IP,
        "device.name=qemu-b",
        "network.mode=static",
        &format!("network.address={SECOND_IP}/24"),
    ]);
    assert_exit(&output, 0);
    assert!(stdout(&output).contains("reboot"), "{}", stdout(&output));
    second.finish();
    let second = boot(&ns, &taps[1], SECOND_IP, &bootloader, &image, &second_state);
    // 198.18.0.2 now goes to another board (another MAC): the host forgets
    // the old one's, as a plant's hosts do once the entry goes stale (the
    // image sends no gratuitous ARP).
    ns.ip(&["neigh", "flush", "to", DEVICE_IP]).unwrap();
    let first_state = installed_state(&dir, &image);
    let first_qemu = boot(&ns, &taps[0], first, &bootloader, &image, &first_state);
    // The host learns the new board's MAC before mbio asks it (its ARP
    // gives up after 3 s: on a loaded machine QEMU's first answers can be
    // later, and mbio would report the device unreachable).
    wait_reachable(&ns, DEVICE_IP, 80);
    assert_exit(&mbio(&["password", DEVICE_IP]), 0);
    assert_exit(&mbio(&["set", DEVICE_IP, "device.name=qemu-a"]), 0);
    let targets = [DEVICE_IP.to_owned(), SECOND_IP.to_string()];

    // A forged file (one bit of the signed one flipped): the first device
    // refuses it, and the rollout stops there.
    let output = mbio(&["update", forged.to_str().unwrap(), &targets[0], &targets[1], "--parallel", "1", "--json"]);
    assert_exit(&output, 1);
    let summary: Value = serde_json::from_str(&stdout(&output)).unwrap();
    assert_eq!(summary[0]["result"], "refused", "{summary}");
    assert!(summary[0]["note"].as_str().unwrap().contains("signature"), "{summary}");
    assert_eq!(summary[1]["result"], "skipped", "the rollout went on: {summary}");
    assert!(first_qemu.log().contains("update: refused"), "{}", first_qemu.log());
    assert!(!second.log().contains("update: refused"), "the second device was sent the file: {}", second.log());

    // With --keep-going both are tried, and both refuse it.
    let output = mbio(&[
        "update",
        forged.to_str().unwrap(),
        &targets[0],
        &targets[1],
        "--parallel",
        "1",
        "--keep-going",
        "--json",
    ]);
    assert_exit(&output, 1);
    let summary: Value = serde_json::from_str(&stdout(&output)).unwrap();
    assert_eq!(summary[0]["result"], "refused", "{summary}");
    assert_eq!(summary[1]["result"], "refused", "{summary}");
    assert!(second.log().contains("update: refused"), "{}", second.log());
    for ip in [first, SECOND_IP] {
        let status = status_in(&ns, ip);
        assert_eq!(status["device"]["firmware"], old_version.as_str(), "{status}");
        assert_eq!(status["update"]["state"], "confirmed", "{status}");
    }

    // The signed file, to both by name (mDNS), both at once: each reboots
    // into it, and mbio reads the new version in 0x2B.
    let output =
        mbio(&["update", good.to_str().unwrap(), "qemu-a", "qemu-b", "--parallel", "2", "--json", "--timeout", "90"]);
    assert_exit(&output, 0);
    let summary: Value = serde_json::from_str(&stdout(&output)).unwrap();
    for (row, ip) in summary.as_array().unwrap().iter().zip([first, SECOND_IP]) {
        assert_eq!(row["result"], "updated", "{summary}");
        assert_eq!(row["address"], ip.to_string().as_str(), "{summary}");
        assert_eq!(row["before"], old_version.as_str(), "{summary}");
        assert_eq!(row["after"], next_version.as_str(), "{summary}");
    }
    first_qemu.wait_for_log("update: this image is confirmed", Duration::from_secs(60));
    second.wait_for_log("update: this image is confirmed", Duration::from_secs(60));
    for ip in [first, SECOND_IP] {
        let status = status_in(&ns, ip);
        assert_eq!(status["device"]["firmware"], next_version.as_str(), "{status}");
        assert_eq!(status["update"]["previous"], old_version.as_str(), "{status}");
    }
    // mbio find sees both, on the new version.
    let output = mbio(&["find", "--json", "--wait", "5"]);
    assert_exit(&output, 0);
    let found: Value = serde_json::from_str(&stdout(&output)).unwrap();
    assert_eq!(found.as_array().unwrap().len(), 2, "{found}");
    assert!(found.as_array().unwrap().iter().all(|d| d["firmware"] == next_version.as_str()), "{found}");
    first_qemu.finish();
    second.finish();
    drop(ns);
    std::fs::remove_dir_all(&dir).unwrap();
}
