//! Firmware updates in QEMU: the boot state's words, the bootloader's
//! output, signing an image and uploading it through the API. Shared by the
//! update tests (tests/tests/qemu_update*.rs).

use std::net::SocketAddr;
use std::os::unix::fs::FileExt as _;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use crate::qemu::{self, PSRAM};

/// embassy-boot's magic words in the boot state's first word: an update
/// armed (the bootloader is to swap), and a confirmed image.
pub const SWAP_MAGIC: [u8; 4] = [0xf0; 4];
pub const BOOT_MAGIC: [u8; 4] = [0xd0; 4];

/// A fresh directory of this test process for `name`'s files.
pub fn test_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("mbqemu-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The 4-byte word at `address` (in the PSRAM) of the state file `state`.
pub fn state_word(state: &Path, address: u32) -> [u8; 4] {
    let mut word = [0u8; 4];
    std::fs::File::open(state).unwrap().read_exact_at(&mut word, u64::from(address - PSRAM)).unwrap();
    word
}

/// QEMU's stderr without QEMU's own messages, which may land in the middle
/// of a line of the bootloader's (`qemu-system-arm: Slirp: Failed to send
/// packet` when a reboot drops a connection).
pub fn bootloader_output(stderr: &str) -> String {
    let mut rest = stderr;
    let mut output = String::new();
    while let Some(at) = rest.find("qemu-system-arm: ") {
        output.push_str(&rest[..at]);
        rest = rest[at..].split_once('\n').map_or("", |(_, after)| after);
    }
    output.push_str(rest);
    output
}

/// `payload` signed for mps2-an386 as `version` with the development key,
/// as an update file (`scripts/sign-firmware`; `dir` holds its files).
pub fn signed(dir: &Path, payload: &[u8], version: &str) -> Vec<u8> {
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

/// `POST /api/firmware` with `file`: the status code and the body (status
/// 0 and what went wrong when no response came).
pub fn upload(addr: SocketAddr, file: &[u8]) -> (u16, String) {
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

#[cfg(test)]
mod tests {
    use super::bootloader_output;

    #[test]
    fn qemu_messages_are_taken_out_of_the_bootloader_output() {
        let stderr = "mps2-an386-boot: boot state qemu-system-arm: Slirp: Failed to send packet, ret: -1\nSwap\nnext\n";
        assert_eq!(bootloader_output(stderr), "mps2-an386-boot: boot state Swap\nnext\n");
        assert_eq!(bootloader_output("plain\n"), "plain\n");
    }
}
