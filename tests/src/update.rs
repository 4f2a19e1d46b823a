//! Firmware updates in QEMU: the boot state's words, the bootloader's
//! output, signing an image and uploading it through the API. Shared by the
//! update tests (tests/tests/qemu_update*.rs).

use std::net::SocketAddr;
use std::os::unix::fs::FileExt as _;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use crate::qemu::{self, PSRAM};
use crate::{OWNER_AUTHORIZATION, OWNER_PASSWORD};

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

/// A fresh state file in `dir` (erased, as a new device's flash) with
/// `image` installed in ACTIVE, as the QEMU scripts install it.
pub fn installed_state(dir: &Path, image: &Path) -> PathBuf {
    let state = dir.join("psram.state");
    qemu::erased_state(&state).unwrap();
    qemu::install(image, &state, qemu::ACTIVE);
    state
}

/// Writes `bytes` at `address` (in the PSRAM) of the state file `state`.
pub fn write_at(state: &Path, address: u32, bytes: &[u8]) {
    let file = std::fs::OpenOptions::new().write(true).open(state).unwrap();
    file.write_all_at(bytes, u64::from(address - PSRAM)).unwrap();
}

/// Arms the swap to what DFU holds, as `adapter::update` does once an
/// upload is checked: embassy-boot's swap magic in the boot state.
pub fn arm(state: &Path) {
    write_at(state, qemu::BOOTLOADER_STATE, &SWAP_MAGIC);
}

/// The bootloader and its image in QEMU with no network at all (the
/// image's DHCP gets no answer), its stderr in a file: for the tests that
/// only watch the bootloader and the state file.
pub struct Offline {
    child: std::process::Child,
    stderr: PathBuf,
}

impl Offline {
    /// Boots `bootloader` on `state`; QEMU is ended after `limit` at the latest.
    pub fn boot(bootloader: &Path, state: &Path, dir: &Path, limit: Duration) -> Self {
        let stderr = dir.join("qemu.stderr");
        let child = Command::new("timeout")
            .args(["-k", "5", &limit.as_secs().to_string()])
            .args(qemu::qemu_args(bootloader, "none", state))
            .stdin(std::process::Stdio::null())
            .stdout(std::process::Stdio::null())
            .stderr(std::fs::File::create(&stderr).unwrap())
            .spawn()
            .unwrap();
        Self { child, stderr }
    }

    /// The bootloader's output so far.
    pub fn output(&self) -> String {
        bootloader_output(&std::fs::read_to_string(&self.stderr).unwrap_or_default())
    }

    /// How many times the bootloader has started (one line each).
    pub fn boots(&self) -> usize {
        self.output().matches("mps2-an386-boot: boot state").count()
    }

