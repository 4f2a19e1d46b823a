//! hal-sim through tokio-modbus: every function code and exception, both
//! views of the same points, both write policies, reserved addresses, the
//! analog range checks, the unit id filter and the controller version's registers
//! (docs/data-map.md). Each test runs its own hal-sim in its own namespace.

use std::time::Duration;

use system_tests::hal_sim::{HalSim, controller_version, read_frame};
use test_support::framer::adu;
use tokio::io::AsyncWriteExt;
use tokio_modbus::prelude::*;

/// Longer than the 100 ms refresh, so a source has re-asserted its point.
const AFTER_REFRESH: Duration = Duration::from_millis(350);

#[test]
fn every_function_code_round_trips() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        // 0x06 and 0x03.
        ctx.write_single_register(128, 0x1234).await.unwrap().unwrap();
        assert_eq!(ctx.read_holding_registers(128, 1).await.unwrap().unwrap(), [0x1234]);
        // 0x10.
        ctx.write_multiple_registers(129, &[1, 2, 0xffff]).await.unwrap().unwrap();
        assert_eq!(ctx.read_holding_registers(128, 4).await.unwrap().unwrap(), [0x1234, 1, 2, 0xffff]);
        // 0x05 and 0x01.
        ctx.write_single_coil(16, true).await.unwrap().unwrap();
        assert_eq!(ctx.read_coils(16, 3).await.unwrap().unwrap(), [true, false, false]);
        ctx.write_single_coil(16, false).await.unwrap().unwrap();
        assert_eq!(ctx.read_coils(16, 1).await.unwrap().unwrap(), [false]);
        // 0x0F, across a byte boundary.
        let pattern = [true, false, true, true, false, false, false, false, true, true];
        ctx.write_multiple_coils(16, &pattern).await.unwrap().unwrap();
        assert_eq!(ctx.read_coils(16, 10).await.unwrap().unwrap(), pattern);
        // The largest reads the map allows: 125 registers, every coil.
        assert_eq!(ctx.read_holding_registers(128, 125).await.unwrap().unwrap().len(), 125);
        assert_eq!(ctx.read_coils(0, 266).await.unwrap().unwrap().len(), 266);
        // The largest writes: 123 registers, and the 128 general-purpose ones in two.
        let words: Vec<u16> = (0..123).map(|i| 1000 + i).collect();
        ctx.write_multiple_registers(128, &words).await.unwrap().unwrap();
        assert_eq!(ctx.read_holding_registers(128, 123).await.unwrap().unwrap(), words);
        ctx.write_multiple_registers(251, &[7, 8, 9, 10, 11]).await.unwrap().unwrap();
        assert_eq!(ctx.read_holding_registers(251, 5).await.unwrap().unwrap(), [7, 8, 9, 10, 11]);
    });
}

