//! The system tests against a device at an address: a flashed board
//! (NUCLEO-F429ZI), or anything else that serves the adapter's Modbus map
//! and HTTP API. Run them with
//!
//!     scripts/board-test ADDRESS [options]        # scripts/board-test --help
//!
//! which sets the variables of `system_tests::board::Board::from_env`
//! (`BOARD_ADDR`, ...) and runs this target's ignored tests. Without a
//! device they are ignored, and cargo lists each as ignored with the
//! reason: a plain `cargo test` never passes them silently. Run with
//! `--ignored` but without `BOARD_ADDR`, each fails saying so.
//!
//! One test at a time: they share one device (a lock), and the update
//! reboots it. tests/tests/qemu_board.rs runs the same checks in CI,
//! against the QEMU image on a TAP.

use std::sync::{Mutex, MutexGuard, PoisonError};

use system_tests::board::{ADDR_ENV, Board, Checked};

/// The device, for one test at a time.
fn device() -> (MutexGuard<'static, ()>, Board<'static>) {
    static DEVICE: Mutex<()> = Mutex::new(());
    let guard = DEVICE.lock().unwrap_or_else(PoisonError::into_inner);
    let board = Board::from_env()
        .unwrap_or_else(|| panic!("{ADDR_ENV} is not set: these tests need a device; run scripts/board-test ADDRESS"));
    (guard, board)
}

/// Prints loudly what a check could not check; it does not fail.
fn report(check: &str, checked: Checked) {
    if let Checked::Skipped(why) = checked {
        eprintln!("board: {check}: SKIPPED, NOT CHECKED: {why}");
    }
}

#[test]
#[ignore = "needs a device: scripts/board-test ADDRESS"]
fn status_settings_and_the_page_have_their_shape() {
    let (_device, board) = device();
    board.check_api();
}

#[test]
#[ignore = "needs a device: scripts/board-test ADDRESS"]
fn the_device_identifies_itself_as_its_status_says() {
    let (_device, board) = device();
    board.check_identification();
}

#[test]
#[ignore = "needs a device: scripts/board-test ADDRESS"]
fn the_whole_map_reads_and_its_views_agree() {
    let (_device, board) = device();
    board.check_map();
}

#[test]
#[ignore = "needs a device: scripts/board-test ADDRESS"]
fn bad_functions_addresses_and_quantities_get_their_exceptions() {
    let (_device, board) = device();
    board.check_exceptions();
}

#[test]
#[ignore = "needs a device: scripts/board-test ADDRESS"]
fn an_output_written_reads_back_and_is_put_back() {
    let (_device, board) = device();
    board.check_output();
}

#[test]
#[ignore = "needs a device: scripts/board-test ADDRESS"]
fn a_foreign_host_origin_or_type_is_refused() {
    let (_device, board) = device();
    board.check_site_rules();
}

#[test]
#[ignore = "needs a device: scripts/board-test ADDRESS"]
fn the_name_answers_over_mdns() {
    let (_device, board) = device();
    report("discovery", board.check_discovery());
}

#[test]
#[ignore = "needs a device: scripts/board-test ADDRESS"]
fn an_uploaded_update_runs_and_is_confirmed() {
    let (_device, board) = device();
    report("update", board.check_update());
}

/// The script's usage and its refusals, which come before it builds or
/// sends anything: exit 0 for --help, 2 for what it cannot take.
#[test]
fn the_script_says_its_usage_and_refuses_bad_arguments() {
    let script = system_tests::qemu::workspace().join("scripts/board-test");
    let run = |args: &[&str]| {
        let output = std::process::Command::new(&script).args(args).env_remove("BOARD_PASSWORD").output().unwrap();
        let text = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
        (output.status.code(), text)
    };
    let (code, help) = run(&["--help"]);
    assert_eq!(code, Some(0), "{help}");
    assert!(help.contains("scripts/board-test ADDRESS [options]") && help.contains("Exit codes"), "{help}");
    for (args, says) in [
        (&[][..], "scripts/board-test ADDRESS"),
        (&["198.18.0"], "198.18.0 is not an IPv4 address"),
        (&["198.18.0.256"], "is not an IPv4 address"),
        (&["198.18.0.2", "--output", "17"], "--output takes a digital output, 1-16"),
        (&["198.18.0.2", "--http-port", "0"], "--http-port takes a port"),
        (&["198.18.0.2", "--mdns", "maybe"], "--mdns takes auto, on or off"),
        (&["198.18.0.2", "--update", "/nonexistent.update"], "no such file"),
        (&["198.18.0.2", "--colour"], "unknown option --colour"),
    ] {
        let (code, output) = run(args);
        assert_eq!(code, Some(2), "{args:?}: {output}");
        assert!(output.contains(says), "{args:?}: {output}");
    }
}
