//! Settings on the device, end to end: the mps2-an386 image in QEMU, its
//! HTTP API driven with curl (the client a user would use) over slirp's
//! forwarded port, Modbus with tokio-modbus, and the PSRAM's state file as
//! the board's flash, across a QEMU that quits, and one that is killed
//! (SIGKILL: a power cut) around a save.
//!
//! Needs the image, `qemu-system-arm`, `curl` and `defmt-print` (as the
//! other QEMU tests).

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use system_tests::OWNER_PASSWORD;
use system_tests::qemu::{self, NO_ROBOT, Qemu, ROBOT_REGISTERS, SETTINGS, SETTINGS_LEN};
use system_tests::update::claim;
use tokio_modbus::client::{Reader as _, tcp};
use tokio_modbus::{ExceptionCode, Slave};

/// A directory of the test's own, for a state file that outlives one QEMU.
fn test_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("mbqemu-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// One request with curl: the status and the body, or why there is none.
fn curl(addr: SocketAddr, method: &str, path: &str, body: Option<&str>) -> Result<(u16, String), String> {
    let mut command = Command::new("curl");
    command.args(["-sS", "--max-time", "5", "-X", method, "-w", "\n%{http_code}"]);
    if let Some(body) = body {
        // A change, with the password the test set first ([`claim`]).
        command.args(["-H", "Content-Type: application/json", "-u", &format!("admin:{OWNER_PASSWORD}")]);
        command.args(["--data-binary", body]);
    }
    let output = command.arg(format!("http://{addr}{path}")).stdin(Stdio::null()).output();
    let output = output.map_err(|e| format!("curl does not run: {e}"))?;
    if !output.status.success() {
        return Err(format!("curl: {} {}", output.status, String::from_utf8_lossy(&output.stderr)));
    }
    let text = String::from_utf8_lossy(&output.stdout).into_owned();
    let (body, status) = text.rsplit_once('\n').ok_or_else(|| format!("no status in {text:?}"))?;
    let status = status.trim().parse().map_err(|e| format!("status {status:?}: {e}"))?;
    Ok((status, body.to_owned()))
}

/// [`curl`], tried again for a few seconds while the connection fails
/// (slirp resets a connection that finds no listener yet).
fn request(addr: SocketAddr, method: &str, path: &str, body: Option<&str>) -> (u16, String) {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        match curl(addr, method, path, body) {
            Ok(answer) => return answer,
            Err(error) if Instant::now() < deadline => eprintln!("{method} {path}: {error}; again"),
            Err(error) => panic!("{method} {path}: {error}"),
        }
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// A field's value in the settings document as the API shows it: the text
/// after `"field":` up to the next `,` or `}` (strings keep their quotes).
fn field<'a>(document: &'a str, name: &str) -> &'a str {
    let key = format!("\"{name}\":");
    let start = document.find(&key).unwrap_or_else(|| panic!("no {name} in {document}")) + key.len();
    let rest = &document[start..];
    let end = rest.find([',', '}']).unwrap_or(rest.len());
    &rest[..end]
}

/// Boots on `state` and waits until the firmware has its address. slirp
/// holds a connection that comes before that for seconds (it retries its
/// SYN to the guest with back-off), so the test's first one waits for the log.
fn boot(state: &std::path::Path) -> Qemu {
    let qemu = Qemu::slirp_with_state(state);
    qemu.wait_for_log("Modbus TCP server at", qemu::READY_TIMEOUT);
    qemu
}

/// What unit `unit` gets for a read of registers 256-259 (the controller's
/// version and the robot state: [`NO_ROBOT`] on this image).
async fn answer_to_unit(qemu: &Qemu, unit: u8) -> Result<Vec<u16>, ExceptionCode> {
    let mut ctx = tcp::connect_slave(qemu.addr(), Slave(unit)).await.unwrap();
    ctx.read_holding_registers(ROBOT_REGISTERS, 4).await.unwrap()
}

