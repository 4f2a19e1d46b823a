//! The system tests against any device at an address: a flashed board
//! (NUCLEO-F429ZI), hal-sim, or the mps2-an386 image in QEMU, reached the
//! way a user reaches it, with independent clients: tokio-modbus for
//! Modbus, curl for the HTTP API, python-zeroconf for discovery.
//!
//! ```no_run
//! use system_tests::board::Board;
//! let board = Board::new("192.168.1.50".parse().unwrap());
//! board.check_all(); // or one check: board.check_map(), ...
//! ```
//!
//! `scripts/board-test ADDRESS` runs them (tests/tests/board.rs, from the
//! variables of [`Board::from_env`]); tests/tests/qemu_board.rs runs them
//! against the QEMU image on a TAP as if it were a board.
//!
//! What they may do to the device: every check reads the settings and the
//! status first and never changes a setting. The output check toggles one
//! digital output (16 unless told otherwise) with FC 05 and puts it back
//! with FC 0F at once; the site-rules check sends `PUT /api/settings {}`
//! (saves nothing) and `POST /api/locate` with a wrong type (refused;
//! at worst the LED blinks); the settings are compared before and after.
//! The update check, only with an update file, uploads it: the device
//! reboots into it and keeps it.

use std::future::Future;
use std::net::{Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;
use tokio_modbus::ExceptionCode::{IllegalDataAddress, IllegalDataValue, IllegalFunction};
use tokio_modbus::client::{Client as _, Context, Reader as _, Writer as _};
use tokio_modbus::prelude::{ConformityLevel, ReadCode};

use crate::netns::Namespace;

/// The device's IPv4 address: the one variable the board tests need.
pub const ADDR_ENV: &str = "BOARD_ADDR";
/// Its HTTP port (80 unless a port is forwarded).
pub const HTTP_PORT_ENV: &str = "BOARD_HTTP_PORT";
/// Its Modbus port (what `/api/settings` says unless a port is forwarded).
pub const MODBUS_PORT_ENV: &str = "BOARD_MODBUS_PORT";
/// The admin password, when one is set on the device.
pub const PASSWORD_ENV: &str = "BOARD_PASSWORD";
/// A signed update file for the device: the update check uploads it.
pub const UPDATE_ENV: &str = "BOARD_UPDATE";
/// Whether mDNS reaches the device: `auto` (on its link and not through
/// 127.0.0.1), `on`, `off`.
pub const MDNS_ENV: &str = "BOARD_MDNS";
/// The digital output (1-16) the output check toggles and restores.
pub const OUTPUT_ENV: &str = "BOARD_OUTPUT";

/// Coils 0-265 and registers 0-435 (docs/data-map.md).
pub const COILS: u16 = 266;
pub const REGISTERS: u16 = 436;
/// The reserved coils and registers (docs/data-map.md), which read 0.
const RESERVED_COILS: [(u16, u16); 1] = [(44, 259)];
const RESERVED_REGISTERS: [(u16, u16); 13] = [
    (2, 3),
    (8, 15),
    (20, 20),
    (23, 127),
    (265, 269),
    (276, 279),
    (286, 289),
    (296, 299),
    (306, 309),
    (316, 399),
    (406, 409),
    (416, 419),
    (426, 429),
];
/// Register 259's robot states: 0-10 and NOT READY (15).
const ROBOT_STATES: [u16; 12] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 15];
/// The largest read of registers the protocol allows.
const MAX_READ_REGISTERS: u16 = 125;
/// How long the device may take to answer at all (a request, a connection).
const ANSWER_TIMEOUT: Duration = Duration::from_secs(30);
/// An update's upload may take this long (the device's own limit is 120 s).
const UPLOAD_TIMEOUT_S: u32 = 150;
/// From the upload's answer to the new image serving, beside the DHCP
/// timeout in `dhcp` mode: the reboot, the bootloader's swap (on the
/// NUCLEO several 1-2 s sector erases) and the start.
const SWAP_TIMEOUT: Duration = Duration::from_secs(120);
/// How long an image on trial has to confirm itself (docs/update.md),
/// beside the DHCP timeout in `dhcp` mode.
const TRIAL_LIMIT: Duration = Duration::from_secs(30);

/// Whether the discovery check runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Discovery {
    /// When mDNS can reach the device: on its link, not through 127.0.0.1.
    Auto,
    /// Always: a device that does not answer fails the check.
    On,
    /// Never (an image without `mdns`).
    Off,
}

/// What a check did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Checked {
    /// It ran and passed.
    Passed,
    /// It could not run, for this reason: nothing was checked.
    Skipped(String),
}

/// A device under test and how to reach it.
#[derive(Debug, Clone)]
pub struct Board<'a> {
    /// The device's address.
    pub ip: Ipv4Addr,
    /// Its HTTP port.
    pub http_port: u16,
    /// Its Modbus port; `None`: `modbus.port` of its settings.
    pub modbus_port: Option<u16>,
    /// The admin password, when one is set.
    pub password: Option<String>,
    /// A signed update file to upload ([`Board::check_update`]).
    pub update: Option<PathBuf>,
    /// Whether to check discovery.
    pub discovery: Discovery,
    /// The digital output (1-16) the output check toggles.
    pub output: u16,
    /// The namespace the device is reached from (QEMU on a TAP); `None`:
    /// this machine's network.
    pub ns: Option<&'a Namespace>,
}

