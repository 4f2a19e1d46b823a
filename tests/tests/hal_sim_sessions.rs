//! hal-sim's sessions: 8 concurrent clients and the eviction of the idlest,
//! idle and frame timeouts, pipelining, a request split into single bytes,
//! a bad protocol id and a bad length. Where tokio-modbus cannot express the
//! bytes, a raw TCP stream sends them, and tokio-modbus checks the server
//! afterwards on the same hal-sim.

use std::time::Duration;

use system_tests::hal_sim::{HalSim, end_within, read_frame};
use test_support::framer::adu;
use tokio::io::AsyncWriteExt;
use tokio_modbus::prelude::*;

const REPLY_WAIT: Duration = Duration::from_secs(2);

#[test]
fn eight_clients_are_served_and_a_ninth_evicts_the_idlest() {
    let sim = HalSim::start(&["--robot", "idle", "--idle-timeout", "0"]);
    sim.run(|| async {
        let mut clients = Vec::new();
        for i in 0..8u16 {
            let mut ctx = sim.connect_watched().await;
            ctx.write_single_register(128 + i, i).await.unwrap().unwrap();
            clients.push(ctx);
        }
        // All eight are served at once; then every one but client 3 makes a request.
        for (i, ctx) in clients.iter_mut().enumerate() {
            assert_eq!(ctx.read_holding_registers(128 + i as u16, 1).await.unwrap().unwrap(), [i as u16]);
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
        for (i, ctx) in clients.iter_mut().enumerate() {
            if i != 3 {
                ctx.read_holding_registers(128, 1).await.unwrap().unwrap();
            }
        }
        // The ninth is served, and client 3 (the idlest) is closed.
        let mut ninth = sim.connect().await;
        assert_eq!(ninth.read_holding_registers(131, 1).await.unwrap().unwrap(), [3]);
        tokio::time::sleep(Duration::from_millis(100)).await;
        for (i, ctx) in clients.iter_mut().enumerate() {
            if i == 3 {
                let end = ctx.end_within(REPLY_WAIT).await;
                assert!(end.is_closed(), "the idlest client is evicted: {end:?}");
            } else {
                assert_eq!(
                    ctx.read_holding_registers(128 + i as u16, 1).await.unwrap().unwrap(),
                    [i as u16],
                    "client {i}"
                );
            }
        }
        ninth.read_holding_registers(128, 8).await.unwrap().unwrap();
    });
    assert!(sim.log().contains("closing the idlest"));
}

#[test]
fn max_connections_sets_how_many_are_served() {
    let sim = HalSim::start(&["--robot", "idle", "--max-connections", "2", "--idle-timeout", "0"]);
    sim.run(|| async {
        let mut first = sim.connect_watched().await;
        first.read_holding_registers(0, 1).await.unwrap().unwrap();
        tokio::time::sleep(Duration::from_millis(50)).await;
        let mut second = sim.connect().await;
        second.read_holding_registers(0, 1).await.unwrap().unwrap();
        let mut third = sim.connect().await;
        third.read_holding_registers(0, 1).await.unwrap().unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;
        let end = first.end_within(REPLY_WAIT).await;
        assert!(end.is_closed(), "the first of three is evicted: {end:?}");
        second.read_holding_registers(0, 1).await.unwrap().unwrap();
        third.read_holding_registers(0, 1).await.unwrap().unwrap();
    });
}

#[test]
fn an_idle_session_times_out_and_a_busy_one_does_not() {
    let sim = HalSim::start(&["--robot", "idle", "--idle-timeout", "1"]);
    sim.run(|| async {
        let mut idle = sim.connect_watched().await;
        let mut busy = sim.connect().await;
        idle.read_holding_registers(0, 1).await.unwrap().unwrap();
        for _ in 0..8 {
            busy.read_holding_registers(0, 1).await.unwrap().unwrap();
            tokio::time::sleep(Duration::from_millis(250)).await;
        }
        let end = idle.end_within(REPLY_WAIT).await;
        assert!(end.is_closed(), "no request for 2 s with a 1 s idle timeout: {end:?}");
        busy.read_holding_registers(0, 1).await.unwrap().unwrap();
    });
    assert!(sim.log().contains("idle timeout"));
}

#[test]
fn a_frame_that_stops_halfway_times_out() {
    let sim = HalSim::start(&["--robot", "idle", "--idle-timeout", "0"]);
    sim.run(|| async {
        let mut raw = sim.raw().await;
        let request = adu(1, 0, 1, &[0x03, 0x00, 0x80, 0x00, 0x01]);
        raw.write_all(&request[..5]).await.unwrap();
        // The frame timeout is 2 s; without idle timeout only it can close this.
        let end = end_within(&mut raw, Duration::from_secs(4)).await;
        assert!(end.is_closed(), "a half frame is not waited for forever: {end:?}");
        let mut ctx = sim.connect().await;
        ctx.read_holding_registers(128, 1).await.unwrap().unwrap();
    });
}

#[test]
fn pipelined_requests_in_one_segment_are_answered_in_order() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let mut raw = sim.raw().await;
        let mut segment = Vec::new();
        segment.extend(adu(0x0101, 0, 1, &[0x06, 0x00, 0x80, 0xbe, 0xef])); // write 128
        segment.extend(adu(0x0102, 0, 1, &[0x03, 0x00, 0x80, 0x00, 0x01])); // read 128
        segment.extend(adu(0x0103, 0, 1, &[0x41])); // unknown function
        segment.extend(adu(0x0104, 0, 1, &[0x10, 0x00, 0x81, 0x00, 0x02, 0x04, 0x00, 0x01, 0x00, 0x02])); // write 129-130
        segment.extend(adu(0x0105, 0, 7, &[0x01, 0x00, 0x10, 0x00, 0x08])); // read coils 16-23
        raw.write_all(&segment).await.unwrap();
        let expected: [&[u8]; 5] = [
            &[0x01, 0x01, 0, 0, 0, 6, 1, 0x06, 0x00, 0x80, 0xbe, 0xef],
            &[0x01, 0x02, 0, 0, 0, 5, 1, 0x03, 0x02, 0xbe, 0xef],
            &[0x01, 0x03, 0, 0, 0, 3, 1, 0xc1, 0x01],
            &[0x01, 0x04, 0, 0, 0, 6, 1, 0x10, 0x00, 0x81, 0x00, 0x02],
            &[0x01, 0x05, 0, 0, 0, 4, 7, 0x01, 0x01, 0x00],
        ];
        for want in expected {
            assert_eq!(read_frame(&mut raw, REPLY_WAIT).await.as_deref(), Some(want));
        }
        let mut ctx = sim.connect().await;
        assert_eq!(ctx.read_holding_registers(128, 3).await.unwrap().unwrap(), [0xbeef, 1, 2]);
        // The raw connection is still served.
        raw.write_all(&adu(9, 0, 1, &[0x03, 0x00, 0x82, 0x00, 0x01])).await.unwrap();
        assert_eq!(read_frame(&mut raw, REPLY_WAIT).await.unwrap(), [0, 9, 0, 0, 0, 5, 1, 0x03, 0x02, 0x00, 0x02]);
    });
}