#[test]
fn a_put_setting_applies_at_once_and_outlives_qemu() {
    let dir = test_dir("settings");
    let state = dir.join("psram.state");
    qemu::erased_state(&state).unwrap();

    let qemu = boot(&state);
    qemu.run(|| async {
        qemu.connect().await;
        assert_eq!(answer_to_unit(&qemu, 1).await, Ok(NO_ROBOT.to_vec()), "any unit at first");
        let (status, body) = request(qemu.http_addr(), "GET", "/api/settings", None);
        assert_eq!((status, field(&body, "unit_id")), (200, "\"any\""), "{body}");

        claim(qemu.http_addr());
        let change = r#"{"modbus": {"unit_id": 7}}"#;
        let (status, body) = request(qemu.http_addr(), "PUT", "/api/settings", Some(change));
        assert_eq!(status, 200, "{body}");
        assert_eq!(field(&body, "unit_id"), "\"7\"", "{body}");
        assert_eq!(field(&body, "reboot_required"), "false", "{body}");
        // In force at once: unit 7 is served, unit 1 is another device (0x0B).
        assert_eq!(answer_to_unit(&qemu, 7).await, Ok(NO_ROBOT.to_vec()));
        assert_eq!(answer_to_unit(&qemu, 1).await, Err(ExceptionCode::GatewayTargetDevice));
    });
    let log = qemu.finish();
    assert!(log.contains("settings: saved and applied"), "{log}");

    // A new QEMU on the same state file: the saved setting, shown and in force.
    let qemu = boot(&state);
    qemu.run(|| async {
        qemu.connect().await;
        let (status, body) = request(qemu.http_addr(), "GET", "/api/settings", None);
        assert_eq!((status, field(&body, "unit_id")), (200, "\"7\""), "{body}");
        assert_eq!(answer_to_unit(&qemu, 7).await, Ok(NO_ROBOT.to_vec()));
        assert_eq!(answer_to_unit(&qemu, 1).await, Err(ExceptionCode::GatewayTargetDevice));
        let (status, body) = request(qemu.http_addr(), "GET", "/api/status", None);
        assert_eq!(status, 200, "{body}");
        assert!(
            body.contains(r#""storage":{"ok":true,"records":4,"#),
            "the password's and the setting's, and the TLS key and certificate of the first start: {body}"
        );
        // The CPU load, measured by the image's executor loop once a second has passed.
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
        let load = loop {
            let (_, body) = request(qemu.http_addr(), "GET", "/api/status", None);
            let load = field(&body, "cpu_load_percent").to_owned();
            if load != "null" || std::time::Instant::now() > deadline {
                break load;
            }
            std::thread::sleep(std::time::Duration::from_millis(200));
        };
        assert!(load.parse::<u8>().is_ok_and(|percent| percent <= 100), "cpu_load_percent: {load}");
    });
    let log = qemu.finish();
    assert!(
        log.contains("settings: 4 records; storage ok: true"),
        "the password's and the setting's, and the TLS key and certificate: {log}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_state_file_holds_the_settings_region_and_nothing_past_it_changes() {
    let dir = test_dir("region");
    let state = dir.join("psram.state");
    qemu::erased_state(&state).unwrap();
    let end = SETTINGS + u32::try_from(SETTINGS_LEN).unwrap();
    let qemu = boot(&state);
    qemu.run(|| async {
        qemu.connect().await;
        claim(qemu.http_addr());
        let (status, body) =
            request(qemu.http_addr(), "PUT", "/api/settings", Some(r#"{"device": {"name": "cab-3"}}"#));
        assert_eq!(status, 200, "{body}");
    });
    // The record is at the region's start, in the guest and in the file.
    let first = qemu.read_word(SETTINGS);
    assert_ne!(first, 0xffff_ffff, "the save wrote the region's first page");
    let bytes = std::fs::read(&state).unwrap();
    assert_eq!(u32::from_le_bytes(bytes[..4].try_into().unwrap()), first, "the file is the region");
    assert_eq!(qemu.read_word(end), 0xffff_ffff, "nothing past the region");
    qemu.finish();
    let bytes = std::fs::read(&state).unwrap();
    assert_eq!(bytes.len(), qemu::STATE_LEN);
    assert!(bytes[SETTINGS_LEN..].iter().all(|&b| b == 0xff), "the PSRAM past the region is untouched");

    // The second boot reads what the first left: the image loads nothing over it.
    let qemu = boot(&state);
    assert_eq!(qemu.read_word(SETTINGS), first);
    qemu.run(|| async {
        qemu.connect().await;
        let (_, body) = request(qemu.http_addr(), "GET", "/api/settings", None);
        assert_eq!(field(&body, "name"), "\"cab-3\"", "{body}");
    });
    qemu.finish();
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_zeroed_region_is_taken_as_blank_with_a_warning() {
    // RAM no state file backs reads all zeros (QEMU makes a missing file so).
    let dir = test_dir("zeroed");
    let state = dir.join("psram.state");
    std::fs::write(&state, vec![0u8; qemu::STATE_LEN]).unwrap();
    let qemu = boot(&state);
    qemu.run(|| async {
        qemu.connect().await;
        claim(qemu.http_addr());
        let (status, body) = request(qemu.http_addr(), "PUT", "/api/settings", Some(r#"{"modbus": {"unit_id": 9}}"#));
        assert_eq!(status, 200, "{body}");
    });
    let log = qemu.finish();
    assert!(log.contains("WARN  settings: the settings region reads all zeros"), "{log}");
    assert!(log.contains("settings: 0 records; storage ok: true"), "blank, not corrupt:\n{log}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A small xorshift generator: the power cuts' moments, from a seed the
/// test prints (set `POWER_CUT_SEED` to replay one).
struct Rng(u64);

impl Rng {
    fn below(&mut self, n: u64) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0 % n
    }
}

/// The generation `k` of the settings the power-cut test saves: two fields
/// that change together, so a mix of two generations shows.
fn generation(k: u32) -> String {
    format!(r#"{{"modbus": {{"idle_timeout_s": {}, "unit_id": {}}}}}"#, 1000 + k, 1 + k)
}

/// The generation the settings document shows (0: the factory settings).
fn generation_of(document: &str) -> u32 {
    let idle: u32 = field(document, "idle_timeout_s").parse().unwrap();
    let unit = field(document, "unit_id").trim_matches('"');
    if idle == 60 && unit == "any" {
        return 0;
    }
    let k = idle.checked_sub(1000).unwrap_or_else(|| panic!("idle_timeout_s {idle}: {document}"));
    assert_eq!(unit, (1 + k).to_string(), "a mix of two saves: {document}");
    k
}

#[test]
fn a_power_cut_around_a_save_leaves_the_old_or_the_new_settings() {
    const CUTS: u32 = 20;
    let seed = std::env::var("POWER_CUT_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| SystemTime::now().duration_since(UNIX_EPOCH).unwrap().as_nanos() as u64 | 1);
    eprintln!("POWER_CUT_SEED={seed}");
    let mut rng = Rng(seed);
    let dir = test_dir("power-cut");
    let state = dir.join("psram.state");
    qemu::erased_state(&state).unwrap();
    // slirp's address as a static one (saved whole, applied at the next
    // boot): each boot is served at once instead of after a DHCP exchange
    // that can take 5 s here, and the test stays short.
    let qemu = boot(&state);
    qemu.run(|| async {
        qemu.connect().await;
        claim(qemu.http_addr());
        let network = r#"{"network": {"mode": "static", "address": "10.0.2.15/24", "gateway": "10.0.2.2"}}"#;
        let (status, body) = request(qemu.http_addr(), "PUT", "/api/settings", Some(network));
        assert_eq!((status, field(&body, "reboot_required")), (200, "true"), "{body}");
    });
    qemu.finish();

    let mut saved = 0;
    let (mut old, mut new) = (0, 0);
    for k in 1..=CUTS {
        let qemu = boot(&state);
        // It boots and answers, with the settings of a whole save.
        let before = qemu.run(|| async {
            qemu.connect().await;
            let (status, body) = request(qemu.http_addr(), "GET", "/api/settings", None);
            assert_eq!(status, 200, "{body}");
            generation_of(&body)
        });
        assert!(before == saved || before == k - 1, "cut {k}: generation {before}, expected {saved} or {}", k - 1);
        if k == 1 {
            // The first boot: nothing saved yet.
        } else if before == saved {
            old += 1;
        } else {
            new += 1;
        }
        saved = before;
        // The save of generation k, and the power cut a random moment after
        // the request leaves (0-15 ms: before, during or after the save).
        let mut client = Command::new("curl")
            .args(["-s", "--max-time", "2", "-o", "/dev/null", "-X", "PUT", "-H", "Content-Type: application/json"])
            .args(["-u", &format!("admin:{OWNER_PASSWORD}"), "--data-binary", &generation(k)])
            .arg(format!("http://{}/api/settings", qemu.http_addr()))
            .stdin(Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_micros(rng.below(15_000)));
        qemu.power_cut();
        let _ = client.wait();
    }
    // The last boot: whole settings, a store that reads back, Modbus served.
    let qemu = boot(&state);
    let last = qemu.run(|| async {
        qemu.connect().await;
        let (_, body) = request(qemu.http_addr(), "GET", "/api/settings", None);
        let last = generation_of(&body);
        let unit = if last == 0 { 1 } else { u8::try_from(1 + last).unwrap() };
        assert_eq!(answer_to_unit(&qemu, unit).await, Ok(NO_ROBOT.to_vec()));
        last
    });
    assert!(last == saved || last == CUTS, "the last cut: generation {last}, expected {saved} or {CUTS}");
    if last == saved {
        old += 1
    } else {
        new += 1
    }
    qemu.finish();
    eprintln!("{CUTS} power cuts: the old settings after {old}, the new after {new}");
    std::fs::remove_dir_all(&dir).unwrap();
}
