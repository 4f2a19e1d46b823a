//! The robot link (docs/robot-link.md) against independent controllers:
//! pymodbus's server and a plain asyncio one that misbehaves on purpose
//! (tests/peers/robot_controller.py), and a second hal-sim in demo mode.
//!
//! The controller runs in hal-sim's namespace at the TAP's host side,
//! 198.18.0.1; a second hal-sim gets a TAP of its own (198.18.1.0/24) and
//! the namespace routes between the two. A master (tokio-modbus) reads the
//! robot's points through hal-sim all along, and every read it makes must
//! be of one poll: the controller writes one generation into every
//! telemetry register of a snapshot, so a read that mixes two polls shows.

use std::process::{Child, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use system_tests::controller::{CONTROLLER_IP, Controller};
use system_tests::hal_sim::{HalSim, controller_version};
use tokio_modbus::client::Context;
use tokio_modbus::prelude::*;

/// The period the tests poll at.
const POLL_MS: u64 = 100;
/// The longest a master's read may take: it must never wait for the link.
const MASTER_WAIT: Duration = Duration::from_secs(2);
/// How long a change of the link (down, back) may take to show: generous,
/// the back-off reaches 5 s and the machine may be loaded.
const SETTLE: Duration = Duration::from_secs(20);
/// The controller's version (tests/peers/robot_controller.py).
const PEER_VERSION: [u16; 3] = [2, 11, 3];
/// Robot state NOT READY.
const NOT_READY: u16 = 15;

/// The controller's generation now (the wall clock in 10 ms steps, mod 65536).
fn generation_now() -> u16 {
    let ms = SystemTime::now().duration_since(UNIX_EPOCH).unwrap().as_millis();
    ((ms / 10) & 0xffff) as u16
}

/// The age of a value of generation `g`.
fn age(g: u16) -> Duration {
    Duration::from_millis(u64::from(generation_now().wrapping_sub(g)) * 10)
}

/// Registers 256-315 and 400-435 as one master reads them, each read within
/// [`MASTER_WAIT`].
#[derive(Debug, Clone)]
struct Robot {
    head: Vec<u16>,
    task: Vec<u16>,
}

impl Robot {
    fn state(&self) -> u16 {
        self.head[3]
    }

    fn version(&self) -> [u16; 3] {
        [self.head[0], self.head[1], self.head[2]]
    }

    /// The telemetry registers of the head read (the reserved ones left out).
    fn joints(&self) -> Vec<u16> {
        (270u16..=315).filter(|a| (a - 270) % 10 < 6).map(|a| self.head[usize::from(a - 256)]).collect()
    }

    /// The registers of the task read (the reserved ones left out).
    fn tasks(&self) -> Vec<u16> {
        (400u16..=435).filter(|a| (a - 400) % 10 < 6).map(|a| self.task[usize::from(a - 400)]).collect()
    }

    /// The reserved registers read 0 whatever the controller sent.
    fn reserved_are_zero(&self) -> bool {
        let head = (265u16..=315).filter(|&a| a < 270 || (a - 270) % 10 >= 6).map(|a| self.head[usize::from(a - 256)]);
        let task = (400u16..=435).filter(|a| (a - 400) % 10 >= 6).map(|a| self.task[usize::from(a - 400)]);
        head.chain(task).all(|v| v == 0)
    }

    /// Down: NOT READY, every flag, version and telemetry register 0.
    fn is_no_source(&self) -> bool {
        self.state() == NOT_READY
            && self.head.iter().enumerate().all(|(i, &v)| i == 3 || v == 0)
            && self.task.iter().all(|&v| v == 0)
    }

    /// Each read is of one poll of a generation-writing controller: all its
    /// telemetry registers carry one generation, or the link is down. The
    /// two reads (256-315, 400-435) are two requests, so the link may change
    /// between them: each is judged on its own.
    fn check_one_poll(&self) {
        assert!(self.reserved_are_zero(), "reserved registers must read 0: {self:?}");
        let tasks = self.tasks();
        assert!(tasks.iter().all(|&v| v == tasks[0]), "a read of 400-435 mixes polls: {tasks:?}");
        if self.state() == NOT_READY {
            let head_zero = self.head.iter().enumerate().all(|(i, &v)| i == 3 || v == 0);
            assert!(head_zero, "NOT READY with values left over in the same read: {self:?}");
            return;
        }
        let joints = self.joints();
        assert!(joints.iter().all(|&v| v == joints[0]), "a read of 270-315 mixes polls: {joints:?}");
        assert_eq!(self.version(), PEER_VERSION);
        assert_eq!(&self.head[3..9], &[2, 1, 0, 0, 0, 1], "state and flags as the controller has them");
    }
}

async fn read(ctx: &mut Context, start: u16, count: u16) -> Vec<u16> {
    match tokio::time::timeout(MASTER_WAIT, ctx.read_holding_registers(start, count)).await {
        Ok(Ok(Ok(values))) => values,
        Ok(other) => panic!("read {start}+{count}: {other:?}"),
        Err(_) => panic!("read {start}+{count}: no answer within {MASTER_WAIT:?}: the link slows the masters"),
    }
}

async fn read_robot(ctx: &mut Context) -> Robot {
    Robot { head: read(ctx, 256, 60).await, task: read(ctx, 400, 36).await }
}

/// Reads until `done` holds (checking every read with `check`), within [`SETTLE`].
async fn wait_for(ctx: &mut Context, what: &str, check: fn(&Robot), done: impl Fn(&Robot) -> bool) -> Robot {
    let deadline = Instant::now() + SETTLE;
    loop {
        let robot = read_robot(ctx).await;
        check(&robot);
        if done(&robot) {
            return robot;
        }
        assert!(Instant::now() < deadline, "{what}: not within {SETTLE:?}; last read {robot:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

fn no_check(_: &Robot) {}

fn up(robot: &Robot) -> bool {
    robot.state() != NOT_READY
}

fn link_status(sim: &HalSim) -> serde_json::Value {
    let status = sim.get("/api/status").json();
    status["robot"].clone()
}

#[test]
fn a_pymodbus_controller_is_mirrored_and_its_life_followed() {
    let link = format!("{CONTROLLER_IP}:1502");
    let poll = POLL_MS.to_string();
    let sim = HalSim::start(&["--robot-link", &link, "--robot-poll-ms", &poll]);
    // hal-sim first: the link is down and NOT READY while nobody answers.
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        wait_for(&mut ctx, "NOT READY without a controller", Robot::check_one_poll, Robot::is_no_source).await;
    });
    assert_eq!(link_status(&sim)["source"], "link");
    assert_eq!(link_status(&sim)["link"]["connected"], false);

    let mut controller = Controller::start(sim.ns(), 1502, "pymodbus");
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        wait_for(&mut ctx, "the link up", Robot::check_one_poll, up).await;
        // The values arrive within 2 x poll_ms: the freshest of a series of
        // reads is at most a poll and its round trip old.
        let mut freshest = Duration::MAX;
        for _ in 0..30 {
            let robot = read_robot(&mut ctx).await;
            robot.check_one_poll();
            freshest = freshest.min(age(robot.joints()[0]));
            tokio::time::sleep(Duration::from_millis(37)).await;
        }
        assert!(freshest <= Duration::from_millis(2 * POLL_MS), "values {freshest:?} old at best");
    });
    let robot = link_status(&sim);
    assert_eq!(robot["source"], "link");
    assert_eq!(robot["link"]["connected"], true, "{robot}");
    assert!(robot["link"]["polls"].as_u64().unwrap() > 10, "{robot}");
    assert!(robot["link"]["last_ok_ms"].as_u64().unwrap() < 2000, "{robot}");
    let stats = sim.stats();
    assert!(stats["robot_polls"] > 10, "{stats:?}");

    // Paused: the polls time out, the link goes down; and back on SIGCONT.
    controller.signal(libc::SIGSTOP);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        wait_for(&mut ctx, "down while the controller is stopped", Robot::check_one_poll, Robot::is_no_source).await;
    });
    assert!(sim.stats()["robot_link_downs"] >= 1);
    assert_eq!(link_status(&sim)["link"]["connected"], false);
    controller.signal(libc::SIGCONT);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        wait_for(&mut ctx, "back after SIGCONT", Robot::check_one_poll, up).await;
    });

    // Killed: down; started again: back.
    controller.kill();
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        wait_for(&mut ctx, "down once the controller is gone", Robot::check_one_poll, Robot::is_no_source).await;
    });
    let _controller = Controller::start(sim.ns(), 1502, "pymodbus");
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        wait_for(&mut ctx, "back with a new controller", Robot::check_one_poll, up).await;
    });
    let errors = link_status(&sim)["link"]["errors"].as_u64().unwrap();
    assert!(errors >= 3, "the failed polls are counted: {errors}");
    assert!(!sim.log().contains("panicked"), "{}", sim.log());
}