#[test]
fn every_exception() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        use ExceptionCode::*;
        let mut ctx = sim.connect().await;
        // 01: function codes outside the map (unassigned, user-defined, the last one,
        // and Report Server ID, which is serial-line only).
        for code in [0x09u8, 0x0a, 0x41, 0x64, 0x7f] {
            let reply = ctx.call(Request::Custom(code, vec![0, 0, 0, 1].into())).await.unwrap();
            assert_eq!(reply, Err(IllegalFunction), "function code {code:#04x}");
        }
        assert_eq!(ctx.call(Request::ReportServerId).await.unwrap(), Err(IllegalFunction));
        // 03: quantities outside the protocol's limits, a coil value that is not on or off.
        assert_eq!(ctx.read_holding_registers(0, 0).await.unwrap(), Err(IllegalDataValue));
        assert_eq!(ctx.read_holding_registers(0, 126).await.unwrap(), Err(IllegalDataValue));
        assert_eq!(ctx.read_coils(0, 0).await.unwrap(), Err(IllegalDataValue));
        assert_eq!(ctx.read_coils(0, 2001).await.unwrap(), Err(IllegalDataValue));
        assert_eq!(ctx.write_multiple_registers(128, &[]).await.unwrap(), Err(IllegalDataValue));
        assert_eq!(ctx.write_multiple_coils(16, &[]).await.unwrap(), Err(IllegalDataValue));
        assert_eq!(ctx.write_multiple_coils(0, &[false; 1969]).await.unwrap(), Err(IllegalDataValue));
        // tokio-modbus only sends 0xFF00 and 0x0000 for a coil: the odd value goes raw.
        let mut raw = sim.raw().await;
        raw.write_all(&adu(0x0505, 0, 1, &[0x05, 0x00, 0x10, 0x12, 0x34])).await.unwrap();
        let reply = read_frame(&mut raw, Duration::from_secs(2)).await;
        assert_eq!(reply.as_deref(), Some(&[0x05, 0x05, 0, 0, 0, 3, 1, 0x85, 0x03][..]));
        assert_eq!(ctx.read_coils(16, 1).await.unwrap().unwrap(), [false], "a refused coil write changes nothing");
        // 03 from the map: an analog output beyond 20 mA, an analog type that is neither 0 nor 1.
        assert_eq!(ctx.write_single_register(16, 20_001).await.unwrap(), Err(IllegalDataValue));
        assert_eq!(ctx.write_single_register(17, 2).await.unwrap(), Err(IllegalDataValue));
        // 02: past the end of either space, and reserved addresses written.
        assert_eq!(ctx.read_holding_registers(436, 1).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.read_holding_registers(430, 7).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.read_holding_registers(0xffff, 1).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.read_coils(266, 1).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.read_coils(200, 100).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.write_single_register(2, 1).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.write_single_register(436, 1).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.write_single_coil(100, true).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.write_single_coil(266, true).await.unwrap(), Err(IllegalDataAddress));
        // The connection survives every exception.
        assert_eq!(ctx.read_holding_registers(128, 1).await.unwrap(), Ok(vec![0]));
    });
    let log = sim.log();
    assert!(log.contains("exception"), "exceptions are logged:\n{log}");
}

#[test]
fn both_views_of_the_outputs_agree() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        // Coils 16-31 and register 1.
        let mut coils = [false; 16];
        for pin in [0, 3, 8, 15] {
            coils[pin] = true;
        }
        ctx.write_multiple_coils(16, &coils).await.unwrap().unwrap();
        assert_eq!(ctx.read_holding_registers(1, 1).await.unwrap().unwrap(), [0b1000_0001_0000_1001]);
        ctx.write_single_register(1, 0x0102).await.unwrap().unwrap();
        let read = ctx.read_coils(16, 16).await.unwrap().unwrap();
        let expected: Vec<bool> = (0..16).map(|bit| 0x0102 & (1 << bit) != 0).collect();
        assert_eq!(read, expected);
        ctx.write_single_coil(31, true).await.unwrap().unwrap();
        assert_eq!(ctx.read_holding_registers(1, 1).await.unwrap().unwrap(), [0x8102]);
        // Coils 38-43 and register 22.
        ctx.write_single_register(22, 0b10_0101).await.unwrap().unwrap();
        assert_eq!(ctx.read_coils(38, 6).await.unwrap().unwrap(), [true, false, true, false, false, true]);
        ctx.write_multiple_coils(38, &[false, true]).await.unwrap().unwrap();
        assert_eq!(ctx.read_holding_registers(22, 1).await.unwrap().unwrap(), [0b10_0110]);
        // A tool output beyond the 6 pins is not a pin.
        assert_eq!(ctx.write_single_register(22, 0b100_0000).await.unwrap(), Err(ExceptionCode::IllegalDataValue));
    });
    assert_eq!(sim.control_ok("get do"), "33026"); // 0x8102
    assert_eq!(sim.control_ok("get tool-do"), "38"); // 0b10_0110
}

#[test]
fn seed_policy_acknowledges_read_only_writes_and_the_source_wins() {
    let sim = HalSim::start(&["--robot", "idle", "--write-policy", "seed"]);
    sim.control_ok("set di 1 1");
    sim.control_ok("set tool-di 2 1");
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        let version = controller_version();
        ctx.write_single_register(0, 0xaaaa).await.unwrap().unwrap();
        ctx.write_single_coil(0, false).await.unwrap().unwrap();
        ctx.write_single_register(21, 0b11_1101).await.unwrap().unwrap();
        ctx.write_multiple_registers(256, &[9, 9, 9, 5]).await.unwrap().unwrap();
        ctx.write_single_coil(261, true).await.unwrap().unwrap();
        tokio::time::sleep(AFTER_REFRESH).await;
        assert_eq!(ctx.read_holding_registers(0, 1).await.unwrap().unwrap(), [1], "the pins win");
        assert_eq!(ctx.read_coils(0, 2).await.unwrap().unwrap(), [true, false]);
        assert_eq!(ctx.read_holding_registers(21, 1).await.unwrap().unwrap(), [0b10]);
        let robot = ctx.read_holding_registers(256, 6).await.unwrap().unwrap();
        assert_eq!(robot[..3], version, "the simulated controller's version comes back");
        assert_eq!(robot[3..], [1, 1, 0], "STANDBY, servo on, no e-stop: the robot wins");
        assert_eq!(ctx.read_coils(261, 1).await.unwrap().unwrap(), [false]);
    });
}

