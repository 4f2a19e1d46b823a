//! The real firmware image (mps2-an386) in QEMU: boot, reach, inspect, stop.
//!
//! ```no_run
//! use system_tests::qemu::Qemu;
//! let qemu = Qemu::slirp();
//! qemu.run(|| async {
//!     let mut ctx = qemu.connect().await;
//!     // ... tokio-modbus requests ...
//! });
//! assert_eq!(qemu.read_word(system_tests::qemu::LED0) & 1, 0);
//! qemu.finish(); // fails on a panic, a fault or an error in the firmware's log
//! ```
//!
//! - [`Qemu::slirp`]: user networking, free ports of 127.0.0.1 forwarded to
//!   the firmware's port 502 and its HTTP port 80 ([`Qemu::http_addr`];
//!   slirp's DHCP gives the firmware 10.0.2.15).
//! - [`Qemu::tap`]: on the TAP of a new [`Namespace`] (no DHCP there: the
//!   firmware falls back to 198.18.0.2/24 after 5 s).
//! - [`Qemu::slirp_with_state`]: slirp on a state file the test keeps, so a
//!   second boot finds what the first one saved.
//! - [`Qemu::slirp_booting`]: the bootloader as the kernel, starting the
//!   image with the `update` feature from the state file's ACTIVE partition
//!   ([`update_images`], [`install`]); [`Qemu::tap_booting`] the same on a
//!   namespace's TAP.
//!
//! The board's PSRAM (QEMU's machine RAM, 16 MiB at `0x2100_0000`), where
//! the firmware keeps its settings ([`SETTINGS`]), is a state file mapped
//! with `share=on`: the guest's writes land in the file. Unless a test
//! brings its own, each QEMU gets a fresh one in its own directory, erased
//! (0xFF) like new flash ([`erased_state`]).
//!
//! QEMU always runs under `timeout`, writes its output (the firmware's defmt
//! log, over semihosting) to a file rather than a pipe that could stall the
//! firmware, and has a monitor on a unix socket ([`Qemu::read_word`] reads
//! guest memory through it). [`Qemu::log`] decodes the log with `defmt-print`.

use std::fmt::Write as _;

/// The `,mac=` of a QEMU on TAP `tap`: none (QEMU's 52:54:00:12:34:56) on
/// the namespace's own TAP, and one of its own on each TAP of a bridge
/// (`tap1`, `tap2`, ...), as boards on one network have.
fn tap_mac(tap: &str) -> String {
    match tap.strip_prefix("tap").and_then(|n| n.parse::<u8>().ok()) {
        Some(0) | None => String::new(),
        Some(n) => format!(",mac=52:54:00:12:35:{n:02x}"),
    }
}
use std::io::{BufRead as _, Read as _, Write as _};
use std::net::{Ipv4Addr, SocketAddr, TcpListener};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant, SystemTime};

use tokio_modbus::client::Context;

use crate::netns::{DEVICE_IP, Namespace, TAP};

/// Overrides the image under test.
pub const ELF_ENV: &str = "FIRMWARE_MPS2_ELF";
/// How the image is built (the README's test command runs it first).
pub const BUILD_COMMAND: &str = "cargo build -p mps2-an386 --release --target thumbv7em-none-eabihf";
/// `timeout` ends QEMU after this long whatever happens to the test.
pub const QEMU_TIMEOUT: Duration = Duration::from_secs(300);
/// Boot, link and address (DHCP, or its 5 s fallback) within this time.
pub const READY_TIMEOUT: Duration = Duration::from_secs(30);
/// The FPGA IO block's LED0 register: bit n is user LED n (digital output n + 1).
pub const LED0: u32 = 0x4002_8000;
/// The firmware's Modbus port.
pub const MODBUS_PORT: u16 = 502;
/// The firmware's HTTP port (the JSON API).
pub const HTTP_PORT: u16 = 80;
/// Registers 256-259: the robot controller's version and the robot state.
pub const ROBOT_REGISTERS: u16 = 256;
/// What registers 256-259 hold on this image, which has no robot source:
/// controller version 0.0.0, state NOT READY (15).
pub const NO_ROBOT: [u16; 4] = [0, 0, 0, 15];
/// The settings region (`SETTINGS` in firmware/mps2-an386/memory.x): the
/// start of the PSRAM, the state file's first bytes.
pub const SETTINGS: u32 = 0x2100_0000;
/// The settings region's length.
pub const SETTINGS_LEN: usize = 64 * 1024;
/// The state file's length: QEMU's mps2 machine RAM (the PSRAM), which must
/// be exactly 16 MiB.
pub const STATE_LEN: usize = 16 * 1024 * 1024;
/// A QEMU monitor command must answer within this time.
const MONITOR_TIMEOUT: Duration = Duration::from_secs(10);
/// How long `quit` may take.
const QUIT_TIMEOUT: Duration = Duration::from_secs(10);