    /// Waits until the bootloader has started `count` times; panics after `timeout`.
    pub fn wait_for_boots(&self, count: usize, timeout: Duration) {
        let deadline = std::time::Instant::now() + timeout;
        while self.boots() < count {
            assert!(std::time::Instant::now() < deadline, "{} boots of {count} after {timeout:?}", self.boots());
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// Whether QEMU still runs.
    pub fn running(&mut self) -> bool {
        self.child.try_wait().unwrap().is_none()
    }

    /// Ends QEMU (SIGTERM, as a power cut the guest does not see coming).
    pub fn stop(mut self) {
        // SAFETY: kill has no memory effects; the pid is our child's
        // (`timeout`, which passes SIGTERM on to QEMU).
        unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
        self.child.wait().unwrap();
    }
}

/// The 4-byte word at `address` (in the PSRAM) of the state file `state`.
pub fn state_word(state: &Path, address: u32) -> [u8; 4] {
    let mut word = [0u8; 4];
    std::fs::File::open(state).unwrap().read_exact_at(&mut word, u64::from(address - PSRAM)).unwrap();
    word
}

/// How many 4-byte words of the boot state's first [`STATE_WATCHED`]
/// bytes are written (not erased): embassy-boot's magic and, during a swap,
/// one word per step done. A swap's steps come in order, so this is how far
/// it has got.
pub fn state_words_written(state: &Path) -> usize {
    let mut words = [0u8; STATE_WATCHED];
    let file = std::fs::File::open(state).unwrap();
    file.read_exact_at(&mut words, u64::from(crate::qemu::BOOTLOADER_STATE - PSRAM)).unwrap();
    words.chunks_exact(4).filter(|word| *word != [0xff; 4]).count()
}

/// The part of the boot state [`state_words_written`] reads: more than a
/// swap of the 512 KiB ACTIVE in 4 KiB pages writes (two words a page).
pub const STATE_WATCHED: usize = 4096;

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

/// A copy of `bootloader` in `dir` whose signature check's table has lost
/// its magic (one byte changed), as a bootloader without the table would
/// be; checks first that the table is where the image looks for it.
pub fn bootloader_without_check(bootloader: &Path, dir: &Path) -> PathBuf {
    use update_image::service::{MAGIC, TABLE_OFFSET};
    // The mps2 bootloader starts at 0x0: its table is at TABLE_OFFSET.
    let table = u32::try_from(TABLE_OFFSET).unwrap();
    let (mut bytes, at) = qemu::elf_offset_of(bootloader, table);
    assert_eq!(bytes[at..at + MAGIC.len()], MAGIC, "the bootloader has no services' table at {table:#x}");
    bytes[at] ^= 0x20;
    let copy = dir.join("mps2-an386-boot-without-check");
    std::fs::write(&copy, bytes).unwrap();
    copy
}

/// `payload` signed for mps2-an386 as `version` with the development key,
/// as an update file (`scripts/sign-firmware`; `dir` holds its files).
pub fn signed(dir: &Path, payload: &[u8], version: &str) -> Vec<u8> {
    signed_for(dir, payload, version, "mps2-an386")
}

/// [`signed`] for `board`.
pub fn signed_for(dir: &Path, payload: &[u8], version: &str, board: &str) -> Vec<u8> {
    let bin = dir.join("app.bin");
    let out = dir.join("app.update");
    std::fs::write(&bin, payload).unwrap();
    let root = qemu::workspace();
    let status = Command::new(root.join("scripts/sign-firmware"))
        .arg("--key")
        .arg(root.join("keys/update-dev.key"))
        .args(["--board", board, "--version", version])
        .arg(&bin)
        .arg("-o")
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success(), "sign-firmware failed");
    std::fs::read(out).unwrap()
}

/// `GET /api/status` as JSON, tried until `timeout` passes (`None`: no
/// answer by then; a body that is not JSON fails the test).
pub fn api_status(addr: SocketAddr, timeout: Duration) -> Option<serde_json::Value> {
    let deadline = std::time::Instant::now() + timeout;
    loop {
        if let Some(body) = get_status(addr) {
            return Some(serde_json::from_str(&body).unwrap_or_else(|e| panic!("/api/status: {e}: {body}")));
        }
        if std::time::Instant::now() >= deadline {
            return None;
        }
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// One `GET /api/status`: the body of a 200.
fn get_status(addr: SocketAddr) -> Option<String> {
    use std::io::{Read as _, Write as _};
    let mut stream = std::net::TcpStream::connect_timeout(&addr, Duration::from_secs(2)).ok()?;
    stream.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    let head = format!("GET /api/status HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n");
    stream.write_all(head.as_bytes()).ok()?;
    let mut response = String::new();
    stream.read_to_string(&mut response).ok()?;
    let (head, body) = response.split_once("\r\n\r\n")?;
    head.starts_with("HTTP/1.1 200").then(|| body.to_owned())
}

/// Sets the device's first admin password, [`OWNER_PASSWORD`], as its
/// owner does first: until one is set a device takes no other change
/// (docs/http-api.md, "The first password"). A device that has one
/// already (a state file the test set it in before) answers 401: fine.
pub fn claim(addr: SocketAddr) {
    let body = format!(r#"{{"password": "{OWNER_PASSWORD}"}}"#);
    let (status, reply) = send(addr, "PUT", "/api/password", "application/json", body.as_bytes(), false);
    assert!(matches!(status, 200 | 401), "the first password: {status} {reply}");
}

/// `POST /api/firmware` with `file`, with the owner's password: the status
/// code and the body (status 0 and what went wrong when no response came).
pub fn upload(addr: SocketAddr, file: &[u8]) -> (u16, String) {
    send(addr, "POST", "/api/firmware", "application/octet-stream", file, true)
}

/// `PUT /api/settings` with the JSON `change` and the owner's password:
/// the status code and the body.
pub fn put_settings(addr: SocketAddr, change: &str) -> (u16, String) {
    send(addr, "PUT", "/api/settings", "application/json", change.as_bytes(), true)
}

/// One request with `body` (and the owner's credentials when `owner`),
/// answered and closed by the device: the status code and the response's
/// body (status 0 and what went wrong when no response came).
fn send(addr: SocketAddr, method: &str, path: &str, content_type: &str, body: &[u8], owner: bool) -> (u16, String) {
    use std::io::{Read as _, Write as _};
    let mut stream = std::net::TcpStream::connect(addr).unwrap();
    stream.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    let credentials = if owner { format!("{OWNER_AUTHORIZATION}\r\n") } else { String::new() };
    let head = format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nContent-Type: {content_type}\r\n{credentials}Content-Length: {}\r\n\r\n",
        body.len()
    );
    stream.write_all(head.as_bytes()).unwrap();
    stream.write_all(body).unwrap();
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