#[test]
fn strict_policy_refuses_read_only_writes() {
    let sim = HalSim::start(&["--robot", "idle", "--write-policy", "strict"]);
    sim.run(|| async {
        use ExceptionCode::IllegalDataAddress;
        let mut ctx = sim.connect().await;
        assert_eq!(ctx.write_single_register(0, 1).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.write_single_coil(0, true).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.write_single_register(21, 1).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.write_single_register(256, 1).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.write_single_register(270, 1).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.write_single_coil(261, true).await.unwrap(), Err(IllegalDataAddress));
        // A multiple write that touches one read-only point changes nothing.
        assert_eq!(ctx.write_multiple_registers(0, &[1, 0xff]).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.write_multiple_coils(30, &[true, true, true]).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.read_holding_registers(0, 2).await.unwrap().unwrap(), [0, 0]);
        assert_eq!(ctx.read_coils(30, 2).await.unwrap().unwrap(), [false, false]);
        // The writable points still are.
        ctx.write_single_register(1, 0xff).await.unwrap().unwrap();
        ctx.write_single_coil(43, true).await.unwrap().unwrap();
        ctx.write_single_register(200, 42).await.unwrap().unwrap();
        ctx.write_multiple_registers(16, &[4000, 0, 9000, 1]).await.unwrap().unwrap();
        assert_eq!(ctx.read_holding_registers(16, 4).await.unwrap().unwrap(), [4000, 0, 9000, 1]);
    });
    assert_eq!(sim.control_ok("get do"), "255");
    assert_eq!(sim.control_ok("get tool-do"), "32");
}

#[test]
fn reserved_addresses_read_zero_and_refuse_writes() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        use ExceptionCode::IllegalDataAddress;
        let mut ctx = sim.connect().await;
        for (start, count) in
            [(2u16, 2u16), (8, 8), (20, 1), (23, 105), (265, 5), (276, 4), (316, 84), (406, 4), (426, 4)]
        {
            let values = ctx.read_holding_registers(start, count).await.unwrap().unwrap();
            assert!(values.iter().all(|&v| v == 0), "registers {start}+{count}: {values:?}");
        }
        assert!(ctx.read_coils(44, 216).await.unwrap().unwrap().iter().all(|&c| !c));
        // A read across reserved and used addresses is fine; a write is not.
        ctx.write_single_register(1, 0x00ff).await.unwrap().unwrap();
        assert_eq!(ctx.read_holding_registers(0, 8).await.unwrap().unwrap()[1..4], [0x00ff, 0, 0]);
        assert_eq!(ctx.write_multiple_registers(1, &[0, 0, 0]).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.read_holding_registers(1, 1).await.unwrap().unwrap(), [0x00ff], "nothing written");
        for address in [2u16, 3, 8, 15, 20, 23, 127, 265, 269, 276, 316, 399, 406, 416, 426, 429] {
            assert_eq!(
                ctx.write_single_register(address, 0).await.unwrap(),
                Err(IllegalDataAddress),
                "register {address}"
            );
        }
        for address in [44u16, 100, 259] {
            assert_eq!(ctx.write_single_coil(address, false).await.unwrap(), Err(IllegalDataAddress), "coil {address}");
        }
        assert_eq!(ctx.write_multiple_coils(42, &[true, true, true]).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.read_coils(42, 2).await.unwrap().unwrap(), [false, false]);
        // The last addresses of each space are readable.
        assert_eq!(ctx.read_holding_registers(435, 1).await.unwrap().map(|v| v.len()), Ok(1));
        assert_eq!(ctx.read_coils(265, 1).await.unwrap().map(|v| v.len()), Ok(1));
    });
}