impl Board<'static> {
    /// The device the variables name ([`ADDR_ENV`] and the others);
    /// `None` when [`ADDR_ENV`] is not set. A variable that is set but
    /// wrong fails the test, saying which.
    pub fn from_env() -> Option<Self> {
        let var = |name: &str| std::env::var(name).ok().filter(|v| !v.is_empty());
        let ip = var(ADDR_ENV)?;
        let ip = ip.parse().unwrap_or_else(|_| panic!("{ADDR_ENV}={ip:?} is not an IPv4 address"));
        let port = |name: &str| {
            var(name)
                .map(|p| p.parse::<u16>().ok().filter(|&p| p > 0).unwrap_or_else(|| panic!("{name}={p:?}: not a port")))
        };
        let mut board = Self::new(ip);
        board.http_port = port(HTTP_PORT_ENV).unwrap_or(board.http_port);
        board.modbus_port = port(MODBUS_PORT_ENV);
        board.password = var(PASSWORD_ENV);
        board.update = var(UPDATE_ENV).map(PathBuf::from);
        if let Some(file) = &board.update {
            assert!(file.is_file(), "{UPDATE_ENV}={}: no such file", file.display());
        }
        board.discovery = match var(MDNS_ENV).as_deref() {
            None | Some("auto") => Discovery::Auto,
            Some("on") => Discovery::On,
            Some("off") => Discovery::Off,
            Some(other) => panic!("{MDNS_ENV}={other:?}: auto, on or off"),
        };
        if let Some(output) = var(OUTPUT_ENV) {
            board.output = output
                .parse()
                .ok()
                .filter(|n| (1..=16).contains(n))
                .unwrap_or_else(|| panic!("{OUTPUT_ENV}={output:?}: a digital output, 1-16"));
        }
        Some(board)
    }
}

impl<'a> Board<'a> {
    /// The device at `ip`, HTTP on port 80, Modbus where its settings say,
    /// no password, no update, discovery when reachable, output 16.
    pub fn new(ip: Ipv4Addr) -> Self {
        Self {
            ip,
            http_port: 80,
            modbus_port: None,
            password: None,
            update: None,
            discovery: Discovery::Auto,
            output: 16,
            ns: None,
        }
    }

