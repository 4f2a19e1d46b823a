//! Power cuts during firmware updates (docs/update.md): QEMU killed at
//! random moments of an upload and of a swap, [`CUTS`] times each, on one
//! state file that carries on from cut to cut, as a device in the field
//! would. SIGKILL stops the guest between two instructions and the PSRAM's
//! state file keeps what was written before, as flash does.
//!
//! After every cut the device must boot an image, the old or the new one,
//! and answer Modbus (tokio-modbus) and the API (`device.firmware` in `/api/status` says which
//! version runs). The two images are different builds (another version),
//! so an image torn between them would not pass for either.
//!
//! The random moments come from a seed printed at the start; set
//! `POWER_CUT_SEED` to replay a run.
//!
//! Needs what tests/tests/qemu_update.rs needs, and the second image
//! ([`qemu::UPDATE_NEXT_BUILD_COMMAND`]).

use std::io::{Read as _, Write as _};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use system_tests::OWNER_AUTHORIZATION;
use system_tests::qemu::{self, BOOTLOADER_STATE, NO_ROBOT, Qemu, ROBOT_REGISTERS};
use system_tests::update::{
    BOOT_MAGIC, api_status, bootloader_output, claim, installed_state, signed, state_word, state_words_written,
    test_dir, upload,
};
use tokio_modbus::client::Reader as _;

/// Cuts per test (the figure).
const CUTS: usize = 20;
/// How long a booted device may take to serve the API after Modbus.
const API_TIMEOUT: Duration = Duration::from_secs(20);

/// A small xorshift generator: the moments of the cuts, replayable.
struct Moments(u64);

impl Moments {
    fn new(test: &str) -> Self {
        let seed = std::env::var("POWER_CUT_SEED").ok().and_then(|s| s.parse().ok()).unwrap_or_else(|| {
            let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap();
            now.as_nanos() as u64 | 1
        });
        eprintln!("{test}: POWER_CUT_SEED={seed}");
        Self(seed)
    }

    /// A number in `0..bound`.
    fn below(&mut self, bound: u64) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0 % bound.max(1)
    }
}

/// The two images and their update files.
struct Images {
    bootloader: PathBuf,
    /// The running image's ELF file, which decodes the logs.
    elf: PathBuf,
    /// (version, update file) of the two builds.
    files: [(String, Vec<u8>); 2],
}

impl Images {
    fn new(dir: &Path) -> Self {
        let (bootloader, old) = qemu::update_images();
        let (new, new_version) = qemu::update_next_image();
        let old_version = qemu::firmware_version().map(|n| n.to_string()).join(".");
        assert_ne!(old_version, new_version, "the second image must be another version");
        let sign = |elf: &Path, version: &str| {
            let sub = dir.join(version);
            std::fs::create_dir_all(&sub).unwrap();
            signed(&sub, &qemu::flat_binary(elf), version)
        };
        let files = [(old_version.clone(), sign(&old, &old_version)), (new_version.clone(), sign(&new, &new_version))];
        Self { bootloader, elf: old, files }
    }

    /// The update file of the version that is not `running`.
    fn other(&self, running: &str) -> &(String, Vec<u8>) {
        self.files.iter().find(|(version, _)| version != running).unwrap()
    }

    fn is_known(&self, version: &str) -> bool {
        self.files.iter().any(|(known, _)| known == version)
    }
}

/// A fresh state file with the old image installed in ACTIVE.
fn factory_state(dir: &Path) -> PathBuf {
    let (_, old) = qemu::update_images();
    installed_state(dir, &old)
}

/// Boots, waits until the device answers Modbus and the API; the version
/// that runs. Fails when no image serves.
fn boot(images: &Images, state: &Path) -> (Qemu, String) {
    let qemu = Qemu::slirp_booting(&images.bootloader, &images.elf, state);
    let registers = qemu.run(|| async { qemu.connect().await.read_holding_registers(ROBOT_REGISTERS, 4).await });
    let registers =
        registers.unwrap_or_else(|e| panic!("no Modbus answer: {e}\n{}", bootloader_output(&qemu.stderr())));
    assert_eq!(registers.unwrap(), NO_ROBOT);
    let version = running_version(qemu.http_addr())
        .unwrap_or_else(|| panic!("Modbus answers, the API does not\n{}", bootloader_output(&qemu.stderr())));
    assert!(images.is_known(&version), "an image of neither version runs: {version}");
    claim(qemu.http_addr());
    (qemu, version)
}

/// `device.firmware` of `/api/status`, tried until [`API_TIMEOUT`].
fn running_version(addr: SocketAddr) -> Option<String> {
    api_status(addr, API_TIMEOUT)?["device"]["firmware"].as_str().map(str::to_owned)
}

/// Sends the head and the first `len` bytes of `file` as an upload.
fn upload_part(addr: SocketAddr, file: &[u8], len: usize) -> TcpStream {
    let mut stream = TcpStream::connect(addr).unwrap();
    let head = format!(
        "POST /api/firmware HTTP/1.1\r\nHost: {addr}\r\nContent-Type: application/octet-stream\r\n\
         {OWNER_AUTHORIZATION}\r\nContent-Length: {}\r\n\r\n",
        file.len()
    );
    stream.write_all(head.as_bytes()).unwrap();
    // The device may close on a part it refuses; what it took is the point.
    let _ = stream.write_all(&file[..len]);
    stream
}

/// Uploads the other version whole; retried while the running image is on
/// trial (409 until it has confirmed itself).
fn upload_other(images: &Images, qemu: &Qemu, running: &str) -> String {
    let (version, file) = images.other(running);
    for _ in 0..20 {
        let (status, body) = upload(qemu.http_addr(), file);
        match status {
            202 => return version.clone(),
            409 => std::thread::sleep(Duration::from_millis(500)),
            _ => panic!("upload of {version}: {status} {body}"),
        }
    }
    panic!("the device stayed on trial");
}

