//! The board tests (system_tests::board, what `scripts/board-test
//! ADDRESS` runs against a flashed board) against the mps2-an386 image in
//! QEMU as if it were a board: on the TAP of a new network namespace, no
//! DHCP server there, so at its fallback address 198.18.0.2, every check
//! run from inside the namespace, discovery included.
//!
//! Two images, as a board can carry either: the plain one (QEMU boots it
//! directly), and the one with `update` under its bootloader, with an admin
//! password set, where the checks end by uploading the signed file of the
//! `update-next` build (0.99.0) and seeing it run and confirmed.
//!
//! Needs root (the namespace), the images (`scripts/test firmware`),
//! `qemu-system-arm`, curl, python-zeroconf and `defmt-print`.

use std::time::Duration;

use system_tests::OWNER_PASSWORD;
use system_tests::board::{self, Board, Discovery};
use system_tests::netns::DEVICE_IP;
use system_tests::qemu::{self, Qemu};
use system_tests::update::{bootloader_output, installed_state, test_dir};

/// The image has its fallback address (5 s without DHCP).
fn wait_for_address(qemu: &Qemu) {
    qemu.wait_for_log(&format!("Modbus TCP server at {DEVICE_IP}:502"), Duration::from_secs(30));
}

/// The board checks for the image at 198.18.0.2, reached from `qemu`'s
/// namespace; discovery must be checked, not skipped.
fn device(qemu: &Qemu) -> Board<'_> {
    let mut board = Board::new(DEVICE_IP.parse().unwrap());
    board.ns = qemu.ns();
    board.discovery = Discovery::On;
    board
}

#[test]
fn the_board_checks_pass_against_the_image_on_a_tap() {
    let qemu = Qemu::tap();
    wait_for_address(&qemu);
    let skipped = device(&qemu).check_all();
    assert_eq!(skipped, [("update", "no update file given (--update FILE)".to_owned())]);
    qemu.finish();
}

#[test]
fn the_board_checks_and_an_update_pass_against_the_image_under_its_bootloader_on_a_tap() {
    let (bootloader, image) = qemu::update_images();
    let (next, next_version) = qemu::update_next_image();
    let dir = test_dir("board-update");
    let state = installed_state(&dir, &image);
    let file = board::update_file(&dir, &qemu::flat_binary(&next), &next_version);

    let qemu = Qemu::tap_booting(&bootloader, &image, &state);
    wait_for_address(&qemu);
    let mut board = device(&qemu);
    // A device with a password, as one in the field should be: every
    // change the checks make (the upload too) must carry it.
    board.claim(OWNER_PASSWORD);
    board.update = Some(file);
    assert!(board.check_all().is_empty(), "every check ran");

    let stderr = bootloader_output(&qemu.stderr());
    assert!(stderr.contains("mps2-an386-boot: boot state Swap"), "{stderr}");
    let log = qemu.finish();
    assert!(log.contains("update: this image is confirmed"), "{log}");
    std::fs::remove_dir_all(&dir).unwrap();
}
