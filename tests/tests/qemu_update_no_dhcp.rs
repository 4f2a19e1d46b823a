//! An update on a network without DHCP, with the device's default DHCP
//! timeout (`network.dhcp_timeout_s` 30): the new image waits 30 s for a
//! lease before its fallback address, and it confirms itself only once it
//! serves, so its trial must last longer than that. With a trial limit of
//! 30 s from the start (the first firmware's), the watchdog reset it just
//! before its fallback address came, and the bootloader rolled it back:
//! every update of a device on such a network failed. The trial's limit is
//! now 30 s plus the DHCP timeout in `dhcp` mode (docs/update.md).
//!
//! The image with `update` under its bootloader on the TAP of a new network
//! namespace (no DHCP server there). The test images are built with a 5 s
//! timeout, so the test sets 30 with `PUT /api/settings` first; it takes
//! effect at the next start, which is the upload's own reboot into the new
//! image (the new image's log says its fallback came after 30 s). Needs
//! root, the images (`scripts/test firmware`), `qemu-system-arm`, curl and
//! `defmt-print`.

use std::time::{Duration, Instant};

use system_tests::OWNER_PASSWORD;
use system_tests::board::{self, Board};
use system_tests::netns::DEVICE_IP;
use system_tests::qemu::{self, BOOTLOADER_STATE, Qemu};
use system_tests::update::{BOOT_MAGIC, bootloader_output, installed_state, state_word, test_dir};
use tokio_modbus::client::Reader as _;
use tokio_modbus::prelude::{ConformityLevel, ReadCode};

/// The device's default DHCP timeout (docs/settings.md).
const DHCP_TIMEOUT_S: u64 = 30;
/// The new image must still run, confirmed, past this uptime: longer than
/// the old 30 s limit and its watchdog's reset, and than 30 s + the DHCP
/// timeout, the new limit.
const KEPT_PAST_S: u64 = 60;

/// How many times the bootloader has started.
fn boots(qemu: &Qemu) -> usize {
    bootloader_output(&qemu.stderr()).matches("mps2-an386-boot: boot state").count()
}

/// The running version, its boot state and its uptime, from `/api/status`.
fn running(status: &serde_json::Value) -> (&str, &str, u64) {
    let firmware = status["device"]["firmware"].as_str().unwrap_or_default();
    let state = status["update"]["state"].as_str().unwrap_or_default();
    (firmware, state, status["device"]["uptime_s"].as_u64().unwrap_or(0))
}

/// 0x2B's extended stream: MajorMinorRevision and the previous version (0x80).
fn identification(board: &Board<'_>) -> (String, String) {
    let addr = board.modbus_addr(&board.snapshot());
    board.run(|| async {
        let reply = board::connect(addr).await.read_device_identification(ReadCode::Extended, 0).await.unwrap();
        let reply = reply.unwrap();
        assert_eq!(reply.conformity_level, ConformityLevel::ExtendedIdentification, "0x83");
        let text = |id: u8| {
            let object = reply.device_id_objects.iter().find(|o| o.id == id);
            object.and_then(|o| o.value_as_str()).unwrap_or_else(|| panic!("object {id:#x}: {reply:?}")).to_owned()
        };
        (text(2), text(0x80))
    })
}

