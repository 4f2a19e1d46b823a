//! hal-sim's simulated board seen through tokio-modbus: inputs set on the
//! control socket, outputs read back on it, and the simulated robot
//! (telemetry every 100 ms, e-stop and safety stops, buttons).

use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::time::{Duration, Instant};

use system_tests::hal_sim::HalSim;
use tokio_modbus::client::Context;
use tokio_modbus::prelude::*;

async fn registers(ctx: &mut Context, start: u16, count: u16) -> Vec<u16> {
    ctx.read_holding_registers(start, count).await.unwrap().unwrap()
}

async fn coils(ctx: &mut Context, start: u16, count: u16) -> Vec<bool> {
    ctx.read_coils(start, count).await.unwrap().unwrap()
}

fn signed(values: &[u16]) -> Vec<i16> {
    values.iter().map(|&v| v as i16).collect()
}

/// The period of the refresh that writes the telemetry (100 ms).
const REFRESH: Duration = Duration::from_micros(adapter::device::REFRESH_PERIOD.as_micros());
/// Refreshes the demo telemetry test watches.
const REFRESHES: u32 = 12;
/// They take 1.2 s at one per 100 ms; twice that leaves room for a loaded machine.
const REFRESHES_WITHIN: Duration = REFRESH.saturating_mul(2 * REFRESHES);

/// The joint block (270-315) and the task block (400-435) of one refresh. They
/// take two requests, and a refresh may fall between them: the joint block is
/// read again after the task block until it has not changed.
async fn telemetry(ctx: &mut Context) -> (Vec<u16>, Vec<u16>) {
    let mut joints = registers(ctx, 270, 46).await;
    loop {
        let task = registers(ctx, 400, 36).await;
        let again = registers(ctx, 270, 46).await;
        if again == joints {
            return (joints, task);
        }
        joints = again;
    }
}

#[test]
fn inputs_set_on_the_control_socket_are_visible_at_once_in_both_views() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        assert_eq!(sim.control("set di 1 1"), "ok");
        assert_eq!(sim.control("set di 16 1"), "ok");
        assert_eq!(sim.control("set di 5 1"), "ok");
        // At once: no wait for the 100 ms refresh.
        assert_eq!(registers(&mut ctx, 0, 1).await, [0x8011]);
        let expected: Vec<bool> = (0..16).map(|bit| 0x8011 & (1 << bit) != 0).collect();
        assert_eq!(coils(&mut ctx, 0, 16).await, expected);
        assert_eq!(sim.control("set di 5 0"), "ok");
        assert_eq!(registers(&mut ctx, 0, 1).await, [0x8001]);
        assert!(!coils(&mut ctx, 4, 1).await[0]);

        assert_eq!(sim.control("set tool-di 1 1"), "ok");
        assert_eq!(sim.control("set tool-di 6 1"), "ok");
        assert_eq!(registers(&mut ctx, 21, 1).await, [0b10_0001]);
        assert_eq!(coils(&mut ctx, 32, 6).await, [true, false, false, false, false, true]);
        assert_eq!(sim.control_ok("get di"), "32769");
        assert_eq!(sim.control_ok("get tool-di"), "33");

        // They stay: the refresh re-asserts the pins, not a stale copy.
        tokio::time::sleep(Duration::from_millis(350)).await;
        assert_eq!(registers(&mut ctx, 0, 1).await, [0x8001]);
        assert_eq!(registers(&mut ctx, 21, 1).await, [0b10_0001]);
    });
}

