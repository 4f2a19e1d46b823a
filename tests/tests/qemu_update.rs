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
//! The HTTP upload, which will arm updates through adapter::update, is not
//! there yet; its checks are adapter::update's unit tests.

use std::os::unix::fs::FileExt as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use system_tests::qemu::{self, ACTIVE, BOOTLOADER_STATE, DFU, NO_ROBOT, PSRAM, Qemu, ROBOT_REGISTERS};
use tokio_modbus::client::Reader as _;

/// embassy-boot's magic words in the boot state's first word.
const SWAP_MAGIC: [u8; 4] = [0xf0; 4];
const BOOT_MAGIC: [u8; 4] = [0xd0; 4];

fn test_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("mbqemu-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn state_word(state: &Path, address: u32) -> [u8; 4] {
    let mut word = [0u8; 4];
    std::fs::File::open(state).unwrap().read_exact_at(&mut word, u64::from(address - PSRAM)).unwrap();
    word
}

/// QEMU's stderr without QEMU's own messages, which may land in the middle
/// of a line of the bootloader's (`qemu-system-arm: Slirp: Failed to send
/// packet` when a reboot drops a connection).
fn bootloader_output(stderr: &str) -> String {
    let mut rest = stderr;
    let mut output = String::new();
    while let Some(at) = rest.find("qemu-system-arm: ") {
        output.push_str(&rest[..at]);
        rest = rest[at..].split_once('\n').map_or("", |(_, after)| after);
    }
    output.push_str(rest);
    output
}

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

/// The image's flat binary for ACTIVE: its loadable segments at their
/// offsets from ACTIVE, gaps erased (what `llvm-objcopy -O binary` makes).
fn flat_binary(elf: &Path) -> Vec<u8> {
    let bytes = std::fs::read(elf).unwrap();
    let u16_at = |at: usize| u16::from_le_bytes(bytes[at..at + 2].try_into().unwrap());
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    let (table, entry_len, entries) = (u32_at(0x1c) as usize, usize::from(u16_at(0x2a)), usize::from(u16_at(0x2c)));
    let mut flat = Vec::new();
    for header in (0..entries).map(|i| table + i * entry_len) {
        let (kind, offset, address, len) =
            (u32_at(header), u32_at(header + 4) as usize, u32_at(header + 12), u32_at(header + 16) as usize);
        if kind != 1 || len == 0 {
            continue;
        }
        let at = (address - ACTIVE) as usize;
        if flat.len() < at + len {
            flat.resize(at + len, 0xff);
        }
        flat[at..at + len].copy_from_slice(&bytes[offset..offset + len]);
    }
    flat
}

/// `payload` signed for mps2-an386 with the development key, as an update file.
fn signed(dir: &Path, payload: &[u8], version: &str) -> Vec<u8> {
    let bin = dir.join("app.bin");
    let out = dir.join("app.update");
    std::fs::write(&bin, payload).unwrap();
    let root = qemu::workspace();
    let status = Command::new(root.join("scripts/sign-firmware"))
        .arg("--key")
        .arg(root.join("keys/update-dev.key"))
        .args(["--board", "mps2-an386", "--version", version])
        .arg(&bin)
        .arg("-o")
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success(), "sign-firmware failed");
    std::fs::read(out).unwrap()
}

/// `POST /api/firmware` with `file`: the status code and the body.
fn upload(addr: std::net::SocketAddr, file: &[u8]) -> (u16, String) {
    use std::io::{Read as _, Write as _};
    let mut stream = std::net::TcpStream::connect(addr).unwrap();
    stream.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    let head = format!(
        "POST /api/firmware HTTP/1.1\r\nHost: mbio\r\nContent-Type: application/octet-stream\r\n\
         Content-Length: {}\r\n\r\n",
        file.len()
    );
    stream.write_all(head.as_bytes()).unwrap();
    stream.write_all(file).unwrap();
    let mut response = Vec::new();
    if let Err(e) = stream.read_to_end(&mut response) {
        return (0, format!("no response: {e}"));
    }
    let text = String::from_utf8_lossy(&response).into_owned();
    let status = text.get(9..12).and_then(|code| code.parse().ok()).unwrap_or(0);
    let body = text.split_once("\r\n\r\n").map_or(String::new(), |(_, body)| body.to_string());
    (status, body)
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
    let payload = flat_binary(&image);
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

#[test]
fn qemu_messages_are_taken_out_of_the_bootloader_output() {
    let stderr = "mps2-an386-boot: boot state qemu-system-arm: Slirp: Failed to send packet, ret: -1\nSwap\nnext\n";
    assert_eq!(bootloader_output(stderr), "mps2-an386-boot: boot state Swap\nnext\n");
    assert_eq!(bootloader_output("plain\n"), "plain\n");
}
