//! Issue "Reliability and security" through hal-sim and tokio-modbus: the
//! communication watchdog and its safe state, the connect and write
//! allow-lists, and the diagnostics counters on the control socket.

use std::time::Duration;

use system_tests::hal_sim::{HalSim, end_within};
use test_support::framer::adu;
use tokio::io::AsyncWriteExt;
use tokio_modbus::prelude::*;

#[test]
fn the_watchdog_puts_outputs_in_their_safe_state_until_a_client_writes_again() {
    let sim = HalSim::start(&["--robot", "idle", "--watchdog-ms", "500", "--safe-do", "0x8000", "--safe-ao1", "4000"]);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        ctx.write_single_register(1, 0x00ff).await.unwrap().unwrap();
        ctx.write_single_register(16, 12_000).await.unwrap().unwrap();
        assert_eq!(sim.control_ok("get do"), "255");
        // Requests every 200 ms keep it quiet.
        for _ in 0..5 {
            tokio::time::sleep(Duration::from_millis(200)).await;
            ctx.read_holding_registers(128, 1).await.unwrap().unwrap();
        }
        assert_eq!(sim.control_ok("get do"), "255");
        assert_eq!(sim.stats()["watchdog_trips"], 0);
        // Silence: within the timeout plus one 100 ms refresh, the outputs are safe.
        tokio::time::sleep(Duration::from_millis(800)).await;
        assert_eq!(sim.control_ok("get do"), "32768");
        assert_eq!(sim.control_ok("get ao 1"), "4000 0");
        assert_eq!(sim.stats()["watchdog_trips"], 1);
        // Both views show it; a read re-arms the watchdog but changes nothing.
        assert_eq!(ctx.read_holding_registers(1, 1).await.unwrap().unwrap(), [0x8000]);
        assert!(ctx.read_coils(31, 1).await.unwrap().unwrap()[0]);
        assert_eq!(sim.control_ok("get do"), "32768");
        // A write restores the outputs.
        ctx.write_single_coil(16, true).await.unwrap().unwrap();
        assert_eq!(sim.control_ok("get do"), "32769");
        assert!(sim.log().contains("watchdog"), "the trip is logged:\n{}", sim.log());
    });
}

#[test]
fn clients_outside_the_connect_allow_list_are_refused_at_once() {
    // The test's client is 198.18.0.1: allow another network only.
    let sim = HalSim::start(&["--robot", "idle", "--allow", "198.18.5.0/24"]);
    sim.run(|| async {
        // hal-sim resets the connection as soon as it is accepted: the reset
        // may even beat the client's connect() to completion.
        match tokio::net::TcpStream::connect(sim.addr()).await {
            Ok(mut stream) => {
                let _ = stream.write_all(&adu(1, 0, 1, &[0x03, 0x00, 0x80, 0x00, 0x01])).await;
                let end = end_within(&mut stream, Duration::from_secs(2)).await;
                assert!(end.is_closed(), "the connection is closed, unanswered: {end:?}");
            }
            Err(e) => assert_eq!(e.kind(), std::io::ErrorKind::ConnectionReset, "{e}"),
        }
    });
    assert_eq!(sim.stats()["refused_connections"], 1);
    assert_eq!(sim.stats()["requests"], 0);
    assert!(sim.log().contains("refused 198.18.0.1"), "{}", sim.log());

    let allowed = HalSim::start(&["--robot", "idle", "--allow", "198.18.5.0/24,198.18.0.1"]);
    allowed.run(|| async {
        let mut ctx = allowed.connect().await;
        assert_eq!(ctx.read_holding_registers(128, 1).await.unwrap().unwrap(), [0]);
    });
}

#[test]
fn clients_outside_the_write_allow_list_may_read_but_not_write() {
    let sim = HalSim::start(&["--robot", "idle", "--allow-write", "198.18.0.200"]);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        assert_eq!(ctx.read_holding_registers(256, 3).await.unwrap().unwrap().len(), 3);
        let refused = Err(ExceptionCode::IllegalFunction);
        assert_eq!(ctx.write_single_coil(16, true).await.unwrap(), refused);
        assert_eq!(ctx.write_single_register(128, 7).await.unwrap(), refused);
        assert_eq!(ctx.write_multiple_coils(16, &[true, true]).await.unwrap(), refused);
        assert_eq!(ctx.write_multiple_registers(128, &[1, 2]).await.unwrap(), refused);
        assert_eq!(ctx.read_holding_registers(128, 1).await.unwrap().unwrap(), [0], "nothing was written");
        assert_eq!(sim.control_ok("get do"), "0");
    });
    let counters = sim.stats();
    assert_eq!((counters["refused_writes"], counters["bad_function"]), (4, 0));
}

#[test]
fn the_control_socket_reports_the_diagnostics_counters() {
    let sim = HalSim::start(&["--robot", "idle", "--max-connections", "1"]);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        ctx.read_holding_registers(0, 10).await.unwrap().unwrap();
        assert_eq!(ctx.read_holding_registers(436, 1).await.unwrap(), Err(ExceptionCode::IllegalDataAddress));
        assert_eq!(ctx.write_single_register(17, 2).await.unwrap(), Err(ExceptionCode::IllegalDataValue));
        // A bad protocol id, then a bad length on a raw connection (evicting the first).
        let mut raw = sim.raw().await;
        raw.write_all(&adu(9, 7, 1, &[0x03, 0, 0, 0, 1])).await.unwrap();
        raw.write_all(&[0, 1, 0, 0, 0x01, 0x00]).await.unwrap();
        let end = end_within(&mut raw, Duration::from_secs(2)).await;
        assert!(end.is_closed(), "a bad length closes the connection: {end:?}");
    });
    let counters = sim.stats();
    assert_eq!(counters["requests"], 3);
    assert_eq!((counters["bad_address"], counters["bad_value"]), (1, 1));
    assert_eq!((counters["bad_protocol"], counters["bad_length"], counters["evictions"]), (1, 1, 1));
    assert_eq!((counters["robot_polls"], counters["robot_errors"], counters["robot_link_downs"]), (0, 0, 0), "no link");
    assert_eq!((counters["tls_sessions"], counters["tls_failed"], counters["tls_refused"]), (0, 0, 0), "no TLS client");
    assert_eq!(counters.len(), 18, "every counter is listed");
}