#[test]
fn analog_inputs_follow_the_type_the_master_selects() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        assert_eq!(sim.control("set ai 1 12000"), "ok");
        assert_eq!(sim.control("set ai 2 25000"), "ok");
        // Current mode: µA up to 20 000 (a reading beyond the range is clamped).
        assert_eq!(registers(&mut ctx, 4, 4).await, [12_000, 0, 20_000, 0]);
        assert_eq!(sim.control_ok("get ai 1"), "12000 0");
        // Voltage mode: mV up to 10 000.
        ctx.write_single_register(5, 1).await.unwrap().unwrap();
        ctx.write_single_register(7, 1).await.unwrap().unwrap();
        tokio::time::sleep(Duration::from_millis(350)).await;
        assert_eq!(registers(&mut ctx, 4, 4).await, [10_000, 1, 10_000, 1]);
        assert_eq!(sim.control("set ai 1 3300"), "ok");
        assert_eq!(registers(&mut ctx, 4, 1).await, [3_300]);
        assert_eq!(sim.control_ok("get ai 1"), "3300 1");
    });
}

#[test]
fn output_writes_are_visible_on_the_control_socket() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        assert_eq!(sim.control_ok("get do"), "0");
        ctx.write_single_coil(17, true).await.unwrap().unwrap();
        assert_eq!(sim.control_ok("get do"), "2");
        ctx.write_single_register(1, 0xa5a5).await.unwrap().unwrap();
        assert_eq!(sim.control_ok("get do"), "42405");
        ctx.write_multiple_coils(38, &[true, true, false, false, false, true]).await.unwrap().unwrap();
        assert_eq!(sim.control_ok("get tool-do"), "35");
        ctx.write_single_register(22, 0).await.unwrap().unwrap();
        assert_eq!(sim.control_ok("get tool-do"), "0");
        ctx.write_multiple_registers(16, &[7_500, 1, 16_000, 0]).await.unwrap().unwrap();
        assert_eq!(sim.control_ok("get ao 1"), "7500 1");
        assert_eq!(sim.control_ok("get ao 2"), "16000 0");
    });
    assert!(sim.log().contains("outputs: do 0xa5a5"), "writes are logged");
}

#[test]
fn the_control_socket_answers_every_line() {
    let sim = HalSim::start(&["--robot", "idle"]);
    let mut stream = UnixStream::connect(sim.control_path()).unwrap();
    stream.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    // Several commands in one write, one of them long, CRLF line ends.
    let long = "x".repeat(1000);
    let batch =
        format!("set di 2 1\r\nbogus\n{long}\nget di\nset di 99 1\nget ao 3\nset tool-di 1 2\nrobot dance\nhelp\n\n");
    stream.write_all(batch.as_bytes()).unwrap();
    let mut reader = BufReader::new(stream.try_clone().unwrap());
    let mut replies = Vec::new();
    for _ in 0..10 {
        let mut line = String::new();
        reader.read_line(&mut line).unwrap();
        replies.push(line.trim_end().to_owned());
    }
    assert_eq!(replies[0], "ok");
    assert!(replies[1].starts_with("err unknown command"), "{replies:?}");
    assert!(replies[2].starts_with("err line longer than"), "{replies:?}");
    assert_eq!(replies[3], "ok 2");
    assert!(replies[4].starts_with("err pin must be 1..=16"), "{replies:?}");
    assert!(replies[5].starts_with("err analog channel"), "{replies:?}");
    assert!(replies[6].starts_with("err level must be 0 or 1"), "{replies:?}");
    assert!(replies[7].starts_with("err usage: robot"), "{replies:?}");
    assert!(replies[8].starts_with("ok commands:"), "{replies:?}");
    assert_eq!(replies[9], "err empty command");
    // Other connections are served meanwhile, and this one still is.
    assert_eq!(sim.control("get di"), "ok 2");
    stream.write_all(b"get di\n").unwrap();
    let mut line = String::new();
    reader.read_line(&mut line).unwrap();
    assert_eq!(line, "ok 2\n");
}