#[test]
fn an_update_without_dhcp_outlasts_the_dhcp_timeout_confirms_and_is_kept() {
    let (bootloader, image) = qemu::update_images();
    let (next, next_version) = qemu::update_next_image();
    let old_version = qemu::firmware_version().map(|n| n.to_string()).join(".");
    let dir = test_dir("update-no-dhcp");
    let state = installed_state(&dir, &image);
    let file = board::update_file(&dir, &qemu::flat_binary(&next), &next_version);

    let qemu = Qemu::tap_booting(&bootloader, &image, &state);
    qemu.wait_for_log(&format!("Modbus TCP server at {DEVICE_IP}:502"), Duration::from_secs(30));
    let mut board = Board::new(DEVICE_IP.parse().unwrap());
    board.ns = qemu.ns();
    let settings = board.get("/api/settings").json();
    assert_eq!(settings["network"]["mode"], "dhcp", "the image's factory settings: {settings}");
    board.claim(OWNER_PASSWORD);
    let change = format!(r#"{{"network": {{"dhcp_timeout_s": {DHCP_TIMEOUT_S}}}}}"#);
    let reply = board.change("PUT", "/api/settings", &change);
    reply.expect(200, "PUT /api/settings");
    let changed = reply.json();
    assert_eq!(changed["network"]["dhcp_timeout_s"], DHCP_TIMEOUT_S, "{changed}");
    assert_eq!(changed["reboot_required"], true, "{changed}");
    assert_eq!(board.get("/api/settings").json()["network"]["dhcp_timeout_s"], DHCP_TIMEOUT_S, "saved");

    board.upload(&file).expect(202, "POST /api/firmware");
    let deadline = Instant::now() + Duration::from_secs(20);
    while boots(&qemu) < 2 {
        assert!(Instant::now() < deadline, "no reboot after the upload\n{}", qemu.stderr());
        std::thread::sleep(Duration::from_millis(20));
    }
    let started = Instant::now();

    // The new image serves once its fallback address comes, DHCP_TIMEOUT_S
    // after its start, and confirms itself; the watchdog must not reset it
    // before.
    let deadline = started + Duration::from_secs(DHCP_TIMEOUT_S + 20);
    loop {
        assert!(boots(&qemu) == 2, "{}", reset_report(&qemu, started));
        let status = board.try_status();
        if let Some(status) = &status {
            let (firmware, boot_state, _) = running(status);
            if firmware == next_version && boot_state == "confirmed" {
                break;
            }
        }
        assert!(Instant::now() < deadline, "{next_version} not confirmed in {:?}: {status:?}", deadline - started);
        std::thread::sleep(Duration::from_millis(250));
    }
    let confirmed = started.elapsed();
    eprintln!("no DHCP: {next_version} confirmed {:.1} s after its start", confirmed.as_secs_f64());
    assert!(confirmed > Duration::from_secs(DHCP_TIMEOUT_S), "confirmed before the DHCP timeout: {confirmed:?}");
    assert_eq!(identification(&board), (next_version.clone(), old_version.clone()), "0x2B at the confirmation");

    // Still the same boot, confirmed, past KEPT_PAST_S of its own uptime
    // (the guest's clock: under load QEMU's runs behind the host's, so
    // the test waits for the device to say so, not for the host's time).
    let deadline = Instant::now() + Duration::from_secs(3 * KEPT_PAST_S);
    let status = loop {
        let status = board.snapshot().status;
        if running(&status).2 > KEPT_PAST_S || Instant::now() > deadline {
            break status;
        }
        std::thread::sleep(Duration::from_secs(1));
    };
    let (firmware, boot_state, uptime) = running(&status);
    assert!(boots(&qemu) == 2, "{}", reset_report(&qemu, started));
    assert_eq!((firmware, boot_state), (next_version.as_str(), "confirmed"), "{status}");
    assert!(uptime > KEPT_PAST_S, "{status}");
    assert_eq!(status["update"]["previous"], old_version.as_str(), "{status}");
    assert_eq!(identification(&board), (next_version.clone(), old_version), "0x2B past {KEPT_PAST_S} s");
    // The confirmation is in the boot state: a reset now would not roll back.
    assert_eq!(state_word(&state, BOOTLOADER_STATE), BOOT_MAGIC, "the confirmation is not in the boot state");
    eprintln!("no DHCP: {next_version} still running and confirmed at {uptime} s of uptime");

    let log = qemu.finish();
    let new_image = log.split_once("update: boot state Trial").map(|(_, after)| after);
    let new_image = new_image.unwrap_or_else(|| panic!("the new image did not start on trial:\n{log}"));
    assert!(new_image.contains(&format!("no DHCP lease after {DHCP_TIMEOUT_S} s")), "{log}");
    assert!(new_image.contains("update: this image is confirmed"), "{log}");
    assert!(!log.contains("RolledBack"), "{log}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// What a reset of the new image looked like: when, the bootloader's
/// lines, and the firmware's lines about the update and DHCP.
fn reset_report(qemu: &Qemu, started: Instant) -> String {
    let log = qemu.log();
    let lines: Vec<&str> = log.lines().filter(|l| l.contains("update:") || l.contains("DHCP")).collect();
    format!(
        "the new image was reset (seen {:.1} s after its start) before it confirmed itself and stayed\n\
         bootloader:\n{}firmware:\n{}",
        started.elapsed().as_secs_f64(),
        bootloader_output(&qemu.stderr()),
        lines.join("\n")
    )
}