/// The workspace's root directory.
pub fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The image under test: `FIRMWARE_MPS2_ELF`, or the release build of this
/// workspace, which must exist and be newer than every source it was built
/// from (as listed in cargo's dep-info file next to it).
pub fn image() -> PathBuf {
    if let Some(path) = std::env::var_os(ELF_ENV) {
        let path = PathBuf::from(path);
        assert!(path.is_file(), "{ELF_ENV}={} is not a file", path.display());
        return path;
    }
    let target = match std::env::var_os("CARGO_TARGET_DIR") {
        Some(dir) => PathBuf::from(dir),
        None => workspace().join("target"),
    };
    let path = target.join("thumbv7em-none-eabihf/release/mps2-an386");
    let built = modified(&path).unwrap_or_else(|| {
        panic!(
            "the mps2-an386 image is not built ({} is missing): run `{BUILD_COMMAND}` first, or set {ELF_ENV}",
            path.display()
        )
    });
    let dep_info = std::fs::read_to_string(path.with_extension("d")).unwrap_or_default();
    let manifest = workspace().join("firmware/mps2-an386/Cargo.toml");
    for source in dep_info_sources(&dep_info).into_iter().chain([manifest]) {
        let changed = modified(&source).is_some_and(|time| time > built);
        assert!(
            !changed,
            "the mps2-an386 image is older than {}: run `{BUILD_COMMAND}` again, or set {ELF_ENV}",
            source.display()
        );
    }
    path
}

/// Overrides the bootloader under test.
pub const BOOT_ELF_ENV: &str = "FIRMWARE_MPS2_BOOT_ELF";
/// Overrides the image with the `update` feature under test.
pub const UPDATE_ELF_ENV: &str = "FIRMWARE_MPS2_UPDATE_ELF";
/// How the bootloader and the image with `update` are built: the image in
/// a target directory of its own, so that it does not replace the plain
/// image the other tests run ([`image`]).
pub const UPDATE_BUILD_COMMAND: &str = "cargo build -p mps2-an386-boot --release --target thumbv7em-none-eabihf && \
     CARGO_TARGET_DIR=target/update cargo build -p mps2-an386 --release --target thumbv7em-none-eabihf --features update";
/// The version of the second image with `update`, which the update tests
/// upload over the first ([`update_next_image`]): one no release has.
pub const UPDATE_NEXT_VERSION: &str = "0.99.0";
/// Overrides the second image with `update` under test.
pub const UPDATE_NEXT_ELF_ENV: &str = "FIRMWARE_MPS2_UPDATE_NEXT_ELF";
/// How the second image is built: the image with `update` again, with
/// [`UPDATE_NEXT_VERSION`] for its version (firmware/adapter/build.rs reads
/// `FIRMWARE_VERSION`), in a target directory of its own.
pub const UPDATE_NEXT_BUILD_COMMAND: &str = "FIRMWARE_VERSION=0.99.0 CARGO_TARGET_DIR=target/update-next \
     cargo build -p mps2-an386 --release --target thumbv7em-none-eabihf --features update";
/// The partitions of the image with `update` (firmware/mps2-an386/memory-update.x).
pub const BOOTLOADER_STATE: u32 = 0x2101_0000;
pub const ACTIVE: u32 = 0x2102_0000;
pub const ACTIVE_LEN: u32 = 512 * 1024;
pub const DFU: u32 = 0x210A_0000;
/// The PSRAM's first address: the state file's offset 0.
pub const PSRAM: u32 = 0x2100_0000;

/// The bootloader and the image with the `update` feature: the variables'
/// files, or the builds of [`UPDATE_BUILD_COMMAND`], which must exist and be
/// newer than their sources.
pub fn update_images() -> (PathBuf, PathBuf) {
    let target = std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| workspace().join("target"), PathBuf::from);
    let bootloader = built(
        BOOT_ELF_ENV,
        target.join("thumbv7em-none-eabihf/release/mps2-an386-boot"),
        "firmware/mps2-an386-boot/Cargo.toml",
    );
    let image = built(
        UPDATE_ELF_ENV,
        target.join("update/thumbv7em-none-eabihf/release/mps2-an386"),
        "firmware/mps2-an386/Cargo.toml",
    );
    (bootloader, image)
}

/// The second image with `update` ([`UPDATE_NEXT_BUILD_COMMAND`]: the
/// same sources, version [`UPDATE_NEXT_VERSION`]) and its version: what the
/// update tests upload. Checked as [`update_images`] are.
pub fn update_next_image() -> (PathBuf, String) {
    let target = std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| workspace().join("target"), PathBuf::from);
    let image = built_by(
        UPDATE_NEXT_BUILD_COMMAND,
        UPDATE_NEXT_ELF_ENV,
        target.join("update-next/thumbv7em-none-eabihf/release/mps2-an386"),
        "firmware/mps2-an386/Cargo.toml",
    );
    (image, UPDATE_NEXT_VERSION.to_string())
}

/// The file `env` names, or `path`, built after every source its dep-info lists.
fn built(env: &str, path: PathBuf, manifest: &str) -> PathBuf {
    built_by(UPDATE_BUILD_COMMAND, env, path, manifest)
}