#[test]
fn demo_telemetry_changes_every_100_ms() {
    let sim = HalSim::start(&["--robot", "demo"]);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        // INITIALIZING, then STANDBY, then OPERATING, in a few seconds.
        let mut states = Vec::new();
        let deadline = Instant::now() + Duration::from_secs(6);
        while Instant::now() < deadline {
            let state = registers(&mut ctx, 259, 1).await[0];
            if states.last() != Some(&state) {
                states.push(state);
            }
            if state == 2 {
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        assert_eq!(states.last(), Some(&2), "OPERATING within 6 s: {states:?}");
        assert!(states.iter().all(|s| [0, 1, 2].contains(s)), "{states:?}");
        tokio::time::sleep(Duration::from_millis(600)).await; // past the ramp

        // Every refresh, seen by polling far faster than it runs; not samples
        // on a client timer of the same period, which now and then fall twice
        // between two refreshes, whatever its tick policy. The time bound is
        // what checks the period.
        let mut samples = vec![telemetry(&mut ctx).await];
        let started = Instant::now();
        while samples.len() <= REFRESHES as usize {
            assert!(
                started.elapsed() < REFRESHES_WITHIN,
                "{REFRESHES} refreshes within {REFRESHES_WITHIN:?}: {} seen",
                samples.len() - 1
            );
            tokio::time::sleep(Duration::from_millis(10)).await;
            let sample = telemetry(&mut ctx).await;
            if samples.last().is_some_and(|(joints, _)| *joints != sample.0) {
                samples.push(sample);
            }
        }
        for pair in samples.windows(2) {
            let ((j0, t0), (j1, t1)) = (&pair[0], &pair[1]);
            assert_ne!(j0[0..6], j1[0..6], "joint positions change at every refresh");
            assert_ne!(t0[0..6], t1[0..6], "the task pose changes at every refresh");
            // Velocities agree in sign with the position change of each moving
            // joint: the velocity at the end, or the one at the start if the
            // joint turned in between (samples are one refresh apart, or more
            // if the client was held up past one).
            let (p0, p1, v0, v1) = (signed(&j0[0..6]), signed(&j1[0..6]), signed(&j0[10..16]), signed(&j1[10..16]));
            for (((a, b), v0), v1) in p0.iter().zip(&p1).zip(&v0).zip(&v1) {
                let moved = b - a;
                if moved.abs() >= 5 {
                    let turned = v0.signum() != v1.signum() && moved.signum() == v0.signum();
                    assert!(moved.signum() == v1.signum() || turned, "moved {moved}, velocity {v0} then {v1}");
                }
            }
        }
        let (joints, task) = samples.last().unwrap();
        let currents = &joints[20..26];
        let temperatures = &joints[30..36];
        let torques = signed(&joints[40..46]);
        assert!(currents.iter().all(|&ma| (100..=10_000).contains(&ma)), "{currents:?}");
        assert!(temperatures.iter().all(|&c| (15..=80).contains(&c)), "{temperatures:?}");
        assert!(torques.iter().all(|t| t.abs() <= 500), "{torques:?}");
        let pose = signed(&task[0..6]);
        let reach = ((pose[0] as f64).powi(2) + (pose[1] as f64).powi(2) + (pose[2] as f64).powi(2)).sqrt() / 10.0;
        assert!((200.0..=1_500.0).contains(&reach), "tool within reach: {pose:?}");
        assert!((0..=1_800).contains(&pose[4]), "B of Z-Y-Z is 0..180 deg: {pose:?}");
        assert_eq!(signed(&task[20..26]), [0, 0, 1_200, 0, 0, 0], "tool offset");
    });
}

#[test]
fn idle_robot_stays_in_standby_and_still() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        tokio::time::sleep(Duration::from_millis(200)).await;
        let first = registers(&mut ctx, 270, 46).await;
        let first_task = registers(&mut ctx, 400, 16).await;
        for _ in 0..15 {
            tokio::time::sleep(Duration::from_millis(100)).await;
            assert_eq!(registers(&mut ctx, 259, 3).await, [1, 1, 0], "STANDBY, servo on");
            let now = registers(&mut ctx, 270, 46).await;
            assert_eq!(now[0..6], first[0..6], "joints still");
            assert_eq!(now[10..16], [0; 6], "no joint velocity");
            let task = registers(&mut ctx, 400, 16).await;
            assert_eq!(task[0..6], first_task[0..6], "tool still");
            assert_eq!(task[10..16], [0; 6], "no task velocity");
        }
    });
}

