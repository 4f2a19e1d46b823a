//! The page's firmware update as a person uses it: Debian's chromium,
//! driven by playwright-core (tests/browser/update.js), on the page of the
//! mps2-an386 image with `update` in QEMU (slirp, 127.0.0.1), under its
//! bootloader. A forged file, another board's and one cut short are
//! refused and the page says why; the signed
//! file of the next version is sent with its progress shown and taken; the
//! device restarts into it and the page shows it running, the old version
//! as the previous. This test checks the device behind the page again:
//! the API, Modbus (tokio-modbus), the boot state.
//!
//! Needs what tests/tests/qemu_update.rs needs, the second image
//! ([`qemu::UPDATE_NEXT_BUILD_COMMAND`]), node, chromium and `npm ci` in
//! tests/browser (scripts/setup installs them); fails loudly without any.
//! Screenshots: target/artifacts/update.png, update-failure.png.

use std::process::Stdio;

use serde_json::Value;
use system_tests::browser::{BROWSER_TIMEOUT, browser_dir, fresh_artifacts, require_browser, run_within, summary};
use system_tests::qemu::{self, BOOTLOADER_STATE, NO_ROBOT, Qemu, ROBOT_REGISTERS};
use system_tests::update::{BOOT_MAGIC, api_status, installed_state, signed, signed_for, state_word, test_dir};
use tokio_modbus::client::Reader as _;

#[test]
fn the_page_uploads_an_update_with_its_progress_and_shows_the_new_version() {
    require_browser();
    let (bootloader, image) = qemu::update_images();
    let (next, new_version) = qemu::update_next_image();
    let old_version = qemu::firmware_version().map(|n| n.to_string()).join(".");
    let dir = test_dir("page-update");
    let state = installed_state(&dir, &image);
    let payload = qemu::flat_binary(&next);
    let good = signed(&dir, &payload, &new_version);
    // The files the page must refuse, each with the word its reason must
    // hold: a byte changed, another board's, and one cut short.
    let mut forged = good.clone();
    let middle = forged.len() / 2;
    forged[middle] ^= 0x10;
    let other_board = signed_for(&dir, &payload, &new_version, "nucleo-f429zi");
    let cut_off = good[..good.len() - 1000].to_vec();
    let good_path = dir.join("next.update");
    std::fs::write(&good_path, &good).unwrap();
    let mut refused = Vec::new();
    for (name, file, word) in [
        ("forged", &forged, "signature"),
        ("other-board", &other_board, "another board"),
        ("cut-off", &cut_off, "cut off"),
    ] {
        let path = dir.join(format!("{name}.update"));
        std::fs::write(&path, file).unwrap();
        refused.push(format!("{}={word}", path.display()));
    }

    let qemu = Qemu::slirp_booting(&bootloader, &image, &state);
    qemu.wait_for_log("Modbus TCP server at", qemu::READY_TIMEOUT);
    let artifacts = fresh_artifacts(&["update.png", "update-failure.png"]);
    let mut node = std::process::Command::new("node");
    node.current_dir(browser_dir())
        .arg("update.js")
        .arg(format!("http://{}/", qemu.http_addr()))
        .arg(&artifacts)
        .arg(&good_path)
        .arg(&old_version)
        .arg(&new_version)
        .args(&refused)
        .stdin(Stdio::null());
    let (passed, stdout, stderr) = run_within(node, BROWSER_TIMEOUT);
    assert!(
        passed,
        "the update through the page failed (screenshot: {}):\n{stderr}\n{stdout}\nQEMU: {}",
        artifacts.join("update-failure.png").display(),
        qemu.stderr()
    );
    let summary = summary(&stdout);
    let reasons = summary["refused"].as_array().expect("the refusals seen");
    assert_eq!(reasons.len(), 3, "{summary}");
    for (reason, word) in reasons.iter().zip(["signature", "another board", "cut off"]) {
        assert!(reason.as_str().is_some_and(|m| m.starts_with("Not updated") && m.contains(word)), "{summary}");
    }
    let progress: Vec<f64> = summary["progress"].as_array().unwrap().iter().filter_map(Value::as_f64).collect();
    assert!(progress.iter().filter(|&&v| v > 0.0 && v < 1.0).count() >= 2, "progress shown in steps: {progress:?}");
    assert_eq!(summary["after"]["Previous"], old_version.as_str(), "{summary}");
    assert_eq!(summary["page_errors"], serde_json::json!([]));

    // The device behind the page: the new version runs, confirmed, and serves.
    assert_eq!(state_word(&state, BOOTLOADER_STATE), BOOT_MAGIC, "the new image has not confirmed itself");
    let registers = qemu.run(|| async { qemu.connect().await.read_holding_registers(ROBOT_REGISTERS, 4).await });
    assert_eq!(registers.unwrap().unwrap(), NO_ROBOT);
    let status = api_status(qemu.http_addr(), std::time::Duration::from_secs(20)).expect("the API answers");
    assert_eq!(status["device"]["firmware"], new_version.as_str(), "{status}");
    assert_eq!(status["update"]["previous"], old_version.as_str(), "{status}");
    let png = std::fs::read(artifacts.join("update.png")).expect("update.png");
    assert!(png.starts_with(b"\x89PNG\r\n\x1a\n"), "update.png is a screenshot");
    qemu.power_cut();
    std::fs::remove_dir_all(&dir).unwrap();
}
