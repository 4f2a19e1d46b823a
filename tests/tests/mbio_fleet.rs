//! `mbio` against a fleet of hal-sims in one namespace, on a bridge of
//! TAPs (system_tests::fleet): `mbio find` finds all five by mDNS, with
//! their names; a backup of one is restored onto another (the settings
//! compared through the API, the network left alone, the password never
//! in the file); points read and written by name, checked with pymodbus.
//! Needs root (namespaces), hal-sim and mbio built, curl, and python3 with
//! pymodbus; fails loudly without them.

use std::path::Path;

use serde_json::{Value, json};
use system_tests::OWNER_PASSWORD;
use system_tests::fleet::{Fleet, assert_exit};

fn stdout(output: &std::process::Output) -> String {
    String::from_utf8_lossy(&output.stdout).into_owned()
}

fn stderr(output: &std::process::Output) -> String {
    String::from_utf8_lossy(&output.stderr).into_owned()
}

#[test]
fn mbio_find_finds_all_five_with_their_names() {
    let names = ["cell-1", "cell-2", "cell-3", "press-4", "weld-5"];
    let fleet = Fleet::start(&names, &["--robot", "idle"]);
    let output = fleet.mbio(&["find", "--json", "--wait", "6"]);
    assert_exit(&output, 0);
    let found: Value = serde_json::from_str(&stdout(&output)).expect("find --json prints JSON");
    let found = found.as_array().expect("an array");
    let version = fleet.get(0, "/api/status")["device"]["firmware"].clone();
    for member in &fleet.members {
        let device = found
            .iter()
            .find(|d| d["name"] == member.name.as_str())
            .unwrap_or_else(|| panic!("{} not found: {found:?}", member.name));
        assert_eq!(device["address"], member.ip.to_string().as_str(), "{device}");
        assert_eq!(device["model"], "hal-sim", "{device}");
        assert_eq!(device["firmware"], version, "{device}");
        assert_eq!(device["robot_state"], "standby", "{device}");
        assert_eq!(device["link"], true, "{device}");
        assert_eq!(device["modbus_port"], 502, "{device}");
        assert_eq!(device["http_port"], 80, "{device}");
    }
    assert_eq!(found.len(), names.len(), "only the fleet: {found:?}");

    // The table a person reads: a line per device, with its address.
    let output = fleet.mbio(&["find", "--wait", "6"]);
    assert_exit(&output, 0);
    let table = stdout(&output);
    for member in &fleet.members {
        let line = table.lines().find(|l| l.contains(&member.name)).unwrap_or_else(|| panic!("{table}"));
        assert!(
            line.contains(&member.ip.to_string()) && line.contains("hal-sim") && line.contains("standby"),
            "{line}"
        );
    }
    // A name resolves through mDNS for the other commands.
    let output = fleet.mbio(&["status", "press-4", "--json"]);
    assert_exit(&output, 0);
    let status: Value = serde_json::from_str(&stdout(&output)).unwrap();
    assert_eq!(status["network"]["address"], format!("{}/24", fleet.members[3].ip).as_str());
    // One that is not there: exit 3.
    assert_exit(&fleet.mbio(&["status", "nobody-here", "--resolve-wait", "1"]), 3);
}

