//! A fleet: several hal-sims in one network namespace, each on its own
//! TAP, the TAPs on one bridge with the host side's address, so one client
//! (`mbio`) sees them all as a plant network does: by mDNS and by address.
//!
//! Each hal-sim has a MAC of its own (`--mac`), as boards on one network
//! have, and the bridge switches frames between them as a plant's does.
//!
//! ```no_run
//! use system_tests::fleet::Fleet;
//! let fleet = Fleet::start(&["cell-1", "cell-2"], &["--robot", "idle"]);
//! let out = fleet.mbio(&["find", "--json"]);
//! ```

use std::io::{BufRead, BufReader};
use std::net::Ipv4Addr;
use std::path::{Path, PathBuf};
use std::process::{Child, Output, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use crate::OWNER_PASSWORD;
use crate::hal_sim::START_TIMEOUT;
use crate::netns::{HOST_CIDR, Namespace, TAP};

/// The bridge inside the fleet's namespace; it has the host side's address.
pub const BRIDGE: &str = "br0";

/// The `mbio` binary: `MBIO_BIN`, or `target/debug/mbio` of this workspace.
pub fn mbio_binary() -> PathBuf {
    crate::host_binary("MBIO_BIN", "mbio")
}

/// Makes `ns` a plant network: its TAP's address moves to a bridge with
/// `taps` TAPs (`tap0`, `tap1`, ...) as its ports. The TAP names.
pub fn bridge(ns: &Namespace, taps: usize) -> Vec<String> {
    ns.ip(&["addr", "flush", "dev", TAP]).unwrap();
    ns.ip(&["link", "add", BRIDGE, "type", "bridge", "mcast_snooping", "0", "stp_state", "0"]).unwrap();
    ns.ip(&["addr", "add", HOST_CIDR, "dev", BRIDGE]).unwrap();
    ns.ip(&["link", "set", BRIDGE, "up"]).unwrap();
    let names: Vec<String> = (0..taps).map(|i| format!("tap{i}")).collect();
    for (i, tap) in names.iter().enumerate() {
        if i > 0 {
            ns.ip(&["tuntap", "add", "dev", tap, "mode", "tap"]).unwrap();
        }
        ns.ip(&["link", "set", tap, "master", BRIDGE]).unwrap();
        ns.ip(&["link", "set", tap, "up"]).unwrap();
    }
    names
}

/// The address of the fleet's member `i`: 198.18.0.11, .12, ...
pub fn member_ip(i: usize) -> Ipv4Addr {
    Ipv4Addr::new(198, 18, 0, 11 + u8::try_from(i).unwrap())
}

/// The MAC of the fleet's member `i`: 02:4d:42:00:00:0b, ...0c, ... (as its address).
pub fn member_mac(i: usize) -> String {
    format!("02:4d:42:00:00:{:02x}", 11 + u8::try_from(i).unwrap())
}

/// One hal-sim of the fleet.
#[derive(Debug)]
pub struct Member {
    pub name: String,
    pub ip: Ipv4Addr,
    child: Child,
    log: PathBuf,
    control: PathBuf,
}

impl Member {
    /// hal-sim's log (stderr).
    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// The control socket's path.
    pub fn control_path(&self) -> &Path {
        &self.control
    }

    /// Sends one control-socket command (docs/hal-sim.md); the reply line.
    pub fn control(&self, command: &str) -> String {
        use std::io::Write as _;
        let mut stream = std::os::unix::net::UnixStream::connect(&self.control).expect("the control socket accepts");
        stream.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        stream.write_all(format!("{command}\n").as_bytes()).unwrap();
        let mut reply = String::new();
        BufReader::new(&mut stream).read_line(&mut reply).unwrap();
        reply.trim_end().to_owned()
    }

    /// Kills this hal-sim (a unit that failed).
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// hal-sims in one namespace on a bridge; all killed, and the namespace
/// deleted, on drop.
#[derive(Debug)]
pub struct Fleet {
    pub members: Vec<Member>,
    // Last: dropped after the hal-sims.
    ns: Namespace,
}

impl Fleet {
    /// One hal-sim per name, at [`member_ip`], each with `args` too;
    /// returns once every one says it listens.
    pub fn start(names: &[&str], args: &[&str]) -> Self {
        let ns = Namespace::new().expect("a network namespace with a TAP");
        let taps = bridge(&ns, names.len());
        let mut members = Vec::new();
        for (i, (name, tap)) in names.iter().zip(&taps).enumerate() {
            let ip = member_ip(i);
            let dir = std::env::temp_dir();
            let control = dir.join(format!("{}.{tap}.control.sock", ns.name()));
            let log = dir.join(format!("{}.{tap}.hal-sim.log", ns.name()));
            let mut child = ns
                .command(crate::hal_sim::binary())
                .args(["--tap", tap, "--mac", &member_mac(i), "--ip", &format!("{ip}/24"), "--name", name, "--control"])
                .arg(&control)
                .args(args)
                .env("RUST_LOG", std::env::var("RUST_LOG").unwrap_or_else(|_| "info".into()))
                .stdin(Stdio::null())
                .stdout(Stdio::piped())
                .stderr(std::fs::File::create(&log).unwrap())
                .spawn()
                .expect("hal-sim starts");
            let stdout = child.stdout.take().unwrap();
            let (tx, rx) = mpsc::channel();
            std::thread::spawn(move || {
                for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                    if tx.send(line).is_err() {
                        break;
                    }
                }
            });
            let member = Member { name: name.to_string(), ip, child, log, control };
            let expected = format!("hal-sim: modbus tcp listening on {ip}:");
            let deadline = Instant::now() + START_TIMEOUT;
            loop {
                match rx.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
                    Ok(line) if line.starts_with(&expected) => break,
                    Ok(_) => {}
                    Err(_) => panic!("{name} did not say it listens on {ip}; its log:\n{}", member.log()),
                }
            }
            // Keep draining stdout so hal-sim never blocks on it.
            std::thread::spawn(move || for _ in rx {});
            members.push(member);
        }
        Self { members, ns }
    }

    /// The namespace the fleet runs in.
    pub fn ns(&self) -> &Namespace {
        &self.ns
    }

    /// Runs `mbio ARGS` inside the namespace with the owner's password in
    /// `MBIO_PASSWORD` and no terminal (stdin `input`), within 120 s.
    pub fn mbio_with_input(&self, args: &[&str], input: &str) -> Output {
        mbio_in(&self.ns, args, input)
    }

    /// [`Fleet::mbio_with_input`] with nothing on stdin.
    pub fn mbio(&self, args: &[&str]) -> Output {
        mbio_in(&self.ns, args, "")
    }

    /// `GET path` of member `i`'s API (curl inside the namespace) as JSON.
    pub fn get(&self, i: usize, path: &str) -> serde_json::Value {
        let output = self
            .ns
            .command("curl")
            .args(["-sS", "-m", "5", "--fail"])
            .arg(format!("http://{}{path}", self.members[i].ip))
            .output()
            .unwrap();
        assert!(output.status.success(), "curl {path}: {}", String::from_utf8_lossy(&output.stderr));
        serde_json::from_slice(&output.stdout).unwrap()
    }
}