#[test]
fn bad_controllers_give_errors_and_not_ready_and_never_torn_data() {
    let poll = POLL_MS.to_string();
    let sim = HalSim::start(&["--robot-poll-ms", &poll, "--robot", "idle"]);
    assert_eq!(link_status(&sim)["source"], "sim");
    assert!(link_status(&sim)["link"].is_null());
    let modes = ["good", "exception", "wrong-tid", "short", "garbage", "slow", "flaky"];
    let controllers: Vec<Controller> =
        modes.iter().zip(1600u16..).map(|(mode, port)| Controller::start(sim.ns(), port, mode)).collect();
    for (mode, port) in modes.iter().zip(1600u16..) {
        // The setting changes at once, through the API, without a reboot.
        let body = format!(r#"{{"robot": {{"link": "{CONTROLLER_IP}:{port}"}}}}"#);
        let reply = sim.put("/api/settings", &body, Some(sim.claim()));
        assert_eq!(reply.status, 200, "{mode}: {reply:?}");
        let before = link_status(&sim)["link"]["errors"].as_u64().unwrap_or(0);
        match *mode {
            "good" => sim.run(|| async {
                let mut ctx = sim.connect().await;
                wait_for(&mut ctx, "up with a good controller", Robot::check_one_poll, up).await;
            }),
            "flaky" => sim.run(|| async {
                // Good replies and bad ones mixed: the link may go down and
                // up, but every read is of one poll, and good polls arrive.
                let mut ctx = sim.connect().await;
                let deadline = Instant::now() + Duration::from_secs(5);
                let mut good = 0;
                while Instant::now() < deadline {
                    let robot = read_robot(&mut ctx).await;
                    robot.check_one_poll();
                    good += usize::from(up(&robot));
                    tokio::time::sleep(Duration::from_millis(10)).await;
                }
                assert!(good > 0, "a flaky controller's good replies are used");
            }),
            _ => sim.run(|| async {
                // Down from the change on, and it stays down while the
                // errors are counted, with the masters answered all along.
                let mut ctx = sim.connect().await;
                let before = sim.stats()["robot_errors"];
                let deadline = Instant::now() + SETTLE;
                loop {
                    let robot = read_robot(&mut ctx).await;
                    assert!(robot.is_no_source(), "{mode}: {robot:?}");
                    if sim.stats()["robot_errors"] >= before + 3 {
                        break;
                    }
                    assert!(Instant::now() < deadline, "{mode}: fewer than 3 errors in {SETTLE:?}");
                    tokio::time::sleep(Duration::from_millis(25)).await;
                }
            }),
        }
        let robot = link_status(&sim);
        assert_eq!(robot["source"], "link", "{mode}");
        let errors = robot["link"]["errors"].as_u64().unwrap();
        if *mode != "good" {
            assert!(errors >= before + 3, "{mode}: errors {before} -> {errors}");
        }
    }
    // No link: the simulated robot again (idle: STANDBY, 1).
    let reply = sim.put("/api/settings", r#"{"robot": {"link": "none"}}"#, Some(sim.claim()));
    assert_eq!(reply.status, 200, "{reply:?}");
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        wait_for(&mut ctx, "the simulated robot back", no_check, |r| r.state() == 1).await;
    });
    assert_eq!(link_status(&sim)["source"], "sim");
    drop(controllers);
    assert!(!sim.log().contains("panicked"), "{}", sim.log());
}

