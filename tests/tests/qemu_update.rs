//! The mps2-an386 bootloader and the image with the `update` feature in
//! QEMU: the bootloader (QEMU's kernel) starts the image from the ACTIVE
//! partition of the PSRAM's state file and it answers Modbus; an update
//! armed in DFU the way `adapter::update` arms one (the image in DFU, the
//! swap magic in the boot state) is swapped in, and the new image confirms
//! itself once it serves, or is rolled back at the next boot when it has
//! not; an empty ACTIVE is refused, not jumped into; an image that hangs
//! on trial is reset by the watchdog and rolled back.
//!
//! Needs the bootloader and the image with `update`
//! (`qemu::UPDATE_BUILD_COMMAND`), the second image
//! (`qemu::UPDATE_NEXT_BUILD_COMMAND`), `qemu-system-arm` and `defmt-print`.
//! One test uploads a signed file of another version through the API, as a
//! user would, and reads the versions in 0x2B and the status; another does
//! the same under a bootloader whose signature check is gone, and the image
//! refuses it.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::json;
use system_tests::qemu::{self, ACTIVE, BOOTLOADER_STATE, DFU, NO_ROBOT, Qemu, ROBOT_REGISTERS};
use system_tests::update::{
    BOOT_MAGIC, Offline, SWAP_MAGIC, api_status, arm, bootloader_output, bootloader_without_check, claim,
    installed_state, put_settings, signed, state_word, test_dir, upload, write_at,
};
use tokio_modbus::client::Reader as _;
use tokio_modbus::prelude::{ConformityLevel, ReadCode};

/// Boots, reads registers 256-259 (the image's answer), quits; QEMU's stderr.
fn boot_and_read(bootloader: &Path, image: &Path, state: &Path, wait_for: &str) -> String {
    let qemu = Qemu::slirp_booting(bootloader, image, state);
    let registers = qemu.run(|| async {
        let mut ctx = qemu.connect().await;
        ctx.read_holding_registers(ROBOT_REGISTERS, 4).await.unwrap().unwrap()
    });
    assert_eq!(registers, NO_ROBOT);
    qemu.wait_for_log(wait_for, Duration::from_secs(30));
    let stderr = bootloader_output(&qemu.stderr());
    qemu.finish();
    stderr
}

