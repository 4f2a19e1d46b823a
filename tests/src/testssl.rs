//! testssl.sh (Debian's `testssl`, 3.0.8) against a TLS port of the device,
//! inside the test's namespace, with its findings read from its JSON file.
//!
//! ```no_run
//! # let ns = system_tests::netns::Namespace::new().unwrap();
//! # let dir = std::path::Path::new("/tmp");
//! use system_tests::testssl;
//! let report = testssl::run(&ns, "198.18.0.2:802", &[], dir);
//! report.assert_no_high_or_critical(&[]);
//! ```
//!
//! What it runs ([`CHECKS`]): the protocols, the standard cipher
//! categories, every cipher of its list (`-e`), forward secrecy, the
//! server's preferences, its defaults and certificate, and every
//! vulnerability check. Not the HTTP header checks (`-h`): pass them in
//! `extra` for an HTTPS port. It makes no DNS lookup (`--nodns none`),
//! fetches no CRL or OCSP answer (no `--phone-out`), and the namespace
//! has no route beyond its TAP: it reaches nothing but the device.
//!
//! testssl 3.0.8 cannot present a client certificate (`--mtls` came in
//! 3.1): on a port that requires one, every check that needs a finished
//! handshake cannot run, and testssl says so (see docs/tls.md, "Tests").

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

use crate::netns::Namespace;

/// testssl's checks: protocols, standard ciphers, each cipher, forward
/// secrecy, server preferences, server defaults, vulnerabilities.
pub const CHECKS: [&str; 7] = ["-p", "-s", "-e", "-f", "-P", "-S", "-U"];
/// `timeout` ends testssl after this long.
pub const TIMEOUT: Duration = Duration::from_secs(300);

/// One finding of testssl's flat JSON file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Finding {
    pub id: String,
    pub severity: String,
    pub finding: String,
}

impl std::fmt::Display for Finding {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:<8} {}: {}", self.severity, self.id, self.finding)
    }
}

/// A HIGH or CRITICAL finding that is the device's design, not a flaw:
/// the finding `id` whose text starts with `finding`, and why.
#[derive(Debug, Clone, Copy)]
pub struct Accepted {
    pub id: &'static str,
    pub finding: &'static str,
    pub why: &'static str,
}

impl Accepted {
    fn covers(&self, finding: &Finding) -> bool {
        finding.id == self.id && finding.finding.starts_with(self.finding)
    }
}

/// What testssl found.
#[derive(Debug)]
pub struct Report {
    pub findings: Vec<Finding>,
    pub took: Duration,
    pub json: PathBuf,
    /// testssl's screen output (no colours).
    pub output: String,
}

impl Report {
    /// The findings of `severity`.
    pub fn of(&self, severity: &str) -> Vec<&Finding> {
        self.findings.iter().filter(|f| f.severity == severity).collect()
    }

    /// The finding `id`, if testssl reported it.
    pub fn get(&self, id: &str) -> Option<&Finding> {
        self.findings.iter().find(|f| f.id == id)
    }

    /// How many findings of each severity, in testssl's order.
    pub fn counts(&self) -> String {
        let severities = ["CRITICAL", "HIGH", "MEDIUM", "LOW", "WARN", "INFO", "OK", "DEBUG"];
        let mut parts: Vec<String> = severities
            .iter()
            .map(|s| (s, self.of(s).len()))
            .filter(|(_, n)| *n > 0)
            .map(|(s, n)| format!("{s} {n}"))
            .collect();
        let known = self.findings.iter().filter(|f| !severities.contains(&f.severity.as_str())).count();
        if known > 0 {
            parts.push(format!("other {known}"));
        }
        parts.join(", ")
    }

    /// Prints every finding above INFO and OK, and the accepted ones with
    /// why; fails on any HIGH or CRITICAL finding that `accepted` does not
    /// cover, printing them.
    pub fn assert_no_high_or_critical(&self, accepted: &[Accepted]) {
        eprintln!("testssl: {} findings in {:.0} s ({})", self.findings.len(), self.took.as_secs_f64(), self.counts());
        for finding in self.findings.iter().filter(|f| !matches!(f.severity.as_str(), "INFO" | "OK" | "DEBUG")) {
            eprintln!("testssl: {finding}");
        }
        let mut failures = Vec::new();
        for finding in self.findings.iter().filter(|f| matches!(f.severity.as_str(), "HIGH" | "CRITICAL")) {
            match accepted.iter().find(|a| a.covers(finding)) {
                Some(a) => eprintln!("testssl: accepted by design: {finding}\n         because {}", a.why),
                None => failures.push(finding.to_string()),
            }
        }
        assert!(
            failures.is_empty(),
            "testssl found {} HIGH or CRITICAL findings (JSON: {}):\n{}",
            failures.len(),
            self.json.display(),
            failures.join("\n")
        );
    }
}

