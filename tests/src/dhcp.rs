//! A real DHCP server on a test namespace's TAP: dnsmasq (Debian's
//! dnsmasq-base), serving the device's one address, 198.18.0.2, and nothing
//! else; its lease file tells what the device sent.

use std::path::PathBuf;
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

use crate::netns::{DEVICE_IP, Namespace, TAP};

/// One dnsmasq on a namespace's TAP, killed on drop.
#[derive(Debug)]
pub struct DhcpServer {
    child: Child,
    leases: PathBuf,
    log: PathBuf,
}

/// A lease as dnsmasq's lease file records it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Lease {
    pub mac: String,
    pub address: String,
    /// The hostname the client sent (option 12), `*` for none.
    pub hostname: String,
}

impl DhcpServer {
    /// dnsmasq on `ns`'s TAP (host side 198.18.0.1), DHCP only (no DNS),
    /// handing out [`DEVICE_IP`]/24 alone for 2 minutes, no configuration
    /// file of the machine's.
    pub fn start(ns: &Namespace) -> Self {
        let dir = std::env::temp_dir();
        let leases = dir.join(format!("{}.dnsmasq.leases", ns.name()));
        let log = dir.join(format!("{}.dnsmasq.log", ns.name()));
        let _ = std::fs::remove_file(&leases);
        let stderr = std::fs::File::create(&log).expect("a log file in the temp dir");
        let dnsmasq = ["/usr/sbin/dnsmasq", "/usr/bin/dnsmasq"]
            .into_iter()
            .find(|path| std::path::Path::new(path).is_file())
            .expect("dnsmasq is installed (scripts/setup installs dnsmasq-base)");
        let child = ns
            .command(dnsmasq)
            .args([
                "--keep-in-foreground",
                "--conf-file=/dev/null",
                "--port=0",
                "--no-resolv",
                "--no-hosts",
                "--user=root",
                "--group=root",
                "--pid-file",
                "--log-dhcp",
                "--log-facility=-",
                "--bind-interfaces",
                &format!("--interface={TAP}"),
                "--except-interface=lo",
                &format!("--dhcp-range={DEVICE_IP},{DEVICE_IP},255.255.255.0,2m"),
                "--dhcp-authoritative",
            ])
            .arg(format!("--dhcp-leasefile={}", leases.display()))
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(stderr)
            .spawn()
            .expect("dnsmasq starts");
        let mut server = Self { child, leases, log };
        // dnsmasq binds its socket at once; give it a moment, and fail
        // early (with its log) if it exited.
        std::thread::sleep(Duration::from_millis(300));
        if let Ok(Some(status)) = server.child.try_wait() {
            panic!("dnsmasq exited ({status}); its log:\n{}", server.log());
        }
        server
    }

    /// The leases in the lease file now.
    pub fn leases(&self) -> Vec<Lease> {
        let text = std::fs::read_to_string(&self.leases).unwrap_or_default();
        text.lines()
            .filter_map(|line| {
                // expiry MAC address hostname client-id
                let fields: Vec<&str> = line.split_whitespace().collect();
                match fields.as_slice() {
                    [_, mac, address, hostname, ..] => Some(Lease {
                        mac: (*mac).to_owned(),
                        address: (*address).to_owned(),
                        hostname: (*hostname).to_owned(),
                    }),
                    _ => None,
                }
            })
            .collect()
    }

    /// Waits up to `wait` for a lease that names `hostname`.
    pub fn wait_lease(&self, hostname: &str, wait: Duration) -> Lease {
        let deadline = Instant::now() + wait;
        loop {
            if let Some(lease) = self.leases().into_iter().find(|lease| lease.hostname == hostname) {
                return lease;
            }
            assert!(
                Instant::now() < deadline,
                "no lease named {hostname} within {wait:?}; leases: {:?}; dnsmasq's log:\n{}",
                self.leases(),
                self.log()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// dnsmasq's log so far.
    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

impl Drop for DhcpServer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_file(&self.leases);
        if std::thread::panicking() {
            eprintln!("--- dnsmasq log ({}) ---\n{}", self.log.display(), self.log());
        } else {
            let _ = std::fs::remove_file(&self.log);
        }
    }
}
