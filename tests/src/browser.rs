//! The page in a real browser: Debian's chromium driven by playwright-core
//! (node scripts in tests/browser/), for the page tests of hal-sim and of
//! the QEMU image.

use std::io::Read as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Where Debian's chromium is (the script launches it by this path).
pub const CHROMIUM: &str = "/usr/bin/chromium";
/// The most a browser run may take (the hal-sim page test takes about 10 s).
pub const BROWSER_TIMEOUT: Duration = Duration::from_secs(120);

/// tests/browser: the scripts and their node_modules.
pub fn browser_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("browser")
}

/// target/artifacts of this workspace (git-ignored).
pub fn artifacts() -> PathBuf {
    let target = match std::env::var_os("CARGO_TARGET_DIR") {
        Some(dir) => PathBuf::from(dir),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join("target"),
    };
    let dir = target.join("artifacts");
    std::fs::create_dir_all(&dir).expect("target/artifacts");
    dir
}

/// Fails loudly, saying what to install, unless node, chromium and
/// playwright-core are there.
pub fn require_browser() {
    let node = Command::new("node").arg("--version").output();
    assert!(
        node.as_ref().is_ok_and(|o| o.status.success()),
        "this test needs node (apt-get install nodejs npm; scripts/setup does it): {node:?}"
    );
    assert!(
        Path::new(CHROMIUM).is_file(),
        "this test needs {CHROMIUM} (apt-get install chromium; scripts/setup does it)"
    );
    for package in ["playwright-core", "axe-core"] {
        assert!(
            browser_dir().join("node_modules").join(package).join("package.json").is_file(),
            "this test needs {package} in tests/browser/node_modules: run `npm ci` in tests/browser (scripts/setup does it)"
        );
    }
}

/// Runs `command` to its end or kills it after `limit`: status, stdout, stderr.
pub fn run_within(mut command: Command, limit: Duration) -> (bool, String, String) {
    let mut child = command.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("the browser script starts");
    let mut stdout = child.stdout.take().expect("stdout");
    let mut stderr = child.stderr.take().expect("stderr");
    let out = std::thread::spawn(move || {
        let mut text = String::new();
        let _ = stdout.read_to_string(&mut text);
        text
    });
    let err = std::thread::spawn(move || {
        let mut text = String::new();
        let _ = stderr.read_to_string(&mut text);
        text
    });
    let deadline = Instant::now() + limit;
    let status = loop {
        if let Some(status) = child.try_wait().expect("the browser script can be waited on") {
            break Some(status);
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let (stdout, mut stderr) = (out.join().unwrap_or_default(), err.join().unwrap_or_default());
    if status.is_none() {
        stderr.push_str(&format!("\n(killed after {limit:?})"));
    }
    (status.is_some_and(|s| s.success()), stdout, stderr)
}

/// [`artifacts`], with the screenshots `names` of an earlier run removed
/// (a failed run must not leave one that looks like this run's).
pub fn fresh_artifacts(names: &[&str]) -> PathBuf {
    fresh_artifacts_in("", names)
}

/// [`fresh_artifacts`] in the subdirectory `sub` of [`artifacts`] (made if missing).
pub fn fresh_artifacts_in(sub: &str, names: &[&str]) -> PathBuf {
    let dir = artifacts().join(sub);
    std::fs::create_dir_all(&dir).expect("an artifacts directory");
    for name in names {
        let _ = std::fs::remove_file(dir.join(name));
    }
    dir
}

/// The script's summary: the last line of its stdout that is JSON,
/// printed for the test's log.
pub fn summary(stdout: &str) -> serde_json::Value {
    let summary = stdout
        .lines()
        .rev()
        .find_map(|line| serde_json::from_str(line).ok())
        .unwrap_or_else(|| panic!("the script's summary: {stdout}"));
    println!("browser: {summary}");
    summary
}
