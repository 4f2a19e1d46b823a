//! hal-sim's command line: bad arguments are refused with a reason (never a
//! panic), and a TAP that cannot be opened names the missing privilege and
//! the command that fixes it. Each run happens inside a namespace of its own,
//! so even a run that got as far as opening a TAP would stay inside it.

use std::process::Output;

use system_tests::hal_sim::binary;
use system_tests::netns::{Namespace, TAP};

fn hal_sim(ns: &Namespace, args: &[&str]) -> Output {
    ns.command("timeout").arg("10").arg(binary()).args(args).output().unwrap()
}

fn stderr(output: &Output) -> String {
    String::from_utf8_lossy(&output.stderr).into_owned()
}

#[test]
fn bad_arguments_are_refused_with_a_reason() {
    let ns = Namespace::new().unwrap();
    for (args, reason) in [
        (&[][..], "`--tap NAME` is required"),
        (&["--tap"][..], "needs a value"),
        (&["--tap", TAP, "--port", "0"][..], "`--port` must be 1-65535"),
        (&["--tap", TAP, "--port", "502x"][..], "not `502x`"),
        (&["--tap", TAP, "--ip", "198.18.0.999/24"][..], "`--ip` must be none, or an IPv4 address"),
        (&["--tap", TAP, "--max-connections", "100"][..], "MODBUS_MAX_CONNECTIONS"),
        (&["--tap", TAP, "--write-policy", "loose"][..], "seed or strict"),
        (&["--tap", TAP, "--robot", "fast"][..], "demo or idle"),
        (&["--tap", TAP, "--unit-id", "-1"][..], "--unit-id"),
        (&["--tap", "a-name-much-too-long"][..], "at most 15 bytes"),
        (&["--tap", TAP, "--verbose"][..], "unknown option `--verbose`"),
    ] {
        let output = hal_sim(&ns, args);
        let text = stderr(&output);
        assert_eq!(output.status.code(), Some(2), "{args:?}: {text}");
        assert!(text.contains(reason), "{args:?}: {text}");
        assert!(text.contains("usage: hal-sim --tap NAME"), "{args:?}: {text}");
        assert!(!text.contains("panicked"), "{args:?}: {text}");
    }
}

#[test]
fn help_and_version_exit_zero() {
    let ns = Namespace::new().unwrap();
    let help = hal_sim(&ns, &["--help"]);
    assert!(help.status.success());
    let text = String::from_utf8_lossy(&help.stdout);
    for option in [
        "--tap",
        "--ip",
        "--gateway",
        "--port",
        "--max-connections",
        "--idle-timeout",
        "--unit-id",
        "--write-policy",
        "--control",
        "--robot",
    ] {
        assert!(text.contains(option), "{option} in --help");
    }
    let version = hal_sim(&ns, &["--version"]);
    assert!(version.status.success());
    let text = String::from_utf8_lossy(&version.stdout);
    assert!(text.starts_with("hal-sim ") && text.contains("(firmware "), "{text}");
}

#[test]
fn a_tap_that_cannot_be_opened_names_the_privilege_and_the_fix() {
    let ns = Namespace::new().unwrap();
    // A TAP that belongs to root (a TAP with no owner lets anyone attach),
    // opened by an ordinary user with no capabilities: TUNSETIFF refuses.
    ns.ip(&["tuntap", "del", "dev", TAP, "mode", "tap"]).unwrap();
    ns.ip(&["tuntap", "add", "dev", TAP, "mode", "tap", "user", "0", "group", "0"]).unwrap();
    let output = ns
        .command("setpriv")
        .args(["--reuid=65534", "--regid=65534", "--clear-groups", "--inh-caps=-all", "--bounding-set=-all"])
        .args(["timeout", "10"])
        .arg(binary())
        .args(["--tap", TAP])
        .output()
        .unwrap();
    let text = stderr(&output);
    assert_eq!(output.status.code(), Some(1), "{text}");
    assert!(text.contains("cannot open TAP tap0"), "{text}");
    assert!(text.contains("CAP_NET_ADMIN"), "{text}");
    assert!(text.contains("ip tuntap add dev tap0 mode tap user $USER"), "{text}");
    assert!(!text.contains("panicked"), "{text}");
}

#[test]
fn a_control_socket_in_use_is_refused() {
    let ns = Namespace::new().unwrap();
    let path = std::env::temp_dir().join(format!("{}.busy.sock", ns.name()));
    let _listener = std::os::unix::net::UnixListener::bind(&path).unwrap();
    let output = hal_sim(&ns, &["--tap", TAP, "--control", path.to_str().unwrap()]);
    let _ = std::fs::remove_file(&path);
    let text = stderr(&output);
    assert_eq!(output.status.code(), Some(1), "{text}");
    assert!(text.contains("cannot open the control socket"), "{text}");
}