#[test]
fn a_backup_restored_onto_a_replacement_makes_it_the_same_device_but_its_network() {
    let mut fleet = Fleet::start(&["cell-1", "spare-9"], &["--robot", "idle"]);
    for member in &fleet.members {
        // A new device takes no change before its first password.
        assert_exit(&fleet.mbio(&["set", &member.ip.to_string(), "modbus.unit_id=7"]), 4);
        let output = fleet.mbio(&["password", &member.name]);
        assert_exit(&output, 0);
    }
    // A wrong password: 4, nothing changed.
    let wrong = std::env::temp_dir().join(format!("mbio-wrong-{}", std::process::id()));
    std::fs::write(&wrong, "not-the-password\n").unwrap();
    let output = fleet.mbio(&["--password-file", wrong.to_str().unwrap(), "set", "cell-1", "modbus.unit_id=9"]);
    std::fs::remove_file(&wrong).unwrap();
    assert_exit(&output, 4);

    // All or nothing: one bad field refuses the whole change, the device's message shown.
    let before = fleet.get(0, "/api/settings");
    let output = fleet.mbio(&["set", "cell-1", "modbus.idle_timeout_s=31", "modbus.unit_id=300"]);
    assert_exit(&output, 1);
    assert!(stderr(&output).contains("modbus.unit_id: any, or 1-247"), "{}", stderr(&output));
    assert_eq!(fleet.get(0, "/api/settings"), before, "a refused change saved something");

    let output = fleet.mbio(&[
        "set",
        "cell-1",
        "modbus.unit_id=7",
        "modbus.idle_timeout_s=30",
        "modbus.write_policy=strict",
        "modbus.allow_write=198.18.0.0/24",
        "watchdog.timeout_ms=1500",
        "watchdog.safe_do=0x8001",
        "robot.poll_ms=250",
        "network.gateway=198.18.0.1",
    ]);
    assert_exit(&output, 0);
    let output = fleet.mbio(&["get", "cell-1", "watchdog.safe_do"]);
    assert_exit(&output, 0);
    assert_eq!(stdout(&output).trim(), "32769");
    let source = fleet.get(0, "/api/settings");
    assert_eq!(source["network"]["gateway"], "198.18.0.1");

    // The backup: every setting, no secret.
    let output = fleet.mbio(&["backup", "cell-1"]);
    assert_exit(&output, 0);
    let file = std::env::temp_dir().join(format!("mbio-backup-{}.json", std::process::id()));
    std::fs::write(&file, &output.stdout).unwrap();
    let backup: Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(backup["mbio_backup"], 1);
    assert_eq!(backup["from"]["name"], "cell-1");
    let mut expected = source.clone();
    expected.as_object_mut().unwrap().remove("admin");
    assert_eq!(backup["settings"], expected, "the backup is the settings, less the admin group");
    assert!(!stdout(&output).contains(OWNER_PASSWORD) && !stdout(&output).contains("password"), "{}", stdout(&output));

    // cell-1 fails; its replacement, spare-9, takes its settings.
    fleet.members[0].kill();
    let spare = fleet.members[1].ip.to_string();
    let spare_before = fleet.get(1, "/api/settings");
    // Asked and refused (no terminal: the answer on stdin): nothing changes, exit 5.
    let output = fleet.mbio_with_input(&["restore", &spare, file.to_str().unwrap()], "n\n");
    assert_exit(&output, 5);
    assert!(
        stdout(&output).contains("modbus.unit_id") && stdout(&output).contains("device.name"),
        "the difference shown"
    );
    assert!(!stdout(&output).contains("network.gateway"), "the network is not restored without --network");
    assert_eq!(fleet.get(1, "/api/settings"), spare_before);

    let output = fleet.mbio(&["restore", &spare, file.to_str().unwrap(), "--yes"]);
    assert_exit(&output, 0);
    let restored = fleet.get(1, "/api/settings");
    for (group, fields) in source.as_object().unwrap() {
        let want = if group == "network" { &spare_before[group] } else { fields };
        assert_eq!(&restored[group], want, "group {group}");
    }
    assert_eq!(restored["network"]["gateway"], "none", "the network left alone");
    // The replacement answers to the old name now.
    let output = fleet.mbio(&["status", "cell-1", "--json"]);
    assert_exit(&output, 0);
    let status: Value = serde_json::from_str(&stdout(&output)).unwrap();
    assert_eq!(status["network"]["address"], format!("{spare}/24").as_str());
    // Nothing left to restore: exit 0 with nothing asked.
    let output = fleet.mbio(&["restore", &spare, file.to_str().unwrap()]);
    assert_exit(&output, 0);
    assert!(stdout(&output).contains("nothing to change"), "{}", stdout(&output));
    // --network restores the gateway too.
    let output = fleet.mbio(&["restore", &spare, file.to_str().unwrap(), "--yes", "--network"]);
    assert_exit(&output, 0);
    assert_eq!(fleet.get(1, "/api/settings")["network"]["gateway"], "198.18.0.1");
    std::fs::remove_file(&file).unwrap();
}

/// Runs pymodbus (tests/peers/pymodbus_json.py) on `requests` in the fleet's namespace.
fn pymodbus(fleet: &Fleet, ip: &str, requests: Value) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("peers/pymodbus_json.py");
    let output = fleet.ns().command("python3").arg(&script).args([ip, "502", &requests.to_string()]).output().unwrap();
    assert!(output.status.success(), "pymodbus: {}\n{}", stdout(&output), stderr(&output));
    serde_json::from_str(stdout(&output).trim()).unwrap()
}