/// Fails loudly unless testssl is installed.
pub fn require() {
    let probe = Command::new("testssl").arg("--version").stdin(Stdio::null()).output();
    assert!(
        probe.as_ref().is_ok_and(|o| String::from_utf8_lossy(&o.stdout).contains("testssl")),
        "this test needs testssl.sh: `apt-get install testssl.sh` (scripts/setup installs it): {probe:?}"
    );
}

/// Runs testssl's [`CHECKS`] (and `extra`) against `target` (`host:port`)
/// inside `ns`, its JSON file in `dir`, and reads its findings. Fails if
/// testssl did not finish in [`TIMEOUT`] or wrote no findings.
pub fn run(ns: &Namespace, target: &str, extra: &[&str], dir: &Path) -> Report {
    let json = dir.join(format!("testssl-{}.json", target.replace([':', '.'], "_")));
    let _ = std::fs::remove_file(&json);
    let started = Instant::now();
    let output = ns
        .command("timeout")
        .args(["-k", "5", &TIMEOUT.as_secs().to_string(), "testssl"])
        .args(["--quiet", "--color", "0", "--warnings", "off", "--nodns", "none"])
        .args(["--connect-timeout", "10", "--openssl-timeout", "10"])
        .args(["--openssl", "/usr/bin/openssl"])
        .arg("--jsonfile")
        .arg(&json)
        .args(CHECKS)
        .args(extra)
        .arg(target)
        .current_dir(dir)
        .stdin(Stdio::null())
        .output()
        .expect("testssl runs");
    let took = started.elapsed();
    let screen = String::from_utf8_lossy(&output.stdout).into_owned();
    assert_ne!(
        output.status.code(),
        Some(124),
        "testssl did not finish in {TIMEOUT:?}:\n{screen}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let text = std::fs::read_to_string(&json).unwrap_or_else(|e| {
        panic!(
            "testssl wrote no JSON file {} ({e}; exit {:?}):\n{screen}\n{}",
            json.display(),
            output.status,
            String::from_utf8_lossy(&output.stderr)
        )
    });
    let findings = parse(&text).unwrap_or_else(|e| panic!("testssl's JSON {}: {e}", json.display()));
    assert!(!findings.is_empty(), "testssl reported nothing:\n{screen}");
    Report { findings, took, json, output: screen }
}

/// testssl's flat JSON: an array of objects with `id`, `severity` and
/// `finding` (among others).
pub fn parse(text: &str) -> Result<Vec<Finding>, String> {
    let value: Value = serde_json::from_str(text).map_err(|e| e.to_string())?;
    let items = value.as_array().ok_or("not an array")?;
    items
        .iter()
        .map(|item| {
            let field =
                |name: &str| item[name].as_str().map(str::to_owned).ok_or_else(|| format!("no {name} in {item}"));
            Ok(Finding { id: field("id")?, severity: field("severity")?, finding: field("finding")? })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn findings_are_read_from_the_flat_json_and_accepted_ones_pass() {
        let text = r#"[
            {"id": "TLS1_3", "ip": "198.18.0.2/198.18.0.2", "port": "802", "severity": "OK", "finding": "offered with final"},
            {"id": "cert_revocation", "ip": "198.18.0.2/198.18.0.2", "port": "802", "severity": "HIGH", "cwe": "", "finding": "Neither CRL nor OCSP URI provided"}
        ]"#;
        let findings = parse(text).unwrap();
        assert_eq!(findings.len(), 2);
        assert_eq!(findings[1].severity, "HIGH");
        let report = Report { findings, took: Duration::ZERO, json: PathBuf::from("x.json"), output: String::new() };
        assert_eq!(report.counts(), "HIGH 1, OK 1");
        let accepted = Accepted { id: "cert_revocation", finding: "Neither CRL", why: "no clock" };
        report.assert_no_high_or_critical(&[accepted]);
        let other = Accepted { id: "cert_revocation", finding: "something else", why: "" };
        let failed = std::panic::catch_unwind(|| report.assert_no_high_or_critical(&[other]));
        assert!(failed.is_err(), "an unaccepted HIGH finding fails");
    }
}