#[test]
fn the_bootloader_starts_the_image_and_swaps_in_an_armed_update() {
    let (bootloader, image) = qemu::update_images();
    let dir = test_dir("update");
    // First boot: the image as the QEMU scripts install it, in ACTIVE.
    let state = installed_state(&dir, &image);
    let stderr = boot_and_read(&bootloader, &image, &state, "update: boot state Confirmed");
    assert!(stderr.contains("mps2-an386-boot: boot state Boot"), "{stderr}");

    // An update armed as adapter::update arms one, with ACTIVE erased so
    // that only the swap can bring an image there.
    write_at(&state, ACTIVE, &vec![0xff; qemu::ACTIVE_LEN as usize]);
    qemu::install(&image, &state, DFU);
    arm(&state);
    let stderr = boot_and_read(&bootloader, &image, &state, "update: this image is confirmed");
    assert!(stderr.contains("mps2-an386-boot: boot state Swap"), "{stderr}");
    assert_eq!(state_word(&state, BOOTLOADER_STATE), BOOT_MAGIC, "the confirmation is not in the boot state");

    // Confirmed: the next boot keeps it.
    let stderr = boot_and_read(&bootloader, &image, &state, "update: boot state Confirmed");
    assert!(stderr.contains("mps2-an386-boot: boot state Boot"), "{stderr}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_bootloader_does_not_jump_into_an_empty_active() {
    let (bootloader, _) = qemu::update_images();
    let dir = test_dir("update-empty");
    let state = dir.join("psram.state");
    qemu::erased_state(&state).unwrap();
    let output = Command::new("timeout")
        .args(["-k", "5", "60"])
        .args(qemu::qemu_args(&bootloader, "none", &state))
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(104), "{stderr}");
    assert!(stderr.contains("no image in ACTIVE"), "{stderr}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// An update that never confirms itself is rolled back: QEMU is stopped
/// while the swapped-in image is still without an address, so before it
/// can confirm (the reset the watchdog will make); at the next boot the
/// bootloader reverts, and the image that runs says it was rolled back.
#[test]
fn an_update_that_does_not_confirm_is_rolled_back() {
    let (bootloader, image) = qemu::update_images();
    let dir = test_dir("update-rollback");
    let state = installed_state(&dir, &image);
    qemu::install(&image, &state, DFU);
    arm(&state);

    // No network: the image waits 5 s for DHCP before its fallback address,
    // so it cannot confirm before QEMU is stopped half a second after the swap.
    let qemu = Offline::boot(&bootloader, &state, &dir, Duration::from_secs(60));
    qemu.wait_for_boots(1, Duration::from_secs(20));
    assert!(qemu.output().contains("boot state Swap"), "the bootloader did not swap: {}", qemu.output());
    std::thread::sleep(Duration::from_millis(500));
    qemu.stop();
    assert_eq!(state_word(&state, BOOTLOADER_STATE), SWAP_MAGIC, "confirmed before the power cut");

    // The next boot reverts; the image that runs knows it.
    let stderr = boot_and_read(&bootloader, &image, &state, "update: boot state RolledBack");
    assert!(stderr.contains("mps2-an386-boot: boot state Swap"), "{stderr}");
    assert_eq!(state_word(&state, BOOTLOADER_STATE), [0xc0; 4], "no REVERT magic in the boot state");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The whole path through the API: a badly signed file is refused and
/// nothing is armed; a good one is taken (202), the device reboots, the
/// bootloader swaps it in and the new image confirms itself once it serves.
#[test]
fn an_update_uploaded_through_the_api_is_checked_swapped_in_and_confirmed() {
    let (bootloader, image) = qemu::update_images();
    let (next, next_version) = qemu::update_next_image();
    let old_version = qemu::firmware_version().map(|n| n.to_string()).join(".");
    let dir = test_dir("update-upload");
    let state = installed_state(&dir, &image);
    let file = signed(&dir, &qemu::flat_binary(&next), &next_version);
    let mut forged = file.clone();
    let last = forged.len() - 1;
    forged[last] ^= 0x01;

    let qemu = Qemu::slirp_booting(&bootloader, &image, &state);
    qemu.wait_for_log("update: boot state Confirmed", Duration::from_secs(30));
    // The network in place (a connection made before DHCP's address is
    // reset when it comes).
    qemu.wait_for_log("Modbus TCP server at", Duration::from_secs(30));
    let status = api_status(qemu.http_addr(), Duration::from_secs(20)).expect("the API answers");
    assert_eq!(status["device"]["firmware"], old_version.as_str());
    let capacity = status["update"]["capacity"].as_u64().expect("the update's capacity");
    assert!(capacity > file.len() as u64, "{status}");
    assert_eq!(
        status["update"],
        json!({"state": "confirmed", "previous": null, "capacity": capacity}),
        "never updated"
    );
    claim(qemu.http_addr());
    let (status, body) = upload(qemu.http_addr(), &forged);
    assert_eq!(status, 400, "{body}");
    assert!(body.contains("signature"), "{body}");
    assert_ne!(state_word(&state, BOOTLOADER_STATE), SWAP_MAGIC, "a forged image armed");

    let (status, body) = upload(qemu.http_addr(), &file);
    assert_eq!(status, 202, "{body}\n{}", qemu.log());
    assert!(body.contains("\"rebooting\":true"), "{body}");
    // The reboot: the bootloader swaps, the image confirms once it serves.
    qemu.wait_for_log("update: this image is confirmed", Duration::from_secs(60));
    let stderr = bootloader_output(&qemu.stderr());
    assert!(stderr.contains("mps2-an386-boot: boot state Swap"), "{stderr}");
    assert_eq!(state_word(&state, BOOTLOADER_STATE), BOOT_MAGIC, "the confirmation is not in the boot state");
    // A connection made while the new image's network comes up may be
    // reset under it: a few tries.
    let registers = qemu.run(|| async {
        for _ in 0..10 {
            let mut ctx = qemu.connect().await;
            match ctx.read_holding_registers(ROBOT_REGISTERS, 4).await {
                Ok(Ok(registers)) => return registers,
                other => eprintln!("read after the swap: {other:?}; again"),
            }
            tokio::time::sleep(Duration::from_millis(500)).await;
        }
        panic!("the new image does not answer Modbus");
    });
    assert_eq!(registers, NO_ROBOT, "the new image serves Modbus");
    // The new version runs, and the old one is the previous: in 0x2B, as
    // tokio-modbus reads it (the extended stream), and in the status.
    let objects = qemu.run(|| async {
        let reply = qemu.connect().await.read_device_identification(ReadCode::Extended, 0).await.unwrap().unwrap();
        assert_eq!(reply.conformity_level, ConformityLevel::ExtendedIdentification, "0x83");
        reply.device_id_objects.iter().map(|o| (o.id, o.value_as_str().expect("ASCII").to_owned())).collect::<Vec<_>>()
    });
    let ids: Vec<u8> = objects.iter().map(|(id, _)| *id).collect();
    assert_eq!(ids, [0, 1, 2, 3, 4, 5, 6, 0x80], "{objects:?}");
    assert_eq!(objects[2].1, next_version, "MajorMinorRevision: the new version");
    assert_eq!(objects[7].1, old_version, "the private object 0x80: the previous version");
    let status = api_status(qemu.http_addr(), Duration::from_secs(20)).expect("the API answers");
    assert_eq!(status["device"]["firmware"], next_version.as_str());
    assert_eq!(status["update"], json!({"state": "confirmed", "previous": old_version, "capacity": capacity}));
    qemu.finish();
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The image checks signatures with its bootloader's check
/// (`update_image::service`). Under a bootloader without one (here the
/// real one with its table's magic changed) it must take no update at
/// all: the signed file of the next version is refused with 501, nothing
/// is armed, and the image runs and serves on as before.
#[test]
fn without_the_bootloaders_signature_check_no_update_is_taken() {
    let (bootloader, image) = qemu::update_images();
    let (next, next_version) = qemu::update_next_image();
    let old_version = qemu::firmware_version().map(|n| n.to_string()).join(".");
    let dir = test_dir("update-no-check");
    let without = bootloader_without_check(&bootloader, &dir);
    let state = installed_state(&dir, &image);
    let file = signed(&dir, &qemu::flat_binary(&next), &next_version);

    let qemu = Qemu::slirp_booting(&without, &image, &state);
    qemu.wait_for_log("update: boot state Confirmed", Duration::from_secs(30));
    qemu.wait_for_log("Modbus TCP server at", Duration::from_secs(30));
    claim(qemu.http_addr());
    let (status, body) = upload(qemu.http_addr(), &file);
    assert_eq!(status, 501, "{body}\n{}", qemu.log());
    assert!(body.contains("takes no updates"), "{body}");
    assert!(qemu.log().contains("update: refused: Unsupported"), "{}", qemu.log());
    assert_ne!(state_word(&state, BOOTLOADER_STATE), SWAP_MAGIC, "armed without a signature check");
    let status = api_status(qemu.http_addr(), Duration::from_secs(20)).expect("the API answers");
    assert_eq!(status["device"]["firmware"], old_version.as_str());
    assert_eq!(status["update"]["state"], "confirmed", "{status}");
    let registers = qemu.run(|| async {
        let mut ctx = qemu.connect().await;
        ctx.read_holding_registers(ROBOT_REGISTERS, 4).await.unwrap().unwrap()
    });
    assert_eq!(registers, NO_ROBOT, "the image serves on");
    qemu.finish();
    std::fs::remove_dir_all(&dir).unwrap();
}

/// An image that hangs: a vector table whose reset and NMI vectors point at
/// `b .` (a branch to itself), and nothing else. The bootloader starts it;
/// it never pets the watchdog nor confirms itself.
fn hung_image() -> Vec<u8> {
    const STACK_TOP: u32 = 0x2000_1000;
    const LOOP_OFFSET: u32 = 0x40;
    let branch_to_self = (ACTIVE + LOOP_OFFSET) | 1; // Thumb
    let mut image = Vec::new();
    for word in [STACK_TOP, branch_to_self, branch_to_self, branch_to_self] {
        image.extend(word.to_le_bytes());
    }
    image.resize(LOOP_OFFSET as usize, 0);
    image.extend([0xfe, 0xe7, 0xfe, 0xe7]); // b . ; b .
    image
}

/// docs/update.md: an image swapped in that does not confirm itself
/// within 30 s is reset by the watchdog the bootloader started, and the
/// bootloader rolls back; the old image, confirmed, pets the watchdog and
/// keeps running past the limit.
#[test]
fn a_swapped_in_image_that_hangs_is_reset_by_the_watchdog_and_rolled_back() {
    let (bootloader, image) = qemu::update_images();
    let old_version = qemu::firmware_version().map(|n| n.to_string()).join(".");
    let dir = test_dir("update-watchdog");
    let state = installed_state(&dir, &image);
    write_at(&state, DFU, &hung_image());
    arm(&state);

    let qemu = Qemu::slirp_booting(&bootloader, &image, &state);
    let boots = || bootloader_output(&qemu.stderr()).matches("mps2-an386-boot: boot state").count();
    let deadline = Instant::now() + Duration::from_secs(20);
    while boots() == 0 {
        assert!(Instant::now() < deadline, "the bootloader did not start");
        std::thread::sleep(Duration::from_millis(50));
    }
    let swapped = Instant::now();
    // The hung image runs until the watchdog's second expiry.
    let deadline = swapped + Duration::from_secs(60);
    while boots() < 2 {
        assert!(Instant::now() < deadline, "no reset within 60 s of the swap\n{}", qemu.stderr());
        std::thread::sleep(Duration::from_millis(100));
    }
    let reset_after = swapped.elapsed();
    eprintln!("watchdog: the hung image was reset {:.1} s after the swap", reset_after.as_secs_f64());
    assert!(reset_after > Duration::from_secs(20), "reset after {reset_after:?}: not the watchdog's 30 s");
    let stderr = bootloader_output(&qemu.stderr());
    assert!(stderr.contains("mps2-an386-boot: boot state Swap\nmps2-an386-boot: boot state Swap"), "{stderr}");

    // Rolled back: the old image runs and knows it; the status says so.
    qemu.wait_for_log("update: boot state RolledBack", Duration::from_secs(30));
    let rolled_back = Instant::now();
    let status = api_status(qemu.http_addr(), Duration::from_secs(30)).expect("the API answers");
    assert_eq!(status["device"]["firmware"], old_version.as_str());
    assert_eq!(status["update"]["state"], "rolled_back", "{status}");
    assert_eq!(status["update"]["previous"], serde_json::Value::Null, "the hung image has no record: {status}");
    // The old image pets the watchdog: still the same boot 40 s on, serving.
    std::thread::sleep(Duration::from_secs(40).saturating_sub(rolled_back.elapsed()));
    let registers = qemu.run(|| async {
        let mut ctx = qemu.connect().await;
        ctx.read_holding_registers(ROBOT_REGISTERS, 4).await.unwrap().unwrap()
    });
    assert_eq!(registers, NO_ROBOT);
    assert_eq!(boots(), 2, "a reset after the rollback\n{}", qemu.stderr());
    qemu.finish();
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The other side of the watchdog: an image on trial that is slow to
/// confirm itself, after the watchdog's first expiry (the NMI at 15 s) but
/// before its second (the reset at 30 s), is kept: the NMI does not stop
/// it, and the confirmation pets the watchdog. The image is made slow by
/// its saved settings (20 s of DHCP before the fallback address) and no
/// network; it confirms once it has the fallback.
#[test]
fn an_update_that_confirms_after_the_first_expiry_is_kept() {
    let (bootloader, image) = qemu::update_images();
    let dir = test_dir("update-late");
    let state = installed_state(&dir, &image);
    let qemu = Qemu::slirp_booting(&bootloader, &image, &state);
    qemu.wait_for_log("Modbus TCP server at", Duration::from_secs(30));
    claim(qemu.http_addr());
    let (status, body) = put_settings(qemu.http_addr(), r#"{"network": {"dhcp_timeout_s": 20}}"#);
    assert_eq!(status, 200, "{body}");
    qemu.finish();
    qemu::install(&image, &state, DFU);
    arm(&state);

    let mut qemu = Offline::boot(&bootloader, &state, &dir, Duration::from_secs(120));
    qemu.wait_for_boots(1, Duration::from_secs(20));
    let swapped = Instant::now();
    while state_word(&state, BOOTLOADER_STATE) != BOOT_MAGIC {
        assert!(swapped.elapsed() < Duration::from_secs(30), "not confirmed within 30 s of the swap");
        std::thread::sleep(Duration::from_millis(50));
    }
    let confirmed = swapped.elapsed();
    eprintln!("late confirmation: {:.1} s after the swap", confirmed.as_secs_f64());
    assert!(
        confirmed > Duration::from_secs(15),
        "confirmed {confirmed:?} after the swap: before the NMI, nothing shown"
    );
    // Past the second expiry and more: the same boot, still running.
    std::thread::sleep(Duration::from_secs(45).saturating_sub(swapped.elapsed()));
    assert!(qemu.running(), "QEMU ended");
    assert_eq!(qemu.boots(), 1, "a reset after the late confirmation\n{}", qemu.output());
    qemu.stop();
    std::fs::remove_dir_all(&dir).unwrap();
}
