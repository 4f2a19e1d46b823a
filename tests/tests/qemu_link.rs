//! The robot link on the mps2-an386 image (feature `robot-link`, on by
//! default there): QEMU on a TAP in a network namespace, the controller
//! (pymodbus's server, tests/peers/robot_controller.py) on the namespace's
//! side of the TAP, 198.18.0.1. The link is set through the HTTP API, at
//! once; a master reads the controller's values through the firmware, then
//! NOT READY once the controller is gone. Needs root, QEMU and the image.

use std::time::{Duration, Instant};

use system_tests::OWNER_PASSWORD;
use system_tests::controller::{CONTROLLER_IP, Controller};
use system_tests::qemu::{NO_ROBOT, Qemu, ROBOT_REGISTERS};
use tokio_modbus::client::Reader as _;

/// How long a change may take to show (the firmware's DHCP attempt, the back-off).
const SETTLE: Duration = Duration::from_secs(30);

async fn wait_for(ctx: &mut tokio_modbus::client::Context, what: &str, done: impl Fn(&[u16]) -> bool) -> Vec<u16> {
    let deadline = Instant::now() + SETTLE;
    loop {
        let head = ctx.read_holding_registers(ROBOT_REGISTERS, 60).await.unwrap().unwrap();
        if done(&head) {
            return head;
        }
        assert!(Instant::now() < deadline, "{what}: not within {SETTLE:?}; last read {head:?}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[test]
fn the_image_mirrors_a_controller_on_the_host_side() {
    let qemu = Qemu::tap();
    let ns = qemu.ns().expect("a TAP QEMU has a namespace");
    let mut controller = Controller::start(ns, 1502, "pymodbus");
    qemu.run(|| async {
        let mut ctx = qemu.connect().await;
        let robot = ctx.read_holding_registers(ROBOT_REGISTERS, 4).await.unwrap().unwrap();
        assert_eq!(robot, NO_ROBOT, "no link set: no robot");
    });
    // The owner's first password, then the change with it.
    let put = |path: &str, body: &str, credentials: &[&str]| {
        let output = ns
            .command("curl")
            .args(["-sS", "--max-time", "10", "-X", "PUT", "-H", "Content-Type: application/json"])
            .args(credentials)
            .args(["--data-binary", body, "-w", "\n%{http_code}", &format!("http://198.18.0.2{path}")])
            .output()
            .unwrap();
        let reply = String::from_utf8_lossy(&output.stdout).into_owned();
        assert!(reply.ends_with("\n200"), "PUT {path}: {reply} {}", String::from_utf8_lossy(&output.stderr));
    };
    put("/api/password", &format!(r#"{{"password": "{OWNER_PASSWORD}"}}"#), &[]);
    let body = format!(r#"{{"robot": {{"link": "{CONTROLLER_IP}:1502", "poll_ms": 100}}}}"#);
    put("/api/settings", &body, &["-u", &format!("admin:{OWNER_PASSWORD}")]);
    qemu.run(|| async {
        let mut ctx = qemu.connect().await;
        let head = wait_for(&mut ctx, "the controller's values", |head| head[3] == 2).await;
        assert_eq!(&head[..9], &[2, 11, 3, 2, 1, 0, 0, 0, 1], "version, state and flags");
        let joints: Vec<u16> = (14..60).filter(|i| (i - 14) % 10 < 6).map(|i| head[i]).collect();
        assert!(joints.iter().all(|&v| v == joints[0]), "one poll: {joints:?}");
    });
    controller.kill();
    qemu.run(|| async {
        let mut ctx = qemu.connect().await;
        let head = wait_for(&mut ctx, "NOT READY once the controller is gone", |head| head[3] == 15).await;
        assert!(head.iter().enumerate().all(|(i, &v)| i == 3 || v == 0), "zeros: {head:?}");
    });
    let log = qemu.finish();
    assert!(log.contains("robot link: up"), "{log}");
    assert!(log.contains("robot link: down"), "{log}");
}