/// The file `env` names, or `path`, which `command` builds, built after
/// every source its dep-info lists.
fn built_by(command: &str, env: &str, path: PathBuf, manifest: &str) -> PathBuf {
    if let Some(path) = std::env::var_os(env) {
        let path = PathBuf::from(path);
        assert!(path.is_file(), "{env}={} is not a file", path.display());
        return path;
    }
    let built =
        modified(&path).unwrap_or_else(|| panic!("{} is missing: run `{command}` first, or set {env}", path.display()));
    let dep_info = std::fs::read_to_string(path.with_extension("d")).unwrap_or_default();
    for source in dep_info_sources(&dep_info).into_iter().chain([workspace().join(manifest)]) {
        let changed = modified(&source).is_some_and(|time| time > built);
        assert!(!changed, "{} is older than {}: run `{command}` again", path.display(), source.display());
    }
    path
}

/// Writes the image `elf` (linked at [`ACTIVE`]) into the state file
/// `state` at the partition starting at `partition` ([`ACTIVE`], or
/// [`DFU`] for an update the bootloader is to swap in): each loadable
/// segment's bytes, at its place relative to ACTIVE's start. What the QEMU
/// scripts do on a fresh state file.
pub fn install(elf: &Path, state: &Path, partition: u32) {
    use std::os::unix::fs::FileExt as _;
    let file = std::fs::OpenOptions::new().write(true).open(state).unwrap();
    for (at, bytes) in active_segments(elf).iter() {
        file.write_all_at(bytes, u64::from(at + partition - PSRAM)).unwrap();
    }
}

/// The image `elf` (linked at [`ACTIVE`]) as one flat binary, what
/// `llvm-objcopy -O binary` makes of it and an update file carries: each
/// loadable segment at its offset from ACTIVE, the gaps erased (0xFF).
pub fn flat_binary(elf: &Path) -> Vec<u8> {
    let segments = active_segments(elf);
    let mut flat = Vec::new();
    for (at, bytes) in segments.iter() {
        let (start, end) = (at as usize, at as usize + bytes.len());
        if flat.len() < end {
            flat.resize(end, 0xff);
        }
        flat[start..end].copy_from_slice(bytes);
    }
    flat
}

/// The loadable segments of a 32-bit ELF file linked into ACTIVE.
struct Segments {
    bytes: Vec<u8>,
    /// Offset from ACTIVE's start, file offset, length.
    segments: Vec<(u32, usize, usize)>,
}

impl Segments {
    /// Each segment's offset from ACTIVE and its bytes.
    fn iter(&self) -> impl Iterator<Item = (u32, &[u8])> {
        self.segments.iter().map(|&(at, offset, len)| (at, &self.bytes[offset..offset + len]))
    }
}

/// Reads `elf`'s program headers; fails on a segment outside ACTIVE or an
/// image with no loadable bytes.
fn active_segments(elf: &Path) -> Segments {
    let bytes = std::fs::read(elf).unwrap_or_else(|e| panic!("{}: {e}", elf.display()));
    let mut segments = Vec::new();
    for (address, offset, len) in load_segments(&bytes, elf) {
        assert!(
            (ACTIVE..ACTIVE + ACTIVE_LEN).contains(&address),
            "a segment of {} loads at {address:#x}, outside ACTIVE",
            elf.display()
        );
        segments.push((address - ACTIVE, offset, len));
    }
    assert!(!segments.is_empty(), "{} has no loadable bytes", elf.display());
    Segments { bytes, segments }
}

/// The loadable segments of the 32-bit ELF file `bytes` (read from
/// `elf`): load (physical) address, file offset and length of each that
/// has bytes.
fn load_segments(bytes: &[u8], elf: &Path) -> Vec<(u32, usize, usize)> {
    const PT_LOAD: u32 = 1;
    let u16_at = |at: usize| u16::from_le_bytes(bytes[at..at + 2].try_into().unwrap());
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    assert_eq!(&bytes[..5], b"\x7fELF\x01", "{} is not a 32-bit ELF file", elf.display());
    let (table, entry_len, entries) = (u32_at(0x1c) as usize, usize::from(u16_at(0x2a)), usize::from(u16_at(0x2c)));
    (0..entries)
        .map(|i| table + i * entry_len)
        .map(|header| (u32_at(header), u32_at(header + 12), u32_at(header + 4) as usize, u32_at(header + 16) as usize))
        .filter(|&(kind, _, _, len)| kind == PT_LOAD && len > 0)
        .map(|(_, address, offset, len)| (address, offset, len))
        .collect()
}

/// Where in the ELF file `elf` the byte that loads at `address` is, and
/// the file's bytes.
pub fn elf_offset_of(elf: &Path, address: u32) -> (Vec<u8>, usize) {
    let bytes = std::fs::read(elf).unwrap_or_else(|e| panic!("{}: {e}", elf.display()));
    let offset = load_segments(&bytes, elf)
        .into_iter()
        .find(|&(start, _, len)| (start..start + len as u32).contains(&address))
        .map(|(start, offset, _)| offset + (address - start) as usize)
        .unwrap_or_else(|| panic!("nothing of {} loads at {address:#x}", elf.display()));
    (bytes, offset)
}

fn modified(path: &Path) -> Option<SystemTime> {
    std::fs::metadata(path).and_then(|m| m.modified()).ok()
}