#[test]
fn analog_outputs_are_range_checked() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        use ExceptionCode::IllegalDataValue;
        let mut ctx = sim.connect().await;
        // Current mode (type 0, the default): 0..=20 000 µA.
        ctx.write_single_register(16, 20_000).await.unwrap().unwrap();
        assert_eq!(sim.control_ok("get ao 1"), "20000 0");
        assert_eq!(ctx.write_single_register(16, 20_001).await.unwrap(), Err(IllegalDataValue));
        assert_eq!(ctx.write_single_register(16, 0xffff).await.unwrap(), Err(IllegalDataValue));
        assert_eq!(sim.control_ok("get ao 1"), "20000 0", "a refused write changes nothing");
        // Voltage mode: 0..=10 000 mV, checked with the type in force after the write.
        ctx.write_multiple_registers(16, &[10_000, 1]).await.unwrap().unwrap();
        assert_eq!(sim.control_ok("get ao 1"), "10000 1");
        assert_eq!(ctx.write_single_register(16, 10_001).await.unwrap(), Err(IllegalDataValue));
        assert_eq!(ctx.write_multiple_registers(16, &[15_000, 1]).await.unwrap(), Err(IllegalDataValue));
        ctx.write_multiple_registers(16, &[15_000, 0]).await.unwrap().unwrap();
        assert_eq!(sim.control_ok("get ao 1"), "15000 0");
        // Type registers take 0 or 1 only; output 2 likewise.
        assert_eq!(ctx.write_single_register(17, 2).await.unwrap(), Err(IllegalDataValue));
        assert_eq!(ctx.write_single_register(19, 7).await.unwrap(), Err(IllegalDataValue));
        ctx.write_multiple_registers(18, &[2_500, 1]).await.unwrap().unwrap();
        assert_eq!(sim.control_ok("get ao 2"), "2500 1");
        assert_eq!(ctx.write_multiple_registers(16, &[1, 0, 12_000, 1]).await.unwrap(), Err(IllegalDataValue));
        assert_eq!(ctx.read_holding_registers(16, 4).await.unwrap().unwrap(), [15_000, 0, 2_500, 1], "all or nothing");
        assert_eq!(sim.control_ok("get ao 1"), "15000 0");
        assert_eq!(sim.control_ok("get ao 2"), "2500 1");
    });
}

#[test]
fn registers_256_to_258_hold_the_simulated_controller_s_version() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        let version = ctx.read_holding_registers(256, 3).await.unwrap().unwrap();
        assert_eq!(version, controller_version());
        assert_ne!(version, system_tests::hal_sim::firmware_version(), "the controller's, not the adapter's");
    });
}

#[test]
fn a_unit_id_filter_answers_its_id_0_and_255_only() {
    let sim = HalSim::start(&["--robot", "idle", "--unit-id", "17"]);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        for unit in [17u8, 0, 255] {
            ctx.set_slave(Slave(unit));
            assert_eq!(ctx.read_holding_registers(256, 3).await.unwrap().map(|v| v.len()), Ok(3), "unit {unit}");
        }
        for unit in [1u8, 16, 18, 254] {
            ctx.set_slave(Slave(unit));
            let reply = ctx.read_holding_registers(256, 3).await.unwrap();
            assert_eq!(reply, Err(ExceptionCode::GatewayTargetDevice), "unit {unit}");
            assert_eq!(ctx.write_single_register(128, 1).await.unwrap(), Err(ExceptionCode::GatewayTargetDevice));
        }
        ctx.set_slave(Slave(17));
        assert_eq!(ctx.read_holding_registers(128, 1).await.unwrap(), Ok(vec![0]), "no write got through");
    });
}

#[test]
fn connections_writes_and_exceptions_are_logged() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        ctx.write_single_coil(16, true).await.unwrap().unwrap();
        ctx.read_coils(300, 1).await.unwrap().unwrap_err();
        ctx.disconnect().await.unwrap();
    });
    std::thread::sleep(Duration::from_millis(200));
    let log = sim.log();
    for needle in ["connection from 198.18.0.1:", "outputs: do 0x0001", "exception", "closed"] {
        assert!(log.contains(needle), "{needle:?} is logged:\n{log}");
    }
}
