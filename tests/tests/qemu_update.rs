//! The mps2-an386 bootloader and the image with the `update` feature in
//! QEMU: the bootloader (QEMU's kernel) starts the image from the ACTIVE
//! partition of the PSRAM's state file and it answers Modbus; an update
//! armed in DFU the way `adapter::update` arms one (the image in DFU, the
//! swap magic in the boot state) is swapped in, and the new image confirms
//! itself once it serves, or is rolled back at the next boot when it has
//! not; an empty ACTIVE is refused, not jumped into.
//!
//! Needs the bootloader and the image with `update`
//! (`qemu::UPDATE_BUILD_COMMAND`), `qemu-system-arm` and `defmt-print`.
//! The last test uploads a signed file through the API, as a user would.

use std::os::unix::fs::FileExt as _;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use system_tests::qemu::{self, ACTIVE, BOOTLOADER_STATE, DFU, NO_ROBOT, PSRAM, Qemu, ROBOT_REGISTERS};
use system_tests::update::{BOOT_MAGIC, SWAP_MAGIC, bootloader_output, signed, state_word, test_dir, upload};
use tokio_modbus::client::Reader as _;

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
    let state = dir.join("psram.state");
    qemu::erased_state(&state).unwrap();

    // First boot: the image as the QEMU scripts install it, in ACTIVE.
    qemu::install(&image, &state, ACTIVE);
    let stderr = boot_and_read(&bootloader, &image, &state, "update: boot state Confirmed");
    assert!(stderr.contains("mps2-an386-boot: boot state Boot"), "{stderr}");

    // An update armed as adapter::update arms one, with ACTIVE erased so
    // that only the swap can bring an image there.
    let file = std::fs::OpenOptions::new().write(true).open(&state).unwrap();
    file.write_all_at(&vec![0xff; qemu::ACTIVE_LEN as usize], u64::from(ACTIVE - PSRAM)).unwrap();
    qemu::install(&image, &state, DFU);
    file.write_all_at(&SWAP_MAGIC, u64::from(BOOTLOADER_STATE - PSRAM)).unwrap();
    drop(file);
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
    let state = dir.join("psram.state");
    qemu::erased_state(&state).unwrap();
    qemu::install(&image, &state, ACTIVE);
    qemu::install(&image, &state, DFU);
    let file = std::fs::OpenOptions::new().write(true).open(&state).unwrap();
    file.write_all_at(&SWAP_MAGIC, u64::from(BOOTLOADER_STATE - PSRAM)).unwrap();
    drop(file);

    // No network: the image waits 5 s for DHCP before its fallback address,
    // so it cannot confirm before QEMU is stopped half a second after the swap.
    let stderr_path = dir.join("qemu.stderr");
    let mut qemu = Command::new("timeout")
        .args(["-k", "5", "60"])
        .args(qemu::qemu_args(&bootloader, "none", &state))
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&stderr_path).unwrap())
        .spawn()
        .unwrap();
    let deadline = std::time::Instant::now() + Duration::from_secs(20);
    while !bootloader_output(&std::fs::read_to_string(&stderr_path).unwrap()).contains("boot state Swap") {
        assert!(std::time::Instant::now() < deadline, "the bootloader did not swap");
        std::thread::sleep(Duration::from_millis(10));
    }
    std::thread::sleep(Duration::from_millis(500));
    // SAFETY: kill has no memory effects; the pid is our child's (`timeout`,
    // which passes SIGTERM on to QEMU).
    unsafe { libc::kill(qemu.id() as i32, libc::SIGTERM) };
    qemu.wait().unwrap();
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
    let dir = test_dir("update-upload");
    let state = dir.join("psram.state");
    qemu::erased_state(&state).unwrap();
    qemu::install(&image, &state, ACTIVE);
    let payload = qemu::flat_binary(&image);
    let file = signed(&dir, &payload, "0.1.0");
    let mut forged = file.clone();
    let last = forged.len() - 1;
    forged[last] ^= 0x01;

    let qemu = Qemu::slirp_booting(&bootloader, &image, &state);
    qemu.wait_for_log("update: boot state Confirmed", Duration::from_secs(30));
    // The network in place (a connection made before DHCP's address is
    // reset when it comes).
    qemu.wait_for_log("Modbus TCP server at", Duration::from_secs(30));
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
    qemu.finish();
    std::fs::remove_dir_all(&dir).unwrap();
}