    /// Runs every check, in order: the API, identification, the map,
    /// exceptions, the output, the site's rules, discovery, the update.
    /// Prints what each did, and says loudly what was skipped and why.
    /// Returns the skipped checks' names and reasons.
    pub fn check_all(&self) -> Vec<(&'static str, String)> {
        let before = self.snapshot();
        eprintln!(
            "board: {} at {}: {} {} ({}), settings read",
            before.name(),
            self.ip,
            before.model(),
            before.firmware(),
            before.status["update"]["state"].as_str().unwrap_or("no update")
        );
        let mut skipped = Vec::new();
        let mut report = |name: &'static str, started: Instant, checked: Checked| match checked {
            Checked::Passed => eprintln!("board: {name}: passed ({:.1} s)", started.elapsed().as_secs_f64()),
            Checked::Skipped(why) => {
                eprintln!("board: {name}: SKIPPED, NOT CHECKED: {why}");
                skipped.push((name, why));
            }
        };
        let always = [
            ("api", Self::check_api as fn(&Self)),
            ("identification", Self::check_identification),
            ("map", Self::check_map),
            ("exceptions", Self::check_exceptions),
            ("output", Self::check_output),
            ("site rules", Self::check_site_rules),
        ];
        for (name, check) in always {
            let started = Instant::now();
            check(self);
            report(name, started, Checked::Passed);
        }
        let optional = [("discovery", Self::check_discovery as fn(&Self) -> Checked), ("update", Self::check_update)];
        for (name, check) in optional {
            let started = Instant::now();
            report(name, started, check(self));
        }
        assert_eq!(self.snapshot().settings, before.settings, "the checks changed the device's settings");
        skipped
    }

    /// `GET /api/status` and `/api/settings`, their types and shape, and
    /// what they must agree on; the page (gzip only) and a 404.
    pub fn check_api(&self) {
        let status = self.get("/api/status");
        status.expect(200, "GET /api/status");
        for (field, value) in
            [("content-type", "application/json"), ("cache-control", "no-store"), ("connection", "close")]
        {
            assert_eq!(status.header(field), Some(value), "GET /api/status: {field}\n{}", status.head);
        }
        let status = status.json();
        let device = &status["device"];
        for key in ["name", "model", "firmware", "mac"] {
            assert!(device[key].as_str().is_some_and(|v| !v.is_empty()), "device.{key} in {status}");
        }
        assert!(device["uptime_s"].is_u64(), "device.uptime_s in {status}");
        assert!(is_version(device["firmware"].as_str().unwrap_or_default()), "device.firmware in {status}");
        let mac = device["mac"].as_str().unwrap_or_default();
        assert!(mac.len() == 17 && mac.split(':').all(|b| u8::from_str_radix(b, 16).is_ok()), "device.mac: {mac}");
        let network = &status["network"];
        assert_eq!(network["link"], true, "{status}");
        assert!(["dhcp", "static"].contains(&network["mode"].as_str().unwrap_or_default()), "{status}");
        if !self.ip.is_loopback() {
            // Reached directly, the address in force is the one we reach.
            let address = network["address"].as_str().unwrap_or_default();
            assert_eq!(address.split('/').next(), Some(self.ip.to_string().as_str()), "network.address: {status}");
        }
        assert!(status["io"].is_object() && status["robot"].is_object(), "{status}");
        assert!(status["connections"].is_array(), "{status}");
        let counters = status["counters"].as_object().unwrap_or_else(|| panic!("counters in {status}"));
        assert!(counters.len() >= 12 && counters.values().all(Value::is_u64), "{status}");
        assert_eq!(status["storage"]["ok"], true, "the settings storage is not ok: {status}");
        assert!(status["admin"]["password_set"].is_boolean(), "{status}");

        let settings = self.get("/api/settings");
        settings.expect(200, "GET /api/settings");
        assert_eq!(settings.header("content-type"), Some("application/json"), "{}", settings.head);
        let settings = settings.json();
        for group in ["device", "network", "modbus", "watchdog", "robot", "admin"] {
            assert!(settings[group].is_object(), "{group} in {settings}");
        }
        assert!(settings["modbus"]["port"].is_u64(), "{settings}");
        assert!(settings["network"]["dhcp_timeout_s"].is_u64(), "{settings}");
        let password_set = &settings["admin"]["password_set"];
        assert_eq!(password_set, &status["admin"]["password_set"], "settings and status disagree on the password");
        if password_set == false {
            // A new device: whether it takes its first password now.
            assert!(status["admin"]["first_password_open"].is_boolean(), "{status}");
        }
        let name = settings["device"]["name"].as_str().unwrap_or_default();
        assert!(name.is_empty() || name == device["name"], "device.name {name:?}, in use {}", device["name"]);
        if self.password.is_none() && settings["admin"]["password_set"] == true {
            eprintln!("board: an admin password is set and none was given: the checks that change something get 401");
        }

        // The page: gzipped, or 406 to a client that does not take gzip.
        let page = self.request("GET", "/", &["-H", "Accept-Encoding: gzip"], false, 10);
        page.expect(200, "GET / (gzip)");
        assert_eq!(page.header("content-type"), Some("text/html; charset=utf-8"), "{}", page.head);
        assert_eq!(page.header("content-encoding"), Some("gzip"), "{}", page.head);
        for (field, value) in
            [("x-frame-options", "DENY"), ("x-content-type-options", "nosniff"), ("referrer-policy", "no-referrer")]
        {
            assert_eq!(page.header(field), Some(value), "GET /: {field}\n{}", page.head);
        }
        assert!(page.header("content-security-policy").is_some_and(|p| p.starts_with("default-src 'none'")));
        self.get("/").expect(406, "GET / without gzip");
        self.get("/api/nothing-here").expect(404, "GET /api/nothing-here");
    }

    /// Read Device Identification (0x2B/0x0E): vendor, product, the
    /// version and model and name `/api/status` shows; object 0x80 (the
    /// previous version) on an image with `update`; exception 02 for an
    /// object the device lacks.
    pub fn check_identification(&self) {
        let snapshot = self.snapshot();
        let extended = !snapshot.status["update"].is_null();
        let addr = self.modbus_addr(&snapshot);
        let (regular, extended_objects, unknown) = self.run(|| async {
            let mut ctx = connect(addr).await;
            let regular = ctx.read_device_identification(ReadCode::Regular, 0).await.unwrap().unwrap();
            let extended_objects = if extended {
                let reply = ctx.read_device_identification(ReadCode::Extended, 0).await.unwrap().unwrap();
                assert_eq!(reply.conformity_level, ConformityLevel::ExtendedIdentification, "0x83");
                Some(objects(&reply.device_id_objects))
            } else {
                None
            };
            let unknown = ctx.read_device_identification(ReadCode::Specific, 7).await.unwrap();
            (regular, extended_objects, unknown)
        });
        let level =
            if extended { ConformityLevel::ExtendedIdentification } else { ConformityLevel::RegularIdentification };
        assert_eq!(regular.conformity_level, level, "an image with `update` says 0x83, else 0x82");
        assert!(!regular.more_follows, "the regular set fits one reply");
        let found = objects(&regular.device_id_objects);
        let ids: Vec<u8> = found.iter().map(|(id, _)| *id).collect();
        assert_eq!(ids, [0, 1, 2, 3, 4, 5, 6], "{found:?}");
        assert_eq!(found[0].1, "mbio", "VendorName");
        assert_eq!(found[1].1, "mbio-tcp-io", "ProductCode");
        assert_eq!(found[2].1, snapshot.firmware(), "MajorMinorRevision: the firmware's version, as /api/status says");
        assert_eq!(found[4].1, "Modbus TCP I/O adapter", "ProductName");
        assert_eq!(found[5].1, snapshot.model(), "ModelName: the board, as /api/status says");
        assert_eq!(found[6].1, snapshot.name(), "UserApplicationName: the device's name, as /api/status says");
        if let Some(objects) = extended_objects {
            let ids: Vec<u8> = objects.iter().map(|(id, _)| *id).collect();
            assert_eq!(ids, [0, 1, 2, 3, 4, 5, 6, 0x80], "{objects:?}");
            let previous = snapshot.status["update"]["previous"].as_str().unwrap_or_default();
            assert_eq!(objects[7].1, previous, "object 0x80: the previous version, as /api/status says");
        }
        assert_eq!(unknown, Err(IllegalDataAddress), "object 7 does not exist");
    }

    /// Every coil and register read, whole and in blocks; reserved points
    /// read 0; values within their encodings; the two views of the outputs,
    /// inputs and robot flags agree.
    pub fn check_map(&self) {
        let addr = self.modbus_addr(&self.snapshot());
        self.run(|| async {
            let mut ctx = connect(addr).await;
            let coils = ctx.read_coils(0, COILS).await.unwrap().unwrap();
            assert_eq!(coils.len(), usize::from(COILS));
            let mut registers = Vec::new();
            for start in (0..REGISTERS).step_by(usize::from(MAX_READ_REGISTERS)) {
                let n = (REGISTERS - start).min(MAX_READ_REGISTERS);
                let part = ctx.read_holding_registers(start, n).await.unwrap().unwrap();
                assert_eq!(part.len(), usize::from(n), "registers {start}..{}", start + n);
                registers.extend(part);
            }
            for &(first, last) in &RESERVED_COILS {
                let on: Vec<u16> = (first..=last).filter(|&c| coils[usize::from(c)]).collect();
                assert!(on.is_empty(), "reserved coils read 1: {on:?}");
            }
            for &(first, last) in &RESERVED_REGISTERS {
                let set: Vec<(u16, u16)> =
                    (first..=last).map(|r| (r, registers[usize::from(r)])).filter(|&(_, v)| v != 0).collect();
                assert!(set.is_empty(), "reserved registers read other than 0: {set:?}");
            }
            check_values(&registers);
            // The views of the same points, read again until one reading
            // agrees (inputs and the robot may change between two reads).
            let mut disagreement = String::new();
            for _ in 0..5 {
                let coils = ctx.read_coils(0, COILS).await.unwrap().unwrap();
                let low = ctx.read_holding_registers(0, 23).await.unwrap().unwrap();
                let robot = ctx.read_holding_registers(259, 6).await.unwrap().unwrap();
                match views_disagree(&coils, &low, &robot) {
                    None => return,
                    Some(what) => disagreement = what,
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            panic!("coils and registers disagree five times running: {disagreement}");
        });
    }

    /// Exceptions, with requests that change nothing: 01 for a function
    /// the map does not serve, 02 for addresses past the end of each space
    /// and a write to a reserved coil, 03 for quantities out of range.
    pub fn check_exceptions(&self) {
        let snapshot = self.snapshot();
        let addr = self.modbus_addr(&snapshot);
        let allow_write = snapshot.settings["modbus"]["allow_write"].clone();
        self.run(|| async {
            let mut ctx = connect(addr).await;
            let reply = ctx.call(tokio_modbus::Request::Custom(0x41, vec![0, 0, 0, 1].into())).await.unwrap();
            assert_eq!(reply.map(|_| ()), Err(IllegalFunction), "function 0x41");
            assert_eq!(ctx.read_holding_registers(REGISTERS, 1).await.unwrap(), Err(IllegalDataAddress));
            assert_eq!(ctx.read_holding_registers(430, 7).await.unwrap(), Err(IllegalDataAddress));
            assert_eq!(ctx.read_coils(COILS, 1).await.unwrap(), Err(IllegalDataAddress));
            assert_eq!(ctx.read_coils(200, 67).await.unwrap(), Err(IllegalDataAddress));
            assert_eq!(ctx.read_holding_registers(0, 0).await.unwrap(), Err(IllegalDataValue));
            assert_eq!(ctx.read_holding_registers(0, MAX_READ_REGISTERS + 1).await.unwrap(), Err(IllegalDataValue));
            assert_eq!(ctx.read_coils(0, 2001).await.unwrap(), Err(IllegalDataValue));
            let reserved = ctx.write_single_coil(44, true).await.unwrap();
            assert_ne!(reserved, Err(IllegalFunction), "{}", refused_write(&allow_write));
            assert_eq!(reserved, Err(IllegalDataAddress), "a write to reserved coil 44");
            // The connection still serves.
            assert_eq!(ctx.read_coils(44, 1).await.unwrap().unwrap(), [false]);
        });
    }

    /// The output [`Board::output`] toggled with FC 05 and read back, in
    /// its coil and in register 1, then put back with FC 0F and read back.
    /// No other output is written (register 1 would write all sixteen).
    pub fn check_output(&self) {
        let snapshot = self.snapshot();
        let addr = self.modbus_addr(&snapshot);
        let allow_write = snapshot.settings["modbus"]["allow_write"].clone();
        let (coil, bit) = (15 + self.output, 1u16 << (self.output - 1));
        self.run(|| async {
            let mut ctx = connect(addr).await;
            let before = ctx.read_coils(coil, 1).await.unwrap().unwrap()[0];
            let register = ctx.read_holding_registers(1, 1).await.unwrap().unwrap()[0];
            assert_eq!(register & bit != 0, before, "coil {coil} and register 1 disagree at the start");
            let toggled = ctx.write_single_coil(coil, !before).await.unwrap();
            assert_ne!(toggled, Err(IllegalFunction), "{}", refused_write(&allow_write));
            // Read back, put back, and only then judge what was read.
            let read = ctx.read_coils(coil, 1).await.unwrap();
            let register = ctx.read_holding_registers(1, 1).await.unwrap();
            let restored = ctx.write_multiple_coils(coil, &[before]).await.unwrap();
            let after = ctx.read_coils(coil, 1).await.unwrap();
            let register_after = ctx.read_holding_registers(1, 1).await.unwrap();
            assert_eq!(toggled, Ok(()), "FC 05 to coil {coil}");
            assert_eq!(read, Ok(vec![!before]), "coil {coil} after FC 05");
            assert_eq!(register.map(|r| r[0] & bit != 0), Ok(!before), "register 1 after FC 05 to coil {coil}");
            assert_eq!(restored, Ok(()), "FC 0F to coil {coil}, putting it back");
            assert_eq!(after, Ok(vec![before]), "coil {coil} put back");
            assert_eq!(register_after.map(|r| r[0] & bit != 0), Ok(before), "register 1 after coil {coil} put back");
        });
    }

    /// What a page of another site, or a DNS-rebinding one, would send
    /// (docs/http-api.md): a foreign `Host` (421), a change without the
    /// JSON type (415), a foreign `Origin` (403); the device's own name
    /// and origin are taken. Every change sent is `{}` or a locate, so a
    /// device that wrongly took one would still change nothing; the
    /// settings and the storage's records are compared before and after.
    pub fn check_site_rules(&self) {
        let before = self.snapshot();
        let name = before.name().to_owned();
        let reply = self.request("GET", "/api/status", &["-H", "Host: evil.example"], false, 10);
        reply.expect(421, "GET /api/status with Host: evil.example");
        let reply = self.request("GET", "/api/settings", &["-H", "Host: evil.example:80"], false, 10);
        reply.expect(421, "GET /api/settings with Host: evil.example:80");
        let own = format!("Host: {name}.local");
        self.request("GET", "/api/status", &["-H", &own], false, 10).expect(200, &format!("GET /api/status, {own}"));

        let text = ["-H", "Content-Type: text/plain", "--data-binary", "{}"];
        self.request("PUT", "/api/settings", &text, true, 10).expect(415, "PUT /api/settings as text/plain");
        let form = ["-H", "Content-Type: application/x-www-form-urlencoded"];
        self.request("POST", "/api/locate", &form, true, 10).expect(415, "POST /api/locate as a form");
        let foreign =
            ["-H", "Content-Type: application/json", "-H", "Origin: http://evil.example", "--data-binary", "{}"];
        self.request("PUT", "/api/settings", &foreign, true, 10).expect(403, "PUT /api/settings from another origin");

        // The same change from the device's own origin is taken (a 200 that
        // saves nothing), so the refusals above were the rules'; a device
        // with no password yet takes no change but its first password.
        let origin = format!("Origin: http://{}", self.authority());
        let own = ["-H", "Content-Type: application/json", "-H", &origin, "--data-binary", "{}"];
        let reply = self.request("PUT", "/api/settings", &own, true, 10);
        if before.settings["admin"]["password_set"] != true {
            reply.expect(403, "PUT /api/settings {} on a device with no admin password yet");
            let message = reply.json()["errors"]["request"].as_str().unwrap_or_default().to_owned();
            assert!(message.starts_with("no admin password is set"), "the refusal says why: {message}");
        } else if self.password.is_none() {
            reply.expect(401, "PUT /api/settings {} without the password that is set");
        } else {
            let what =
                "PUT /api/settings {} from the device's own origin (a 403: is this host outside modbus.allow_write?)";
            reply.expect(200, what);
        }
        let after = self.snapshot();
        assert_eq!(after.settings, before.settings, "a refused request changed the settings");
        assert_eq!(after.status["storage"]["records"], before.status["storage"]["records"], "something was saved");
    }

    /// The device's name over mDNS: `NAME.local` resolves to its address,
    /// and browsing `_modbus._tcp` and `_http._tcp` finds its instances
    /// with their ports and TXT (name, model, version). Skipped when
    /// [`Board::discovery`] is off, or, when it is `Auto`, where multicast
    /// cannot reach the device (through 127.0.0.1, or through a gateway).
    pub fn check_discovery(&self) -> Checked {
        match self.discovery {
            Discovery::Off => return Checked::Skipped(format!("turned off ({MDNS_ENV}=off, --no-mdns)")),
            Discovery::Auto => {
                if let Err(why) = self.on_link() {
                    return Checked::Skipped(format!("{why} (--mdns on to check all the same)"));
                }
            }
            Discovery::On => {}
        }
        let snapshot = self.snapshot();
        let name = snapshot.name();
        let client = crate::mdns::Client::toward(self.ns, self.ip);
        let ip = self.ip.to_string();
        let addresses = client.resolve(&format!("{name}.local."), 5);
        assert_eq!(addresses, [ip.as_str()], "{name}.local resolves to");
        let instance = format!("{name}._modbus._tcp.local.");
        let found = client.browse("_modbus._tcp.local.", Some(&instance), 5);
        let modbus = found.iter().find(|i| i["name"] == instance.as_str());
        let modbus = modbus.unwrap_or_else(|| panic!("no {instance} among {found:#?}"));
        assert_eq!(modbus["port"], self.modbus_addr(&snapshot).port(), "{modbus}");
        assert_eq!(modbus["addresses"], serde_json::json!([ip]), "{modbus}");
        let txt = serde_json::json!({"name": name, "model": snapshot.model(), "version": snapshot.firmware()});
        assert_eq!(modbus["txt"], txt, "{modbus}");
        let instance = format!("{name}._http._tcp.local.");
        let found = client.browse("_http._tcp.local.", Some(&instance), 5);
        let http = found.iter().find(|i| i["name"] == instance.as_str());
        let http = http.unwrap_or_else(|| panic!("no {instance} among {found:#?}"));
        assert_eq!(http["port"], self.http_port, "{http}");
        Checked::Passed
    }

    /// Uploads [`Board::update`]: taken (202, its version), the device
    /// reboots into it, confirms it, and says the new version in
    /// `/api/status` and 0x2B, the old one as the previous. Skipped
    /// without a file. The device keeps the new image.
    pub fn check_update(&self) -> Checked {
        let Some(file) = &self.update else {
            return Checked::Skipped("no update file given (--update FILE)".into());
        };
        let before = self.snapshot();
        let bytes = std::fs::read(file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let header = update_image::Header::parse(&bytes)
            .unwrap_or_else(|e| panic!("{} is not an update file: {e:?}", file.display()));
        let version = format!("{}.{}.{}", header.version.major, header.version.minor, header.version.patch);
        let old = before.firmware().to_owned();
        assert_eq!(header.board.as_str(), before.model(), "{} is for another board", file.display());
        assert_ne!(version, old, "{} is the version running: an update to it would show nothing", file.display());
        let update = &before.status["update"];
        assert!(update.is_object(), "the device's image takes no updates (built without `update`): {}", before.status);
        assert_eq!(update["state"], "confirmed", "not a settled image to update from: {update}");
        let capacity = update["capacity"].as_u64().unwrap_or(0);
        assert!(bytes.len() as u64 <= capacity, "{} bytes, the device takes {capacity}", bytes.len());

        let started = Instant::now();
        let reply = self.upload(file);
        reply.expect(202, "POST /api/firmware");
        assert_eq!(reply.json()["firmware"], serde_json::json!({"version": version, "rebooting": true}));
        eprintln!(
            "board: update: {version} taken in {:.1} s; the device reboots into it",
            started.elapsed().as_secs_f64()
        );

        // Back with the new version: the swap, the start, DHCP.
        let dhcp = match before.settings["network"]["mode"].as_str() {
            Some("dhcp") => Duration::from_secs(before.settings["network"]["dhcp_timeout_s"].as_u64().unwrap_or(30)),
            _ => Duration::ZERO,
        };
        let deadline = Instant::now() + SWAP_TIMEOUT + dhcp + TRIAL_LIMIT;
        let status = loop {
            if let Some(status) = self.try_status() {
                let running = status["device"]["firmware"].as_str().unwrap_or_default();
                let state = status["update"]["state"].as_str().unwrap_or_default();
                assert!(
                    !(running == old && state == "rolled_back"),
                    "the device rolled back to {old}: the update did not confirm itself\n{status}"
                );
                if running == version && state == "confirmed" {
                    break status;
                }
            }
            assert!(
                Instant::now() < deadline,
                "{version} not running and confirmed within {:?}",
                SWAP_TIMEOUT + dhcp + TRIAL_LIMIT
            );
            std::thread::sleep(Duration::from_millis(500));
        };
        eprintln!("board: update: {version} confirmed {:.1} s after the upload", started.elapsed().as_secs_f64());
        assert_eq!(status["update"]["previous"], old.as_str(), "the previous version: {status}");
        let after = self.snapshot();
        let addr = self.modbus_addr(&after);
        let objects = self.run(|| async {
            let reply = connect(addr).await.read_device_identification(ReadCode::Extended, 0).await.unwrap().unwrap();
            assert_eq!(reply.conformity_level, ConformityLevel::ExtendedIdentification, "0x83");
            objects(&reply.device_id_objects)
        });
        let ids: Vec<u8> = objects.iter().map(|(id, _)| *id).collect();
        assert_eq!(ids, [0, 1, 2, 3, 4, 5, 6, 0x80], "{objects:?}");
        assert_eq!(objects[2].1, version, "MajorMinorRevision: the new version");
        assert_eq!(objects[7].1, old, "object 0x80: the previous version");
        assert_eq!(after.settings, before.settings, "the update changed the settings");
        Checked::Passed
    }

    /// `POST /api/firmware` with the update file `file` (and the password,
    /// when one was given), once: an upload is never sent again unasked.
    pub fn upload(&self, file: &Path) -> Response {
        let data = format!("@{}", file.display());
        // No `Expect: 100-continue` (curl's for a large body): the device
        // answers once the body is in, never before.
        let args = ["-H", "Content-Type: application/octet-stream", "-H", "Expect:", "--data-binary", &data];
        self.try_request("POST", "/api/firmware", &args, true, UPLOAD_TIMEOUT_S)
            .unwrap_or_else(|error| panic!("POST /api/firmware with {}: {error}", file.display()))
    }

    /// The status and the settings as the device shows them now.
    pub fn snapshot(&self) -> Snapshot {
        let status = self.get("/api/status");
        status.expect(200, "GET /api/status");
        let settings = self.get("/api/settings");
        settings.expect(200, "GET /api/settings");
        Snapshot { status: status.json(), settings: settings.json() }
    }

    /// `GET /api/status` once, as JSON; `None` when the device does not
    /// answer it (rebooting, say) within a few seconds.
    pub fn try_status(&self) -> Option<Value> {
        let reply = self.try_request("GET", "/api/status", &[], false, 3).ok()?;
        (reply.status == 200).then(|| reply.json())
    }

    /// `GET path`.
    pub fn get(&self, path: &str) -> Response {
        self.request("GET", path, &[], false, 10)
    }

    /// Sets the device's first admin password and gives it with every
    /// change from here on: a device takes no other change until one is
    /// set (docs/http-api.md, "The first password").
    pub fn claim(&mut self, password: &str) {
        let reply = self.change("PUT", "/api/password", &format!(r#"{{"password": "{password}"}}"#));
        reply.expect(200, "PUT /api/password: the first password");
        self.password = Some(password.to_owned());
    }

    /// A change: `method path` with the JSON `body`, and the password
    /// when one was given.
    pub fn change(&self, method: &str, path: &str, body: &str) -> Response {
        let args = ["-H", "Content-Type: application/json", "--data-binary", body];
        self.request(method, path, &args, true, 10)
    }

    /// `method path` with curl's `args` (and the password, if `authenticated`
    /// and one was given), tried again while the device does not answer
    /// (for [`ANSWER_TIMEOUT`]): the response.
    pub fn request(&self, method: &str, path: &str, args: &[&str], authenticated: bool, timeout_s: u32) -> Response {
        let deadline = Instant::now() + ANSWER_TIMEOUT;
        loop {
            match self.try_request(method, path, args, authenticated, timeout_s) {
                Ok(response) => return response,
                Err(error) if Instant::now() < deadline => {
                    eprintln!("board: {method} {path}: {error}; again");
                    std::thread::sleep(Duration::from_millis(500));
                }
                Err(error) => panic!("{method} {path}: no answer within {ANSWER_TIMEOUT:?}: {error}"),
            }
        }
    }

    /// One request with curl ([`Board::request`]): the response, or why
    /// none came.
    pub fn try_request(
        &self,
        method: &str,
        path: &str,
        args: &[&str],
        authenticated: bool,
        timeout_s: u32,
    ) -> Result<Response, String> {
        let mut command = self.command("curl");
        command
            .args(["-sS", "-i", "--noproxy", "*", "-m", &timeout_s.to_string(), "-X", method])
            .args(args)
            .arg(format!("http://{}{path}", self.authority()));
        // The password goes in on curl's stdin (a config line), never on
        // its command line, which anyone on the machine can read.
        let credentials = self.password.as_ref().filter(|_| authenticated);
        if credentials.is_some() {
            command.args(["-K", "-"]).stdin(Stdio::piped());
        } else {
            command.stdin(Stdio::null());
        }
        let mut child =
            command.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().map_err(|e| format!("curl: {e}"))?;
        if let Some(password) = credentials {
            use std::io::Write as _;
            let escaped = password.replace('\\', "\\\\").replace('"', "\\\"");
            let mut stdin = child.stdin.take().expect("curl's stdin");
            stdin.write_all(format!("user = \"admin:{escaped}\"\n").as_bytes()).map_err(|e| format!("curl: {e}"))?;
        }
        let output = child.wait_with_output().map_err(|e| format!("curl: {e}"))?;
        if !output.status.success() {
            return Err(format!("curl {}: {}", output.status, String::from_utf8_lossy(&output.stderr).trim()));
        }
        Response::parse(&output.stdout).ok_or_else(|| format!("not an HTTP response: {:?}", output.stdout))
    }

    /// Where Modbus is reached: the device's address and [`Board::modbus_port`],
    /// or the port its settings give.
    pub fn modbus_addr(&self, snapshot: &Snapshot) -> SocketAddr {
        let port = self.modbus_port.unwrap_or_else(|| {
            let port = snapshot.settings["modbus"]["port"].as_u64().and_then(|p| u16::try_from(p).ok());
            port.unwrap_or_else(|| panic!("modbus.port in {}", snapshot.settings))
        });
        SocketAddr::from((self.ip, port))
    }

    /// Runs `test` on a new thread (inside [`Board::ns`], if any), on a
    /// current-thread tokio runtime (`crate::run_client`).
    pub fn run<T, F, Fut>(&self, test: F) -> T
    where
        T: Send,
        F: FnOnce() -> Fut + Send,
        Fut: Future<Output = T>,
    {
        crate::run_client(self.ns, test)
    }

    /// `program`, in [`Board::ns`] if there is one.
    fn command(&self, program: &str) -> Command {
        match self.ns {
            Some(ns) => ns.command(program),
            None => Command::new(program),
        }
    }

    /// The HTTP authority: `IP`, or `IP:PORT` off port 80 (what curl puts in `Host`).
    fn authority(&self) -> String {
        if self.http_port == 80 { self.ip.to_string() } else { format!("{}:{}", self.ip, self.http_port) }
    }

    /// Whether the device is on one of this machine's links (where mDNS
    /// goes): not reached through 127.0.0.1, and its route has no gateway.
    fn on_link(&self) -> Result<(), String> {
        if self.ip.is_loopback() {
            return Err(format!("{} is this machine (a forwarded port): no multicast reaches the device", self.ip));
        }
        let output = self.command("ip").args(["-4", "route", "get", &self.ip.to_string()]).output();
        let output = output.map_err(|e| format!("`ip route get` does not run ({e}): cannot tell the device's link"))?;
        let route = String::from_utf8_lossy(&output.stdout);
        let route = route.lines().next().unwrap_or_default().trim().to_owned();
        if !output.status.success() {
            return Err(format!("no route to {}: {}", self.ip, String::from_utf8_lossy(&output.stderr).trim()));
        }
        if route.contains(" via ") {
            return Err(format!("the device is reached through a gateway ({route}): mDNS stays on its own link"));
        }
        Ok(())
    }
}

/// The device's status and settings, read together.
#[derive(Debug, Clone)]
pub struct Snapshot {
    pub status: Value,
    pub settings: Value,
}

impl Snapshot {
    /// The device's name in use (`/api/status`).
    pub fn name(&self) -> &str {
        self.status["device"]["name"].as_str().unwrap_or_else(|| panic!("device.name in {}", self.status))
    }

    /// The board (`/api/status`'s model).
    pub fn model(&self) -> &str {
        self.status["device"]["model"].as_str().unwrap_or_else(|| panic!("device.model in {}", self.status))
    }

    /// The running firmware's version.
    pub fn firmware(&self) -> &str {
        self.status["device"]["firmware"].as_str().unwrap_or_else(|| panic!("device.firmware in {}", self.status))
    }
}

/// An HTTP response as curl (`-i`) received it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Response {
    pub status: u16,
    /// The status line and the header fields.
    pub head: String,
    pub body: String,
}

impl Response {
    /// Reads curl's `-i` output: a head, an empty line, the body (an
    /// interim 1xx head before the final one is skipped).
    pub fn parse(output: &[u8]) -> Option<Self> {
        let mut text = String::from_utf8_lossy(output).into_owned();
        loop {
            let (head, body) = text.split_once("\r\n\r\n")?;
            let status: u16 = head.strip_prefix("HTTP/1.")?.get(2..5)?.parse().ok()?;
            if (100..200).contains(&status) {
                text = body.to_owned();
                continue;
            }
            return Some(Self { status, head: head.to_owned(), body: body.to_owned() });
        }
    }

    /// The value of the header field `name` (case-insensitive).
    pub fn header(&self, name: &str) -> Option<&str> {
        self.head.lines().skip(1).find_map(|line| {
            let (field, value) = line.split_once(':')?;
            field.trim().eq_ignore_ascii_case(name).then(|| value.trim())
        })
    }

    /// The body as JSON (every response of the API is).
    pub fn json(&self) -> Value {
        serde_json::from_str(&self.body).unwrap_or_else(|e| panic!("not JSON ({e}): {:?}", self.body))
    }

    /// Fails the test, naming `what`, unless the status is `status`.
    pub fn expect(&self, status: u16, what: &str) {
        assert_eq!(self.status, status, "{what}: {}\n{}", self.head.lines().next().unwrap_or_default(), self.body);
    }
}

/// A tokio-modbus client whose first request was answered; retried for
/// [`ANSWER_TIMEOUT`] (a device that has just started, or a slirp port
/// that resets a connection the firmware is not ready for).
pub async fn connect(addr: SocketAddr) -> Context {
    let deadline = Instant::now() + ANSWER_TIMEOUT;
    let mut last = String::new();
    while Instant::now() < deadline {
        match crate::modbus_answers(addr, 259, Duration::from_secs(3)).await {
            Ok(ctx) => return ctx,
            Err(error) => last = error,
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    panic!("Modbus at {addr} did not answer within {ANSWER_TIMEOUT:?}: {last}")
}

/// A signed update file for mps2-an386 written to `dir`, for the board
/// tests to upload ([`Board::update`]): `payload` (a flat image) signed as
/// `version` with the development key.
pub fn update_file(dir: &Path, payload: &[u8], version: &str) -> PathBuf {
    let file = dir.join(format!("mps2-an386-{version}.update"));
    std::fs::write(&file, crate::update::signed(dir, payload, version)).unwrap();
    file
}

/// The objects of a 0x2B reply as (id, text).
fn objects(objects: &[tokio_modbus::prelude::DeviceIdObject]) -> Vec<(u8, String)> {
    objects.iter().map(|o| (o.id, o.value_as_str().expect("ASCII").to_owned())).collect()
}

/// Whether `text` is a version: three numbers.
fn is_version(text: &str) -> bool {
    let parts: Vec<&str> = text.split('.').collect();
    parts.len() == 3 && parts.iter().all(|p| p.parse::<u16>().is_ok())
}

/// Why a write got 01: the client is outside `modbus.allow_write`.
fn refused_write(allow_write: &Value) -> String {
    format!(
        "the write got exception 01: this host is outside modbus.allow_write ({allow_write}); \
         run the board tests from a host it admits"
    )
}

/// The registers' values within their encodings (docs/data-map.md).
fn check_values(registers: &[u16]) {
    let at = |r: usize| registers[r];
    for r in [5, 7, 17, 19] {
        assert!(at(r) <= 1, "analog type register {r}: {}", at(r));
    }
    // Analog values: µA up to 20 mA (type 0), mV up to 10 V (type 1).
    for (value, kind) in [(4, 5), (6, 7), (16, 17), (18, 19)] {
        let max = if at(kind) == 0 { 20_000 } else { 10_000 };
        assert!(at(value) <= max, "analog register {value}: {} over {max} (type {})", at(value), at(kind));
    }
    assert!(at(21) <= 0b11_1111 && at(22) <= 0b11_1111, "tool points: {} {}", at(21), at(22));
    assert!(ROBOT_STATES.contains(&at(259)), "robot state {}", at(259));
    for r in [260, 261, 263, 264] {
        assert!(at(r) <= 1, "robot flag register {r}: {}", at(r));
    }
    assert!(at(262) <= 2, "safety stop register 262: {}", at(262));
}

/// Where the coils and the registers that show the same points disagree:
/// inputs (coils 0-15, register 0), outputs (16-31, register 1), tool
/// inputs (32-37, 21) and outputs (38-43, 22), and the robot's flags
/// (coils 260-265, registers 260-264; `robot` is registers 259-264).
fn views_disagree(coils: &[bool], low: &[u16], robot: &[u16]) -> Option<String> {
    let mask = |from: usize, n: usize| (0..n).fold(0u16, |m, i| m | (u16::from(coils[from + i]) << i));
    let mut wrong = Vec::new();
    for (from, n, register) in [(0, 16, 0), (16, 16, 1), (32, 6, 21), (38, 6, 22)] {
        if mask(from, n) != low[register] {
            wrong.push(format!(
                "coils {from}-{}: {:#x}, register {register}: {:#x}",
                from + n - 1,
                mask(from, n),
                low[register]
            ));
        }
    }
    let flags = [robot[1] != 0, robot[2] != 0, robot[3] != 0, robot[4] != 0, robot[5] != 0, robot[3] == 2];
    if coils[260..266] != flags {
        wrong.push(format!("coils 260-265: {:?}, registers 260-264: {:?}", &coils[260..266], &robot[1..]));
    }
    (!wrong.is_empty()).then(|| wrong.join("; "))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_response_is_read_from_curl_s_output() {
        let output = b"HTTP/1.1 100 Continue\r\n\r\nHTTP/1.1 202 Accepted\r\nContent-Type: application/json\r\n\
                       Connection: close\r\n\r\n{\"rebooting\":true}";
        let response = Response::parse(output).unwrap();
        assert_eq!(response.status, 202);
        assert_eq!(response.header("content-type"), Some("application/json"));
        assert_eq!(response.header("CONNECTION"), Some("close"));
        assert_eq!(response.header("host"), None);
        assert_eq!(response.json()["rebooting"], true);
        assert_eq!(Response::parse(b"HTTP/1.1 421 Misdirected Request\r\n\r\n").unwrap().body, "");
        assert!(Response::parse(b"").is_none());
        assert!(Response::parse(b"garbage\r\n\r\n").is_none());
    }

    #[test]
    fn the_views_of_one_point_must_agree() {
        let mut coils = vec![false; usize::from(COILS)];
        let mut low = vec![0u16; 23];
        let mut robot = vec![15, 0, 0, 0, 0, 0];
        assert_eq!(views_disagree(&coils, &low, &robot), None);
        coils[16] = true;
        assert!(views_disagree(&coils, &low, &robot).unwrap().contains("coils 16-31: 0x1, register 1: 0x0"));
        low[1] = 1;
        robot[3] = 2; // safety stopped, requiring recovery: coils 262 and 265
        assert!(views_disagree(&coils, &low, &robot).unwrap().contains("coils 260-265"));
        coils[262] = true;
        coils[265] = true;
        assert_eq!(views_disagree(&coils, &low, &robot), None);
    }

    #[test]
    fn versions_are_three_numbers() {
        assert!(is_version("0.99.0"));
        assert!(!is_version("0.99") && !is_version("a.b.c") && !is_version("1.2.3.4"));
    }
}