impl Drop for Fleet {
    fn drop(&mut self) {
        for member in &mut self.members {
            member.kill();
            let _ = std::fs::remove_file(&member.control);
            if std::thread::panicking() {
                eprintln!("--- {} ({}) log ---\n{}", member.name, member.ip, member.log());
            } else {
                let _ = std::fs::remove_file(&member.log);
            }
        }
    }
}

/// Runs `mbio ARGS` inside `ns` (see [`Fleet::mbio_with_input`]).
pub fn mbio_in(ns: &Namespace, args: &[&str], input: &str) -> Output {
    use std::io::Write as _;
    let mut child = ns
        .command("timeout")
        .args(["-k", "5", "300"])
        .arg(mbio_binary())
        .args(args)
        .env("MBIO_PASSWORD", OWNER_PASSWORD)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("mbio runs");
    let mut stdin = child.stdin.take().unwrap();
    stdin.write_all(input.as_bytes()).unwrap();
    drop(stdin);
    let output = child.wait_with_output().unwrap();
    eprintln!(
        "$ mbio {}\n[exit {:?}]\n{}{}",
        args.join(" "),
        output.status.code(),
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    output
}

/// The exit code of an mbio run, with its output in the message when it is not `expected`.
pub fn assert_exit(output: &Output, expected: i32) {
    assert_eq!(
        output.status.code(),
        Some(expected),
        "mbio exited {:?}, not {expected}:\n{}\n{}",
        output.status.code(),
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
}

/// Waits `limit` at most for `check` to hold, trying every 200 ms.
pub fn eventually(limit: Duration, mut check: impl FnMut() -> bool) -> bool {
    let deadline = Instant::now() + limit;
    while Instant::now() < deadline {
        if check() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    false
}