/// The sources a cargo dep-info file (`target: source source ...`) lists.
fn dep_info_sources(dep_info: &str) -> Vec<PathBuf> {
    let Some((_, sources)) = dep_info.lines().next().and_then(|line| line.split_once(": ")) else {
        return Vec::new();
    };
    let mut paths = Vec::new();
    let mut current = String::new();
    let mut words = sources.split(' ').peekable();
    while let Some(word) = words.next() {
        match word.strip_suffix('\\') {
            // An escaped space: the path goes on.
            Some(part) if words.peek().is_some() => {
                current.push_str(part);
                current.push(' ');
            }
            _ => {
                current.push_str(word);
                if !current.is_empty() {
                    paths.push(PathBuf::from(std::mem::take(&mut current)));
                }
            }
        }
    }
    paths
}

/// The firmware's version (the workspace's), as the image reports it in
/// Read Device Identification (MajorMinorRevision).
pub fn firmware_version() -> [u16; 3] {
    let manifest = std::fs::read_to_string(workspace().join("Cargo.toml")).expect("Cargo.toml");
    let line = manifest.lines().find(|l| l.starts_with("version = ")).expect("a version line");
    let version = line.trim_start_matches("version = ").trim_matches('"');
    let parts: Vec<u16> = version.split('.').map(|p| p.parse().expect("a numeric version")).collect();
    [parts[0], parts[1], parts[2]]
}

/// `defmt-print`, installed with `cargo install defmt-print` if it is missing.
pub fn defmt_print() -> &'static Path {
    static PATH: OnceLock<PathBuf> = OnceLock::new();
    PATH.get_or_init(|| {
        let cargo_bin = match std::env::var_os("CARGO_HOME") {
            Some(home) => PathBuf::from(home).join("bin"),
            None => PathBuf::from(std::env::var_os("HOME").unwrap_or_default()).join(".cargo/bin"),
        };
        let found = |dirs: &mut dyn Iterator<Item = PathBuf>| dirs.map(|d| d.join("defmt-print")).find(|p| p.is_file());
        let path_dirs =
            std::env::var_os("PATH").map(|p| std::env::split_paths(&p).collect::<Vec<_>>()).unwrap_or_default();
        if let Some(path) = found(&mut path_dirs.into_iter().chain([cargo_bin.clone()])) {
            return path;
        }
        eprintln!("defmt-print is missing: installing it with `cargo install defmt-print` (about a minute)");
        let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
        let status = Command::new(cargo).args(["install", "--locked", "defmt-print"]).status().expect("cargo runs");
        assert!(status.success(), "`cargo install defmt-print` failed");
        found(&mut std::iter::once(cargo_bin)).expect("defmt-print in cargo's bin directory after installing it")
    })
}

/// Lines of a decoded firmware log that fail a test: errors, panics, faults.
pub fn log_failures(decoded: &str) -> Vec<&str> {
    decoded
        .lines()
        .filter(|line| {
            line.contains(" ERROR ")
                || line.contains("panicked")
                || line.contains("HardFault")
                || line.contains("unexpected exception")
        })
        .collect()
}

/// Writes a fresh state file at `path`: [`STATE_LEN`] bytes of 0xFF, erased
/// flash, the factory state (QEMU would make a missing file zero-filled).
pub fn erased_state(path: &Path) -> std::io::Result<()> {
    std::fs::write(path, vec![0xFF; STATE_LEN])
}

/// How QEMU reaches the firmware's network.
enum Network<'a> {
    Slirp {
        port: u16,
        http_port: u16,
    },
    /// A namespace and the TAP in it.
    Tap(&'a Namespace, &'a str),
}

/// A running QEMU with the image; stopped on drop (use [`Qemu::finish`] to
/// also check the firmware's log).
#[derive(Debug)]
pub struct Qemu {
    child: Mutex<Child>,
    dir: PathBuf,
    elf: PathBuf,
    state: PathBuf,
    addr: SocketAddr,
    http_addr: SocketAddr,
    ns: Option<Namespace>,
}

impl Qemu {
    /// Boots the image with slirp and a free port of 127.0.0.1 forwarded to
    /// 502, on a fresh (erased) state file.
    pub fn slirp() -> Self {
        Self::slirp_on(None, None)
    }

    /// Boots `bootloader` as the kernel with slirp on the state file
    /// `state`, into which the test [`install`]ed `image` (whose symbols
    /// decode the log): the bootloader runs embassy-boot over the
    /// partitions and starts the image in ACTIVE. The bootloader writes
    /// what it did to QEMU's stderr ([`Qemu::stderr`]).
    pub fn slirp_booting(bootloader: &Path, image: &Path, state: &Path) -> Self {
        Self::slirp_on(Some(state), Some((bootloader, image)))
    }

    /// Boots the image as [`Qemu::slirp`] does, on the state file `state`
    /// (made erased if it is missing), which outlives this QEMU: boot again
    /// on it to see what the firmware saved.
    pub fn slirp_with_state(state: &Path) -> Self {
        Self::slirp_on(Some(state), None)
    }