#[test]
fn a_request_sent_one_byte_at_a_time_is_answered() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let mut raw = sim.raw().await;
        let request = adu(0x4242, 0, 1, &[0x10, 0x00, 0x90, 0x00, 0x02, 0x04, 0x12, 0x34, 0x56, 0x78]);
        for byte in &request {
            raw.write_all(std::slice::from_ref(byte)).await.unwrap();
            raw.flush().await.unwrap();
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        let reply = read_frame(&mut raw, REPLY_WAIT).await.expect("a reply");
        assert_eq!(reply, [0x42, 0x42, 0, 0, 0, 6, 1, 0x10, 0x00, 0x90, 0x00, 0x02]);
        let mut ctx = sim.connect().await;
        assert_eq!(ctx.read_holding_registers(0x90, 2).await.unwrap().unwrap(), [0x1234, 0x5678]);
    });
}

#[test]
fn a_bad_protocol_id_is_discarded_and_the_connection_carries_on() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let mut raw = sim.raw().await;
        // Not Modbus: a write that must not happen, and no reply.
        raw.write_all(&adu(1, 0x0001, 1, &[0x06, 0x00, 0x80, 0x00, 0x63])).await.unwrap();
        assert_eq!(read_frame(&mut raw, Duration::from_millis(500)).await, None, "no reply to protocol id 1");
        raw.write_all(&adu(2, 0xffff, 1, &[0x03, 0x00, 0x80, 0x00, 0x01])).await.unwrap();
        // The next Modbus frame on the same connection is answered.
        raw.write_all(&adu(3, 0, 1, &[0x03, 0x00, 0x80, 0x00, 0x01])).await.unwrap();
        assert_eq!(read_frame(&mut raw, REPLY_WAIT).await.unwrap(), [0, 3, 0, 0, 0, 5, 1, 0x03, 0x02, 0x00, 0x00]);
        let mut ctx = sim.connect().await;
        assert_eq!(ctx.read_holding_registers(128, 1).await.unwrap().unwrap(), [0], "the discarded write did nothing");
    });
    assert!(sim.log().contains("discarded protocol id 1"));
}