/// Waits until the image swapped in has confirmed itself (the boot
/// state's BOOT magic): cut before that, the next boot rolls it back.
fn wait_confirmed(qemu: &Qemu, state: &Path) {
    let deadline = Instant::now() + Duration::from_secs(30);
    while state_word(state, BOOTLOADER_STATE) != BOOT_MAGIC {
        assert!(Instant::now() < deadline, "the new image did not confirm itself\n{}", qemu.stderr());
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A whole update, uncut: the upload taken, the swap, the new image
/// confirmed. How long the device takes from the upload's last byte to its
/// answer (the check and the arming), and from the answer to the end of
/// the swap (the reboot and the bootloader's copy); the cuts are drawn
/// within these.
fn calibrate(images: &Images, state: &Path) -> (Qemu, String, Duration, usize) {
    let (qemu, running) = boot(images, state);
    let (next, file) = images.other(&running);
    let mut stream = upload_part(qemu.http_addr(), file, file.len());
    let sent = Instant::now();
    let mut answer = [0u8; 12];
    stream.read_exact(&mut answer).unwrap();
    assert_eq!(&answer[9..], b"202", "the whole upload was not taken");
    let check = sent.elapsed();
    let answered = Instant::now();
    let deadline = answered + Duration::from_secs(30);
    while !bootloader_output(&qemu.stderr()).contains("boot state Swap") {
        assert!(Instant::now() < deadline, "no swap after the upload\n{}", qemu.stderr());
        std::thread::sleep(Duration::from_millis(1));
    }
    let swap = answered.elapsed();
    let steps = state_words_written(state);
    wait_confirmed(&qemu, state);
    qemu.power_cut();
    let (qemu, running) = boot(images, state);
    assert_eq!(&running, next, "the update was not swapped in");
    eprintln!(
        "uncut: the answer {check:?} after the last byte, the swap done {swap:?} after the answer, \
         {steps} words of the boot state written"
    );
    assert!(steps > 2, "the swap wrote no progress into the boot state");
    (qemu, running, check, steps)
}

/// Cuts at random moments of an upload: half of them anywhere in the body
/// (DFU being erased and written), half after the last byte, within the
/// time the check and the arming take and the reboot that follows. Each
/// time the next boot serves: the old image or, if the cut came after the
/// arming, the new one.
#[test]
fn power_cut_at_random_moments_of_an_upload() {
    let dir = test_dir("power-upload");
    let images = Images::new(&dir);
    let state = factory_state(&dir);
    let mut moments = Moments::new("power_cut_at_random_moments_of_an_upload");
    let (mut qemu, mut running, check, _) = calibrate(&images, &state);
    let mut swapped = 0;
    for cut in 0..CUTS {
        let (_, file) = images.other(&running);
        let (sent, wait) = if moments.below(2) == 0 {
            (moments.below(file.len() as u64 + 1) as usize, Duration::ZERO)
        } else {
            (file.len(), Duration::from_micros(moments.below(check.as_micros() as u64 * 3 / 2)))
        };
        let stream = upload_part(qemu.http_addr(), file, sent);
        std::thread::sleep(wait);
        qemu.power_cut();
        drop(stream);
        let before = running.clone();
        (qemu, running) = boot(&images, &state);
        eprintln!("cut {cut}: {sent} of {} bytes sent, cut {wait:?} after; {before} -> {running}", file.len());
        swapped += usize::from(before != running);
        if before != running {
            // Swapped in: let it confirm itself before the next cut.
            wait_confirmed(&qemu, &state);
        }
    }
    // The device is not left unable to update: a whole upload is taken.
    let next = upload_other(&images, &qemu, &running);
    qemu.power_cut();
    let (qemu, running) = boot(&images, &state);
    assert_eq!(running, next, "the last, whole upload was not swapped in");
    qemu.power_cut();
    eprintln!("{CUTS} cuts, {swapped} of them after the arming");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Cuts at random moments of a swap: a whole upload is taken, the device
/// reboots into the bootloader, which swaps page by page and writes a word
/// of progress into the boot state after each step. The test watches those
/// words in the state file and cuts once a number of them drawn at random
/// (up to what a whole swap writes, measured first) is there. Each time the
/// next boot finishes the swap from where it was cut, or rolls it back, and
/// an image serves.
#[test]
fn power_cut_at_random_moments_of_a_swap() {
    let dir = test_dir("power-swap");
    let images = Images::new(&dir);
    let state = factory_state(&dir);
    let mut moments = Moments::new("power_cut_at_random_moments_of_a_swap");
    let (mut qemu, mut running, _, steps) = calibrate(&images, &state);
    let mut outcomes = [0usize; 2];
    for cut in 0..CUTS {
        let next = upload_other(&images, &qemu, &running);
        let target = 1 + moments.below(steps as u64) as usize;
        let deadline = Instant::now() + Duration::from_secs(10);
        while state_words_written(&state) < target && Instant::now() < deadline {
            std::hint::spin_loop();
        }
        qemu.power_cut();
        let written = state_words_written(&state);
        assert!(written >= target, "the swap did not get to step {target}");
        let before = running.clone();
        (qemu, running) = boot(&images, &state);
        eprintln!("cut {cut}: at {written} of {steps} words of progress; {before} -> {running} (armed {next})");
        outcomes[usize::from(running == next)] += 1;
        if running == next {
            wait_confirmed(&qemu, &state);
        }
    }
    qemu.power_cut();
    eprintln!("{CUTS} cuts: {} booted the old image, {} the new one", outcomes[0], outcomes[1]);
    std::fs::remove_dir_all(&dir).unwrap();
}