#[test]
fn points_read_and_written_by_name_are_what_pymodbus_sees() {
    let probe = std::process::Command::new("python3").args(["-c", "import pymodbus"]).output();
    assert!(
        probe.as_ref().is_ok_and(|o| o.status.success()),
        "this test needs python3 with pymodbus: `pip install pymodbus` ({probe:?})"
    );
    let fleet = Fleet::start(&["cell-3"], &["--robot", "idle"]);
    let ip = fleet.members[0].ip.to_string();

    // Writes by name, then read back by pymodbus from the map's addresses.
    let write = |last: &str| {
        let points =
            ["do.3=on", "do.16=on", "tool_do.2=on", "ao.1.type=voltage", "ao.1=7.5", "ao.2=12.25", "gp.1=1234"];
        let args: Vec<&str> = ["write", "cell-3"].into_iter().chain(points).chain([last]).collect();
        fleet.mbio(&args)
    };
    // gp is unsigned: -1 is refused before anything is sent.
    assert_exit(&write("gp.128=-1"), 2);
    assert_eq!(pymodbus(&fleet, &ip, json!([["read_holding", 1, 1]])), json!([[0]]), "nothing written");
    let output = write("gp.128=65535");
    assert_exit(&output, 0);
    let seen = pymodbus(
        &fleet,
        &ip,
        json!([
            ["read_holding", 1, 1],
            ["read_coils", 16, 16],
            ["read_holding", 16, 4],
            ["read_holding", 22, 1],
            ["read_holding", 128, 1],
            ["read_holding", 255, 1]
        ]),
    );
    assert_eq!(seen[0], json!([0x8004]), "do.3 and do.16");
    let coils: Vec<bool> = (1..=16).map(|n| n == 3 || n == 16).collect();
    assert_eq!(seen[1], json!(coils));
    assert_eq!(seen[2], json!([7500, 1, 12250, 0]), "ao.1 7.5 V, ao.2 12.25 mA");
    assert_eq!(seen[3], json!([0b10]), "tool_do.2");
    assert_eq!(seen[4], json!([1234]));
    assert_eq!(seen[5], json!([65535]));
    // A value out of the point's range is the tool's usage error, before a write: 10 V is the most.
    assert_exit(&fleet.mbio(&["write", "cell-3", "ao.1=10.5"]), 2);
    // A read-only point is refused by name.
    assert_exit(&fleet.mbio(&["write", "cell-3", "di.1=on"]), 2);

    // Written by pymodbus, read by name.
    assert_eq!(fleet.members[0].control("set di 5 1"), "ok");
    assert_eq!(
        pymodbus(&fleet, &ip, json!([["write_coil", 16, false], ["write_register", 129, 42]])),
        json!(["ok", "ok"])
    );
    let output = fleet.mbio(&[
        "read",
        "cell-3",
        "--json",
        "do.3",
        "do.1",
        "di",
        "di.5",
        "gp.2",
        "ao.1",
        "ao.1.type",
        "robot.joint_position",
        "robot.state",
        "robot.joint_current.2",
    ]);
    assert_exit(&output, 0);
    let read: Value = serde_json::from_str(&stdout(&output)).unwrap();
    assert_eq!(read["do.3"], true);
    assert_eq!(read["do.1"], false);
    assert_eq!(read["di.5"], true);
    assert_eq!(read["di"][4], true);
    assert_eq!(read["gp.2"]["value"], 42.0);
    assert_eq!(read["ao.1"], json!({"value": 7.5, "unit": "V"}));
    assert_eq!(read["ao.1.type"], "voltage");
    assert_eq!(read["robot.state"]["name"], "standby");
    // The joints: pymodbus's registers (signed, 0.1 degree) are mbio's degrees.
    let raw = pymodbus(&fleet, &ip, json!([["read_holding", 270, 6], ["read_holding", 291, 1]]));
    let degrees: Vec<f64> =
        raw[0].as_array().unwrap().iter().map(|v| f64::from(v.as_u64().unwrap() as u16 as i16) / 10.0).collect();
    assert_eq!(read["robot.joint_position"], json!({"values": degrees, "unit": "deg"}));
    assert_eq!(read["robot.joint_current.2"]["value"], raw[1][0].as_f64().unwrap());
    assert_eq!(read["robot.joint_current.2"]["unit"], "mA");
    // And as a person reads it: six joints in degrees.
    let output = fleet.mbio(&["read", "cell-3", "robot.joint_position"]);
    assert_exit(&output, 0);
    let text = stdout(&output);
    for (n, degrees) in degrees.iter().enumerate() {
        assert!(text.contains(&format!("robot.joint_position.{} = {degrees} deg", n + 1)), "{text}");
    }
    assert_exit(&fleet.mbio(&["read", "cell-3", "robot.nothing"]), 2);
}