#[test]
fn emergency_stop_and_its_release_go_where_a_controller_goes() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        tokio::time::sleep(Duration::from_millis(200)).await;
        assert_eq!(registers(&mut ctx, 259, 6).await, [1, 1, 0, 0, 0, 0]);

        assert_eq!(sim.control("robot estop press"), "ok 6 0 1 0 0 0");
        assert_eq!(registers(&mut ctx, 259, 6).await, [6, 0, 1, 0, 0, 0], "at once");
        assert_eq!(coils(&mut ctx, 260, 6).await, [false, true, false, false, false, false]);
        assert!(sim.control("robot reset").starts_with("err emergency stop pressed"));
        tokio::time::sleep(Duration::from_millis(350)).await;
        assert_eq!(registers(&mut ctx, 259, 3).await, [6, 0, 1], "it stays");

        // Released: SAFE OFF, servo still off, until the operator resets.
        assert_eq!(sim.control("robot estop release"), "ok 3 0 0 1 0 0");
        assert_eq!(registers(&mut ctx, 259, 6).await, [3, 0, 0, 1, 0, 0]);
        assert_eq!(coils(&mut ctx, 260, 6).await, [false, false, true, false, false, false]);
        assert_eq!(sim.control("robot reset"), "ok 1 1 0 0 0 0");
        assert_eq!(registers(&mut ctx, 259, 6).await, [1, 1, 0, 0, 0, 0]);
        assert_eq!(sim.control_ok("get robot"), "1 1 0 0 0 0");
    });
}

#[test]
fn safety_stops_and_buttons_set_their_registers_and_coils() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        tokio::time::sleep(Duration::from_millis(200)).await;
        assert_eq!(sim.control("robot safety-stop recovery"), "ok 9 1 0 2 0 0");
        assert_eq!(registers(&mut ctx, 259, 4).await, [9, 1, 0, 2]);
        assert_eq!(coils(&mut ctx, 262, 4).await, [true, false, false, true], "coil 265: recovery needed");
        assert!(sim.control("robot reset").starts_with("err stop needs recovery mode"));
        assert_eq!(sim.control("robot recover"), "ok 8 1 0 0 0 0");
        assert_eq!(registers(&mut ctx, 259, 4).await, [8, 1, 0, 0]);

        assert_eq!(sim.control("robot state standby"), "ok 1 1 0 0 0 0");
        assert_eq!(sim.control("robot safety-stop"), "ok 5 1 0 1 0 0");
        assert_eq!(coils(&mut ctx, 262, 4).await, [true, false, false, false]);
        assert_eq!(sim.control("robot reset"), "ok 1 1 0 0 0 0");

        assert_eq!(sim.control("robot teach press"), "ok 4 1 0 0 1 0");
        assert_eq!(registers(&mut ctx, 259, 6).await, [4, 1, 0, 0, 1, 0]);
        assert!(coils(&mut ctx, 263, 1).await[0]);
        assert_eq!(sim.control("robot teach release"), "ok 1 1 0 0 0 0");
        assert_eq!(sim.control("robot power press"), "ok 1 1 0 0 0 1");
        assert_eq!(registers(&mut ctx, 264, 1).await, [1]);
        assert!(coils(&mut ctx, 264, 1).await[0]);
        tokio::time::sleep(Duration::from_millis(350)).await;
        assert_eq!(registers(&mut ctx, 259, 6).await, [1, 1, 0, 0, 0, 1], "the refresh keeps the pushed status");
        assert_eq!(sim.control("robot power release"), "ok 1 1 0 0 0 0");
    });
}