    fn slirp_on(state: Option<&Path>, images: Option<(&Path, &Path)>) -> Self {
        let mut last_error = String::new();
        for _ in 0..5 {
            let port = free_port();
            let http_port = free_port();
            if http_port == port {
                continue;
            }
            let addr = SocketAddr::from((Ipv4Addr::LOCALHOST, port));
            match Self::boot(Network::Slirp { port, http_port }, addr, state, images, &[]) {
                Ok(qemu) => return qemu,
                // Another program took the port between our look and QEMU's bind.
                Err(error) if error.contains("host forwarding") => last_error = error,
                Err(error) => panic!("QEMU did not start:\n{error}"),
            }
        }
        panic!("QEMU could not forward a free port:\n{last_error}")
    }

    /// Boots the image on the TAP of a new network namespace; the firmware is
    /// at 198.18.0.2 once its DHCP attempt has timed out.
    pub fn tap() -> Self {
        Self::tap_on(None, None, &[])
    }

    /// Boots the image on the TAP of a new network namespace, as
    /// [`Qemu::tap`] does, on the state file `state` (kept across boots).
    pub fn tap_with_state(state: &Path) -> Self {
        Self::tap_on(Some(state), None, &[])
    }

    /// Boots the image as [`Qemu::tap_with_state`] does, with `extra`
    /// arguments for QEMU after the image's (`-icount ...`, say).
    pub fn tap_with_state_and_args(state: &Path, extra: &[&str]) -> Self {
        Self::tap_on(Some(state), None, extra)
    }

    /// Boots `bootloader` as the kernel, as [`Qemu::slirp_booting`] does,
    /// on the TAP of a new network namespace, as [`Qemu::tap`] does: the
    /// image with `update` from the state file's ACTIVE, with no DHCP
    /// server, at 198.18.0.2 once its DHCP attempt has timed out.
    pub fn tap_booting(bootloader: &Path, image: &Path, state: &Path) -> Self {
        Self::tap_on(Some(state), Some((bootloader, image)), &[])
    }

    fn tap_on(state: Option<&Path>, images: Option<(&Path, &Path)>, extra: &[&str]) -> Self {
        let ns = Namespace::new().expect("a network namespace with a TAP");
        let ip: Ipv4Addr = DEVICE_IP.parse().expect("DEVICE_IP is an IPv4 address");
        let mut qemu = Self::boot(Network::Tap(&ns, TAP), SocketAddr::from((ip, MODBUS_PORT)), state, images, extra)
            .unwrap_or_else(|error| panic!("QEMU did not start:\n{error}"));
        qemu.ns = Some(ns);
        qemu
    }

    /// Boots `bootloader` over `image` on `state`, as [`Qemu::tap_booting`]
    /// does, on the TAP `tap` of `ns`, a namespace the test made and keeps
    /// (several QEMUs on one bridge: system_tests::fleet::bridge); the
    /// firmware is expected at `ip`. [`Qemu::run`] then runs in this
    /// process's namespace: reach the firmware from `ns` yourself.
    pub fn tap_booting_in(
        ns: &Namespace,
        tap: &str,
        ip: Ipv4Addr,
        bootloader: &Path,
        image: &Path,
        state: &Path,
    ) -> Self {
        Self::boot(
            Network::Tap(ns, tap),
            SocketAddr::from((ip, MODBUS_PORT)),
            Some(state),
            Some((bootloader, image)),
            &[],
        )
        .unwrap_or_else(|error| panic!("QEMU did not start:\n{error}"))
    }

    /// The namespace of a [`Qemu::tap`] QEMU.
    pub fn ns(&self) -> Option<&Namespace> {
        self.ns.as_ref()
    }