#[test]
fn a_demo_hal_sim_is_a_controller() {
    let poll = POLL_MS.to_string();
    let sim = HalSim::start(&["--robot-link", "198.18.1.2", "--robot-poll-ms", &poll, "--gateway", CONTROLLER_IP]);
    // The controller: a second hal-sim on a second TAP in the same namespace, routed.
    let ns = sim.ns();
    ns.ip(&["tuntap", "add", "dev", "tap1", "mode", "tap"]).unwrap();
    ns.ip(&["addr", "add", "198.18.1.1/24", "dev", "tap1"]).unwrap();
    ns.ip(&["link", "set", "tap1", "up"]).unwrap();
    let forwarding = ns.command("sysctl").args(["-qw", "net.ipv4.ip_forward=1"]).status().unwrap();
    assert!(forwarding.success());
    let log = std::env::temp_dir().join(format!("{}.controller.log", ns.name()));
    let mut demo = ns
        .command(system_tests::hal_sim::binary())
        .args(["--tap", "tap1", "--ip", "198.18.1.2/24", "--gateway", "198.18.1.1", "--http-port", "0"])
        .args(["--robot", "demo"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log).unwrap())
        .spawn()
        .unwrap();
    let kill = |child: &mut Child| {
        let _ = child.kill();
        let _ = child.wait();
    };
    let seen = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        sim.run(|| async {
            let mut ctx = sim.connect().await;
            let first = wait_for(&mut ctx, "the demo robot mirrored", no_check, |r| {
                r.version() == controller_version() && r.state() == 2
            })
            .await;
            // The demo robot moves: its joints change from poll to poll.
            wait_for(&mut ctx, "the demo robot moving", no_check, |r| r.joints() != first.joints()).await;
        })
    }));
    let robot = link_status(&sim);
    kill(&mut demo);
    if let Err(panic) = seen {
        eprintln!("controller's log:\n{}", std::fs::read_to_string(&log).unwrap_or_default());
        eprintln!("gateway's log:\n{}", sim.log());
        std::panic::resume_unwind(panic);
    }
    assert_eq!(robot["source"], "link");
    assert_eq!(robot["link"]["connected"], true, "{robot}");
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        wait_for(&mut ctx, "down once the controller is gone", no_check, Robot::is_no_source).await;
    });
    let _ = std::fs::remove_file(&log);
}
