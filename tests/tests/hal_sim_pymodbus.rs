//! A second independent client: pymodbus runs tests/peers/pymodbus_smoke.py
//! inside hal-sim's namespace. Needs `pip install pymodbus`; fails loudly
//! without it.

use std::path::Path;
use std::process::Command;

use system_tests::hal_sim::{HalSim, PORT};
use system_tests::netns::DEVICE_IP;

#[test]
fn pymodbus_smoke() {
    let probe = Command::new("python3").args(["-c", "import pymodbus"]).output();
    assert!(
        probe.as_ref().is_ok_and(|o| o.status.success()),
        "this test needs python3 with pymodbus: `pip install pymodbus` ({probe:?})"
    );
    let sim = HalSim::start(&["--robot", "idle"]);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("peers/pymodbus_smoke.py");
    let output = sim
        .ns()
        .command("python3")
        .arg(&script)
        .args([DEVICE_IP, &PORT.to_string()])
        .arg(sim.control_path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    println!("{stdout}");
    assert!(output.status.success(), "pymodbus smoke failed:\n{stdout}\n{}", String::from_utf8_lossy(&output.stderr));
    assert!(stdout.contains(" passed, 0 failed"), "{stdout}");
}