    /// Boots QEMU; `images`: the kernel and the image whose symbols decode
    /// the log, when they differ (a bootloader), else [`image`] for both;
    /// `extra`: more arguments for QEMU.
    fn boot(
        network: Network<'_>,
        addr: SocketAddr,
        state: Option<&Path>,
        images: Option<(&Path, &Path)>,
        extra: &[&str],
    ) -> Result<Self, String> {
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let (kernel, elf) = match images {
            Some((kernel, elf)) => (kernel.to_path_buf(), elf.to_path_buf()),
            None => {
                let elf = image();
                (elf.clone(), elf)
            }
        };
        let dir = std::env::temp_dir().join(format!(
            "mbqemu-{}-{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        let state = state.map_or_else(|| dir.join("psram.state"), Path::to_path_buf);
        if !state.exists() {
            erased_state(&state).map_err(|e| format!("{}: {e}", state.display()))?;
        }
        let http_addr = match network {
            Network::Slirp { http_port, .. } => SocketAddr::from((Ipv4Addr::LOCALHOST, http_port)),
            Network::Tap(..) => SocketAddr::new(addr.ip(), HTTP_PORT),
        };
        let nic = match network {
            Network::Slirp { port, http_port } => format!(
                "user,model=lan9118,restrict=on,hostfwd=tcp:127.0.0.1:{port}-:{MODBUS_PORT},\
                 hostfwd=tcp:127.0.0.1:{http_port}-:{HTTP_PORT}"
            ),
            Network::Tap(_, tap) => format!("tap,ifname={tap},script=no,downscript=no,model=lan9118{}", tap_mac(tap)),
        };
        let mut command = match network {
            Network::Slirp { .. } => Command::new("timeout"),
            Network::Tap(ns, _) => ns.command("timeout"),
        };
        let monitor = dir.join("monitor.sock");
        command
            .args(["-k", "5", &QEMU_TIMEOUT.as_secs().to_string()])
            .args(qemu_args(&kernel, &nic, &state))
            .args(extra)
            .arg("-monitor")
            .arg(format!("unix:{},server=on,wait=off", monitor.display()))
            .stdin(Stdio::null())
            .stdout(file(&dir.join("firmware.log"))?)
            .stderr(file(&dir.join("qemu.stderr"))?);
        let child = command.spawn().map_err(|e| format!("`timeout qemu-system-arm` does not start: {e}"))?;
        let qemu = Self { child: Mutex::new(child), dir, elf, state, addr, http_addr, ns: None };
        // The monitor answers once QEMU has finished setting up (slirp's
        // forwarding included); if setting up failed, QEMU has exited.
        let deadline = Instant::now() + MONITOR_TIMEOUT;
        loop {
            if let Some(status) = qemu.exit_status() {
                return Err(format!("QEMU exited ({status}) at start-up:\n{}", qemu.stderr()));
            }
            if qemu.try_monitor("info version").is_ok() {
                return Ok(qemu);
            }
            if Instant::now() > deadline {
                return Err(format!("QEMU's monitor never answered:\n{}", qemu.stderr()));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Where the firmware's Modbus server is reached from the test.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Where the firmware's HTTP API is reached from the test (slirp: a
    /// port of 127.0.0.1 forwarded to port 80).
    pub fn http_addr(&self) -> SocketAddr {
        self.http_addr
    }

    /// Cuts the power: SIGKILL to QEMU itself (not to `timeout`), which
    /// stops the guest between two instructions. What the guest wrote to
    /// the state file so far is there (a shared mapping); nothing more is.
    pub fn power_cut(self) {
        let timeout_pid = self.child.lock().expect("the child lock").id();
        for pid in children(timeout_pid) {
            // SAFETY: kill has no memory effects; the pid is our child's child.
            unsafe { libc::kill(pid, libc::SIGKILL) };
        }
        let status = self.child.lock().expect("the child lock").wait();
        assert!(status.is_ok(), "waiting for `timeout` after the power cut: {status:?}");
    }

    /// The image QEMU runs.
    pub fn elf(&self) -> &Path {
        &self.elf
    }

    /// The state file QEMU maps over the PSRAM.
    pub fn state(&self) -> &Path {
        &self.state
    }

    /// QEMU's exit status, if it has exited.
    pub fn exit_status(&self) -> Option<ExitStatus> {
        self.child.lock().expect("the child lock").try_wait().ok().flatten()
    }

    /// What QEMU printed on stderr.
    pub fn stderr(&self) -> String {
        std::fs::read_to_string(self.dir.join("qemu.stderr")).unwrap_or_default()
    }

    /// The firmware's log so far, decoded.
    pub fn log(&self) -> String {
        let Ok(raw) = std::fs::File::open(self.dir.join("firmware.log")) else {
            return String::new();
        };
        let output =
            Command::new(defmt_print()).arg("-e").arg(&self.elf).stdin(raw).output().expect("defmt-print runs");
        let mut text = String::from_utf8_lossy(&output.stdout).into_owned();
        if !output.stderr.is_empty() {
            let _ = write!(text, "{}", String::from_utf8_lossy(&output.stderr));
        }
        text
    }

    /// Waits until the decoded log contains `needle`; returns the log.
    pub fn wait_for_log(&self, needle: &str, timeout: Duration) -> String {
        let deadline = Instant::now() + timeout;
        loop {
            let log = self.log();
            if log.contains(needle) {
                return log;
            }
            assert!(Instant::now() < deadline, "no {needle:?} in the firmware's log within {timeout:?}:\n{log}");
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Runs a QEMU monitor command and returns its output.
    pub fn monitor(&self, command: &str) -> String {
        self.try_monitor(command).unwrap_or_else(|e| panic!("QEMU monitor, {command:?}: {e}"))
    }

    fn try_monitor(&self, command: &str) -> std::io::Result<String> {
        let mut stream = UnixStream::connect(self.dir.join("monitor.sock"))?;
        stream.set_read_timeout(Some(MONITOR_TIMEOUT))?;
        read_prompt(&mut stream)?;
        stream.write_all(format!("{command}\n").as_bytes())?;
        read_prompt(&mut stream)
    }

    /// Reads a 32-bit word of the guest's physical memory.
    pub fn read_word(&self, address: u32) -> u32 {
        let output = self.monitor(&format!("xp /1wx {address:#x}"));
        let prefix = format!("{address:016x}: 0x");
        let line = output.lines().find_map(|l| l.split_once(&prefix)).map(|(_, value)| value.trim().to_owned());
        let value = line.unwrap_or_else(|| panic!("no value for {address:#x} in the monitor's output {output:?}"));
        u32::from_str_radix(&value, 16).unwrap_or_else(|e| panic!("{value:?}: {e}"))
    }

    /// Runs `test` on a new thread (inside the namespace for [`Qemu::tap`]),
    /// on a current-thread tokio runtime, and returns its result. A panic
    /// inside fails the test and shows the firmware's log.
    pub fn run<T, F, Fut>(&self, test: F) -> T
    where
        T: Send,
        F: FnOnce() -> Fut + Send,
        Fut: Future<Output = T>,
    {
        crate::run_client(self.ns.as_ref(), test)
    }

    /// A tokio-modbus client whose first request (registers 256-259) was
    /// answered. Retries until [`READY_TIMEOUT`]: slirp accepts a connection
    /// before the firmware does, and resets it if the firmware is not ready.
    /// Call it inside [`Qemu::run`].
    pub async fn connect(&self) -> Context {
        let deadline = Instant::now() + READY_TIMEOUT;
        let mut last = String::new();
        while Instant::now() < deadline {
            if let Some(status) = self.exit_status() {
                panic!("QEMU exited ({status}); the firmware's log:\n{}\nQEMU: {}", self.log(), self.stderr());
            }
            match crate::modbus_answers(self.addr, ROBOT_REGISTERS, Duration::from_secs(2)).await {
                Ok(ctx) => return ctx,
                Err(error) => last = error,
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        panic!(
            "the firmware did not answer at {} within {READY_TIMEOUT:?} ({last}); its log:\n{}",
            self.addr,
            self.log()
        )
    }

    /// Quits QEMU and checks the firmware's log: a panic, a hard fault or an
    /// error line fails the test, as does QEMU exiting by itself. Returns the
    /// decoded log.
    pub fn finish(self) -> String {
        if let Some(status) = self.exit_status() {
            panic!("QEMU exited by itself ({status}); the firmware's log:\n{}\nQEMU: {}", self.log(), self.stderr());
        }
        let _ = self.try_monitor("quit");
        let deadline = Instant::now() + QUIT_TIMEOUT;
        let status = loop {
            if let Some(status) = self.exit_status() {
                break status;
            }
            assert!(Instant::now() < deadline, "QEMU did not quit");
            std::thread::sleep(Duration::from_millis(20));
        };
        let log = self.log();
        assert!(status.success(), "QEMU exited with {status} after `quit`; the firmware's log:\n{log}");
        let failures = log_failures(&log);
        assert!(failures.is_empty(), "the firmware logged {failures:#?}; its whole log:\n{log}");
        log
    }
}

impl Drop for Qemu {
    fn drop(&mut self) {
        let child = self.child.get_mut().expect("the child lock");
        if matches!(child.try_wait(), Ok(None)) {
            // SIGTERM to `timeout`, which passes it on to QEMU (SIGKILL would
            // leave QEMU running without its parent).
            if let Ok(pid) = i32::try_from(child.id()) {
                // SAFETY: kill has no memory effects; the pid is our child's.
                unsafe { libc::kill(pid, libc::SIGTERM) };
            }
            let _ = child.wait();
        }
        if std::thread::panicking() {
            eprintln!(
                "--- firmware log ({}) ---\n{}\n--- QEMU stderr ---\n{}",
                self.dir.display(),
                self.log(),
                self.stderr()
            );
        } else {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

/// QEMU's arguments for the image, apart from the monitor: the board with
/// its PSRAM mapped to the file `state` (`share=on`: the guest's writes go
/// to the file), the NIC, the image.
pub fn qemu_args(elf: &Path, nic: &str, state: &Path) -> Vec<String> {
    // QEMU's option syntax doubles a comma inside a value.
    let state = state.display().to_string().replace(',', ",,");
    let psram = format!("memory-backend-file,id=psram,size={STATE_LEN},mem-path={state},share=on");
    [
        "qemu-system-arm",
        "-M",
        "mps2-an386,memory-backend=psram",
        "-object",
        &psram,
        "-cpu",
        "cortex-m4",
        "-display",
        "none",
        "-serial",
        "none",
        "-semihosting-config",
        "enable=on,target=native",
        "-nic",
        nic,
        "-kernel",
    ]
    .into_iter()
    .map(str::to_owned)
    .chain([elf.display().to_string()])
    .collect()
}

/// Reads monitor output up to the next `(qemu) ` prompt; returns it without
/// the prompt and with the line editor's echo removed.
fn read_prompt(stream: &mut UnixStream) -> std::io::Result<String> {
    let mut bytes = Vec::new();
    let mut buffer = [0u8; 1024];
    while !bytes.ends_with(b"(qemu) ") {
        let n = stream.read(&mut buffer)?;
        if n == 0 {
            return Err(std::io::ErrorKind::UnexpectedEof.into());
        }
        bytes.extend_from_slice(&buffer[..n]);
    }
    bytes.truncate(bytes.len() - b"(qemu) ".len());
    let mut text = String::new();
    for line in bytes.lines().map_while(Result::ok) {
        // The echo of the command is full of cursor movements: skip it.
        if !line.contains('\u{1b}') {
            text.push_str(line.trim_end_matches('\r'));
            text.push('\n');
        }
    }
    Ok(text)
}

/// The processes whose parent is `parent` (from /proc).
fn children(parent: u32) -> Vec<i32> {
    let Ok(entries) = std::fs::read_dir("/proc") else { return Vec::new() };
    entries
        .filter_map(|entry| entry.ok()?.file_name().to_str()?.parse::<i32>().ok())
        .filter(|pid| {
            // /proc/PID/stat: "pid (comm) state ppid ...", comm may hold spaces.
            let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
            let ppid = stat.rsplit_once(')').and_then(|(_, rest)| rest.split_whitespace().nth(1));
            ppid.and_then(|p| p.parse::<u32>().ok()) == Some(parent)
        })
        .collect()
}

fn free_port() -> u16 {
    let listener = TcpListener::bind((Ipv4Addr::LOCALHOST, 0)).expect("a free port on 127.0.0.1");
    listener.local_addr().expect("the listener's address").port()
}

fn file(path: &Path) -> Result<std::fs::File, String> {
    std::fs::File::create(path).map_err(|e| format!("{}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_panics_and_faults_in_the_log_are_failures() {
        let log = "\
0.000 INFO  firmware 0.1.0 on mps2-an386
0.004 INFO  lan9118: link up
1.250 WARN  lan9118: TX error, resetting the transmitter
2.000 ERROR panicked: index out of bounds
2.001 ERROR HardFault at pc 0x00001234, lr 0xfffffff9
";
        assert_eq!(
            log_failures(log),
            ["2.000 ERROR panicked: index out of bounds", "2.001 ERROR HardFault at pc 0x00001234, lr 0xfffffff9"]
        );
        assert!(log_failures("0.005 INFO  Modbus TCP server at 10.0.2.15:502\n").is_empty());
    }

    #[test]
    fn dep_info_lists_the_sources_with_escaped_spaces() {
        let dep_info = "/t/release/mps2-an386: /w/firmware/build.rs /w/my\\ dir/lib.rs /w/memory.x\n";
        assert_eq!(
            dep_info_sources(dep_info),
            [PathBuf::from("/w/firmware/build.rs"), PathBuf::from("/w/my dir/lib.rs"), PathBuf::from("/w/memory.x")]
        );
        assert!(dep_info_sources("").is_empty());
    }

    #[test]
    fn qemu_args_name_the_board_and_the_image() {
        let args = qemu_args(Path::new("/x/fw.elf"), "user,model=lan9118", Path::new("/x/psram.state"));
        assert_eq!(args[0], "qemu-system-arm");
        assert!(args.windows(2).any(|w| w == ["-M", "mps2-an386,memory-backend=psram"]));
        assert!(args.windows(2).any(|w| w == ["-nic", "user,model=lan9118"]));
        assert_eq!(args.last().map(String::as_str), Some("/x/fw.elf"));
    }

    #[test]
    fn qemu_args_map_the_psram_to_the_state_file_shared() {
        let args = qemu_args(Path::new("/x/fw.elf"), "user", Path::new("/x/psram.state"));
        let object = "memory-backend-file,id=psram,size=16777216,mem-path=/x/psram.state,share=on";
        assert!(args.windows(2).any(|w| w == ["-object", object]), "{args:?}");
        assert_eq!(
            args.iter().filter(|a| a.contains("psram")).count(),
            2,
            "one backend, named by the machine: {args:?}"
        );
    }

    #[test]
    fn qemu_args_double_a_comma_in_the_state_file_s_path() {
        let args = qemu_args(Path::new("/x/fw.elf"), "user", Path::new("/x/a,b/s.state"));
        assert!(args.iter().any(|a| a.contains(",mem-path=/x/a,,b/s.state,share=on")), "{args:?}");
    }

    #[test]
    fn an_erased_state_is_16_mib_of_ff() {
        let path = std::env::temp_dir().join(format!("mbqemu-erased-{}.state", std::process::id()));
        erased_state(&path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        std::fs::remove_file(&path).unwrap();
        assert_eq!(bytes.len(), STATE_LEN);
        assert!(bytes.iter().all(|&b| b == 0xFF));
    }

    #[test]
    fn the_settings_region_is_where_the_image_s_memory_map_puts_it() {
        let map = std::fs::read_to_string(workspace().join("firmware/mps2-an386/memory.x")).unwrap();
        let line = map.lines().find(|l| l.trim_start().starts_with("SETTINGS ") && l.contains("ORIGIN"));
        let line = line.expect("a SETTINGS region in the MEMORY block");
        let fields: String = line.split(':').nth(1).unwrap().split_whitespace().collect();
        assert_eq!(fields, format!("ORIGIN={SETTINGS:#010x},LENGTH={}K", SETTINGS_LEN / 1024));
    }

    #[test]
    fn the_partitions_are_where_the_update_image_s_memory_map_puts_them() {
        let map = std::fs::read_to_string(workspace().join("firmware/mps2-an386/memory-update.x")).unwrap();
        let origin = |name: &str| {
            let line = map.lines().find(|l| l.trim_start().starts_with(&format!("{name} ")) && l.contains("ORIGIN"));
            let fields: String = line.expect(name).split(':').nth(1).unwrap().split_whitespace().collect();
            fields.to_lowercase()
        };
        assert_eq!(origin("ACTIVE"), format!("origin={ACTIVE:#010x},length={}k", ACTIVE_LEN / 1024));
        assert!(origin("DFU").starts_with(&format!("origin={DFU:#010x},")));
        assert!(origin("BOOTLOADER_STATE").starts_with(&format!("origin={BOOTLOADER_STATE:#010x},")));
        assert!(origin("SETTINGS").starts_with(&format!("origin={PSRAM:#010x},")));
    }
}