#[test]
fn a_bad_length_closes_that_connection_while_others_carry_on() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let mut other = sim.connect().await;
        other.write_single_register(128, 5).await.unwrap().unwrap();
        for length in [0u16, 1, 255, 0xffff] {
            let mut raw = sim.raw().await;
            let mut bad = vec![0x00, 0x01, 0x00, 0x00];
            bad.extend_from_slice(&length.to_be_bytes());
            bad.extend_from_slice(&[0x01, 0x03, 0x00, 0x80, 0x00, 0x01]);
            raw.write_all(&bad).await.unwrap();
            let end = end_within(&mut raw, REPLY_WAIT).await;
            assert!(end.is_closed(), "length {length} closes the connection: {end:?}");
            assert_eq!(other.read_holding_registers(128, 1).await.unwrap().unwrap(), [5], "after length {length}");
        }
        let mut fresh = sim.connect().await;
        fresh.read_holding_registers(128, 1).await.unwrap().unwrap();
    });
    assert!(sim.log().contains("bad MBAP length"));
}

/// `--busy-poll`: the loop polls instead of sleeping for a while after each
/// event. Clients are served alike, timers still fire while it polls (the
/// communication watchdog trips on time), and once nothing happens it goes
/// back to sleep: an idle hal-sim does not keep its CPU busy.
#[test]
fn busy_polling_serves_alike_keeps_timers_and_sleeps_when_idle() {
    let sim = HalSim::start(&["--robot", "idle", "--busy-poll", "1000", "--watchdog-ms", "500", "--safe-do", "0x8000"]);
    assert!(sim.log().contains("busy polling: up to 1000 µs"), "{}", sim.log());
    let sim = &sim;
    sim.run(|| async {
        let client = |i: u16| async move {
            let mut ctx = sim.connect().await;
            for n in 0..200u16 {
                ctx.write_single_register(128 + i, n).await.unwrap().unwrap();
                assert_eq!(ctx.read_holding_registers(128 + i, 1).await.unwrap().unwrap(), [n], "client {i}");
            }
            ctx
        };
        let (mut first, ..) = tokio::join!(client(0), client(1), client(2), client(3));
        first.write_single_register(1, 0x00ff).await.unwrap().unwrap();
        assert_eq!(sim.control_ok("get do"), "255");
        // Silence: the watchdog's timer fires within its timeout and one refresh.
        tokio::time::sleep(Duration::from_millis(800)).await;
        assert_eq!(sim.control_ok("get do"), "32768");
    });
    // Idle for 2 s: a loop that never stopped polling would use all of it.
    let busy = cpu_time(sim.pid());
    std::thread::sleep(Duration::from_secs(2));
    let used = cpu_time(sim.pid()) - busy;
    assert!(used < Duration::from_millis(500), "an idle hal-sim used {used:?} of CPU in 2 s");
}

/// User and system CPU time of process `pid` so far (/proc/PID/stat).
fn cpu_time(pid: u32) -> Duration {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap();
    // The fields after the command's closing parenthesis; utime and stime are the 12th and 13th.
    let fields: Vec<&str> = stat.rsplit_once(')').unwrap().1.split_whitespace().collect();
    let ticks: u64 = fields[11].parse::<u64>().unwrap() + fields[12].parse::<u64>().unwrap();
    // SAFETY: sysconf takes no pointers.
    let per_second = u64::try_from(unsafe { libc::sysconf(libc::_SC_CLK_TCK) }).unwrap();
    Duration::from_millis(ticks * 1000 / per_second)
}
