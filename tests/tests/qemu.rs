//! Smoke tests of the real firmware image: mps2-an386 in QEMU with slirp, a
//! free port of 127.0.0.1 forwarded to its port 502, tokio-modbus as the
//! client. Each test boots its own QEMU and ends with [`Qemu::finish`], which
//! fails on a panic, a hard fault or an error line in the firmware's log.
//!
//! Needs the image (`cargo build -p mps2-an386 --release --target
//! thumbv7em-none-eabihf`, or
//! `FIRMWARE_MPS2_ELF`), `qemu-system-arm` and `defmt-print` (installed on
//! first use if missing).

use std::borrow::Cow;
use std::time::Duration;

use system_tests::qemu::{self, LED0, NO_ROBOT, Qemu, ROBOT_REGISTERS};
use tokio::io::{AsyncReadExt as _, AsyncWriteExt as _};
use tokio_modbus::ExceptionCode::{IllegalDataAddress, IllegalDataValue, IllegalFunction};
use tokio_modbus::client::{Client as _, Context, Reader as _, Writer as _};
use tokio_modbus::prelude::{ConformityLevel, ReadCode};
use tokio_modbus::{ExceptionCode, FunctionCode, ProtocolError, Request, Response};

/// Coils 0-265 and registers 0-435 (docs/data-map.md).
const COILS: u16 = 266;
const REGISTERS: u16 = 436;
/// Register 259 without a robot: NOT READY.
const ROBOT_STATE: u16 = 259;
const NOT_READY: u16 = 15;
/// Largest reads allowed by the protocol.
const MAX_READ_REGISTERS: u16 = 125;
const MAX_READ_COILS: u16 = 2000;

/// Reads `count` registers from `start` in blocks of at most `block`.
async fn read_registers(ctx: &mut Context, start: u16, count: u16, block: u16) -> Vec<u16> {
    let mut values = Vec::new();
    let end = start + count;
    for from in (start..end).step_by(usize::from(block)) {
        let n = (end - from).min(block);
        let part = ctx.read_holding_registers(from, n).await.unwrap().unwrap();
        assert_eq!(part.len(), usize::from(n), "registers {from}..{}", from + n);
        values.extend(part);
    }
    values
}

/// The exception a raw request got. tokio-modbus reports an exception to a
/// custom request that reuses a standard function code as a "function code
/// mismatch" that carries the reply: take the exception from there.
fn exception_of(reply: tokio_modbus::Result<Response>, function: FunctionCode) -> Option<ExceptionCode> {
    match reply {
        Ok(Err(exception)) => Some(exception),
        Err(tokio_modbus::Error::Protocol(ProtocolError::FunctionCodeMismatch { result: Err(response), .. })) => {
            assert_eq!(response.function, function, "the exception answers the function sent");
            Some(response.exception)
        }
        _ => None,
    }
}

#[test]
fn without_a_robot_the_controller_version_is_0_and_the_robot_not_ready() {
    let qemu = Qemu::slirp();
    qemu.run(|| async {
        let mut ctx = qemu.connect().await;
        let robot = ctx.read_holding_registers(ROBOT_REGISTERS, 4).await.unwrap().unwrap();
        assert_eq!(robot, NO_ROBOT, "controller version 0.0.0 (no robot source), NOT READY");
        assert_eq!(ctx.read_holding_registers(ROBOT_STATE, 1).await.unwrap().unwrap(), [NOT_READY]);
    });
    // slirp's DHCP server gave the firmware its address; the network policy
    // logs it at its next 100 ms tick, which may come after the first client.
    qemu.wait_for_log("Modbus TCP server at 10.0.2.15:502", Duration::from_secs(2));
    qemu.finish();
}

#[test]
fn the_image_identifies_itself_and_answers_diagnostics() {
    let qemu = Qemu::slirp();
    qemu.run(|| async {
        let mut ctx = qemu.connect().await;
        // Read Device Identification (2B/0E), as tokio-modbus asks for it.
        let reply = ctx.read_device_identification(ReadCode::Regular, 0).await.unwrap().unwrap();
        assert_eq!(reply.conformity_level, ConformityLevel::RegularIdentification, "0x82");
        assert!(!reply.more_follows, "the regular set fits one reply");
        let objects: Vec<(u8, String)> =
            reply.device_id_objects.iter().map(|o| (o.id, o.value_as_str().expect("ASCII").to_owned())).collect();
        let [major, minor, patch] = qemu::firmware_version();
        let ids: Vec<u8> = objects.iter().map(|(id, _)| *id).collect();
        assert_eq!(ids, [0, 1, 2, 3, 4, 5, 6], "{objects:?}");
        assert_eq!(objects[2].1, format!("{major}.{minor}.{patch}"), "the firmware's version, not 256-258's");
        assert_eq!(objects[5].1, "mps2-an386");
        let name = &objects[6].1;
        assert!(name.starts_with("mbio-") && name.len() == 11, "the default name from the MAC: {name}");
        let unknown = ctx.read_device_identification(ReadCode::Specific, 7).await.unwrap();
        assert_eq!(unknown, Err(IllegalDataAddress));
        // Diagnostics (08), raw: tokio-modbus sends none of its sub-functions.
        let mut raw = tokio::net::TcpStream::connect(qemu.addr()).await.unwrap();
        for (pdu, want) in [
            (&[0x08, 0x00, 0x00, 0xbe, 0xef][..], &[0x08, 0x00, 0x00, 0xbe, 0xef][..]), // echo
            (&[0x08, 0x00, 0x0c, 0x00, 0x00], &[0x08, 0x00, 0x0c, 0x00, 0x00]),         // no stream lost
            (&[0x08, 0x00, 0x0d, 0x00, 0x00], &[0x08, 0x00, 0x0d, 0x00, 0x01]),         // the 02 above
            (&[0x08, 0x00, 0x01, 0x00, 0x00], &[0x88, 0x01]), // restart communications: not served
        ] {
            let mut frame = vec![0x00, 0x08, 0x00, 0x00, 0x00, pdu.len() as u8 + 1, 0x01];
            frame.extend(pdu);
            raw.write_all(&frame).await.unwrap();
            let mut reply = vec![0u8; 7 + want.len()];
            tokio::time::timeout(Duration::from_secs(5), raw.read_exact(&mut reply)).await.unwrap().unwrap();
            assert_eq!(reply[7..], *want, "{pdu:02x?}");
        }
    });
    qemu.finish();
}

#[test]
fn the_whole_coil_and_register_spaces_read_in_blocks() {
    let qemu = Qemu::slirp();
    qemu.run(|| async {
        let mut ctx = qemu.connect().await;

        let mut coils = Vec::new();
        for start in (0..COILS).step_by(64) {
            let n = (COILS - start).min(64);
            coils.extend(ctx.read_coils(start, n).await.unwrap().unwrap());
        }
        assert_eq!(coils.len(), usize::from(COILS));
        assert!(coils.iter().all(|on| !on), "no input, no output, no robot flag is on at boot: {coils:?}");
        assert_eq!(ctx.read_coils(0, COILS).await.unwrap().unwrap(), coils, "the whole space in one request");

        let registers = read_registers(&mut ctx, 0, REGISTERS, MAX_READ_REGISTERS).await;
        let mut expected = vec![0u16; usize::from(REGISTERS)];
        expected[usize::from(ROBOT_STATE)] = NOT_READY;
        assert_eq!(registers, expected, "at boot: NOT READY, zeros elsewhere (no controller version: no robot)");
        assert_eq!(read_registers(&mut ctx, 0, REGISTERS, 7).await, expected, "in small blocks too");
    });
    qemu.finish();
}

#[test]
fn written_coils_and_registers_read_back() {
    let qemu = Qemu::slirp();
    qemu.run(|| async {
        let mut ctx = qemu.connect().await;

        // Coils 16-31: ControlBox digital outputs 1-16.
        let pattern: Vec<bool> = (0..16).map(|i| i % 3 != 1).collect();
        ctx.write_multiple_coils(16, &pattern).await.unwrap().unwrap();
        assert_eq!(ctx.read_coils(16, 16).await.unwrap().unwrap(), pattern);
        let mask = pattern.iter().enumerate().fold(0u16, |mask, (i, &on)| mask | (u16::from(on) << i));
        assert_eq!(ctx.read_holding_registers(1, 1).await.unwrap().unwrap(), [mask], "register 1 is the same pins");
        ctx.write_single_coil(31, false).await.unwrap().unwrap();
        ctx.write_single_coil(17, true).await.unwrap().unwrap();
        let mut expected = pattern.clone();
        expected[15] = false;
        expected[1] = true;
        assert_eq!(ctx.read_coils(16, 16).await.unwrap().unwrap(), expected);

        // Registers 128-255: general purpose.
        let values: Vec<u16> = (0..128u16).map(|i| 0xa55a ^ i.wrapping_mul(0x0101)).collect();
        ctx.write_multiple_registers(128, &values[..64]).await.unwrap().unwrap();
        ctx.write_multiple_registers(192, &values[64..]).await.unwrap().unwrap();
        assert_eq!(read_registers(&mut ctx, 128, 128, MAX_READ_REGISTERS).await, values);
        ctx.write_single_register(255, 0xbeef).await.unwrap().unwrap();
        assert_eq!(ctx.read_holding_registers(254, 2).await.unwrap().unwrap(), [values[126], 0xbeef]);
        ctx.disconnect().await.unwrap();

        // Another connection sees the same image.
        let mut other = qemu.connect().await;
        assert_eq!(other.read_coils(16, 16).await.unwrap().unwrap(), expected);
        let mut values = values;
        values[127] = 0xbeef;
        assert_eq!(read_registers(&mut other, 128, 128, 100).await, values);
    });
    qemu.finish();
}

#[test]
fn each_exception_is_provoked() {
    let qemu = Qemu::slirp();
    qemu.run(|| async {
        let mut ctx = qemu.connect().await;

        // 01 ILLEGAL FUNCTION: function codes the map does not serve (the
        // user-defined ranges, which no future version will take).
        for code in [0x41, 0x64] {
            let reply = ctx.call(Request::Custom(code, Cow::Borrowed(&[0, 0, 0, 1]))).await.unwrap();
            assert_eq!(reply, Err(IllegalFunction), "function {code:#04x}");
        }

        // 02 ILLEGAL DATA ADDRESS: past the end of a space, or a write to a reserved point.
        assert_eq!(ctx.read_holding_registers(REGISTERS, 1).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.read_holding_registers(430, 7).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.read_coils(COILS, 1).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.read_coils(200, 67).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.write_single_register(2, 1).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(ctx.write_single_coil(44, true).await.unwrap(), Err(IllegalDataAddress));
        assert_eq!(
            ctx.write_multiple_registers(254, &[1, 2, 3]).await.unwrap(),
            Ok(()),
            "256 is read-only: seed policy"
        );
        assert_eq!(ctx.write_multiple_registers(434, &[1, 2, 3]).await.unwrap(), Err(IllegalDataAddress));

        // 03 ILLEGAL DATA VALUE: quantities out of range, a single-coil value
        // other than 0xFF00 / 0x0000, analog values the map rejects.
        assert_eq!(ctx.read_holding_registers(0, 0).await.unwrap(), Err(IllegalDataValue));
        assert_eq!(ctx.read_holding_registers(0, MAX_READ_REGISTERS + 1).await.unwrap(), Err(IllegalDataValue));
        assert_eq!(ctx.read_coils(0, MAX_READ_COILS + 1).await.unwrap(), Err(IllegalDataValue));
        let bad_coil_value = Request::Custom(0x05, Cow::Borrowed(&[0x00, 0x10, 0x12, 0x34]));
        let reply = ctx.call(bad_coil_value).await;
        assert_eq!(exception_of(reply, FunctionCode::WriteSingleCoil), Some(IllegalDataValue));
        assert_eq!(ctx.write_single_register(16, 20_001).await.unwrap(), Err(IllegalDataValue), "above 20 mA");
        assert_eq!(ctx.write_single_register(17, 2).await.unwrap(), Err(IllegalDataValue), "type 2 does not exist");

        // Nothing changed, and the connection still serves requests.
        assert_eq!(ctx.read_holding_registers(16, 2).await.unwrap().unwrap(), [0, 0]);
        assert_eq!(ctx.read_coils(16, 1).await.unwrap().unwrap(), [false]);
        assert_eq!(ctx.read_holding_registers(254, 2).await.unwrap().unwrap(), [1, 2], "the accepted write");
    });
    qemu.finish();
}

#[test]
fn eight_connections_are_served_at_once() {
    const CONNECTIONS: u16 = 8;
    const ROUNDS: u16 = 25;
    let qemu = Qemu::slirp();
    qemu.run(|| async {
        // All eight open before any of them does its work.
        let mut contexts = Vec::new();
        for _ in 0..CONNECTIONS {
            contexts.push(qemu.connect().await);
        }
        let mut clients = tokio::task::JoinSet::new();
        for (i, mut ctx) in (0..CONNECTIONS).zip(contexts) {
            clients.spawn(async move {
                let register = 128 + i;
                for round in 0..ROUNDS {
                    let value = round * 100 + i;
                    ctx.write_single_register(register, value).await.unwrap().unwrap();
                    let read = ctx.read_holding_registers(register, 1).await.unwrap().unwrap();
                    assert_eq!(read, [value], "connection {i}, round {round}");
                    let robot = ctx.read_holding_registers(ROBOT_REGISTERS, 4).await.unwrap().unwrap();
                    assert_eq!(robot, NO_ROBOT);
                }
                ctx
            });
        }
        let mut contexts = Vec::new();
        while let Some(done) = clients.join_next().await {
            contexts.push(done.expect("a client task"));
        }
        // Every connection is still open, and every register holds its last value.
        for ctx in &mut contexts {
            let last: Vec<u16> = (0..CONNECTIONS).map(|i| (ROUNDS - 1) * 100 + i).collect();
            assert_eq!(ctx.read_holding_registers(128, CONNECTIONS).await.unwrap().unwrap(), last);
        }
    });
    qemu.finish();
}

#[test]
fn coil_16_lights_led0_and_clearing_it_turns_it_off() {
    let qemu = Qemu::slirp();
    assert_eq!(qemu.read_word(LED0), 0, "both LEDs off at boot");
    qemu.run(|| async {
        let mut ctx = qemu.connect().await;
        ctx.write_single_coil(16, true).await.unwrap().unwrap();
        assert_eq!(qemu.read_word(LED0), 0b01, "coil 16 (output 1) lights LED0");
        ctx.write_single_coil(17, true).await.unwrap().unwrap();
        assert_eq!(qemu.read_word(LED0), 0b11, "coil 17 (output 2) lights LED1");
        ctx.write_single_coil(16, false).await.unwrap().unwrap();
        assert_eq!(qemu.read_word(LED0), 0b10, "clearing coil 16 turns LED0 off");
        // Register 1 is the same pins; outputs 3-16 have no LED.
        ctx.write_single_register(1, 0b1111_0101).await.unwrap().unwrap();
        assert_eq!(qemu.read_word(LED0), 0b01);
        ctx.write_multiple_coils(16, &[false; 16]).await.unwrap().unwrap();
        assert_eq!(qemu.read_word(LED0), 0);
    });
    qemu.finish();
}

#[test]
fn link_loss_closes_the_sessions_and_the_link_s_return_brings_the_server_back() {
    // QEMU's name for the board's NIC (`info network`).
    const NIC: &str = "lan9118.0";
    let qemu = Qemu::slirp();
    qemu.run(|| async {
        let mut held = qemu.connect().await;
        held.write_single_register(200, 0x1234).await.unwrap().unwrap();
        // The network policy has seen the link and the address (it logs on its 100 ms tick).
        qemu.wait_for_log("Modbus TCP server at", Duration::from_secs(2));
        // The cable out: the driver sees it, and the session it held is
        // closed (by the stack, as DHCP's address goes with the link, or else
        // by the network policy; its RST cannot leave, the link is down).
        qemu.monitor(&format!("set_link {NIC} off"));
        qemu.wait_for_log("lan9118: link down", Duration::from_secs(5));
        // The policy looks at the link every 100 ms: wait until it saw the loss.
        let log = qemu.wait_for_log("link down: closing", Duration::from_secs(5));
        assert!(log.contains(": closing 10.0.2.2") || log.contains("link down: closing 1 sessions"), "{log}");
        qemu.monitor(&format!("set_link {NIC} on"));
        // The held connection is gone on the firmware's side: its next
        // request is reset, or never answered.
        let stale = tokio::time::timeout(Duration::from_secs(3), held.read_holding_registers(200, 1)).await;
        assert!(!matches!(stale, Ok(Ok(Ok(_)))), "the session closed on link loss still answers: {stale:?}");
        // A new client is served, with the map as it was.
        let mut ctx = qemu.connect().await;
        assert_eq!(ctx.read_holding_registers(200, 1).await.unwrap().unwrap(), [0x1234], "the image outlived the link");
    });
    let log = qemu.finish();
    assert_eq!(log.matches("lan9118: link up").count(), 2, "up at boot and again after set_link on:\n{log}");
    // The network policy saw the link come back (and asked DHCP again).
    let after_loss = log.split_once("lan9118: link down").map_or("", |(_, rest)| rest);
    assert!(after_loss.lines().any(|line| line.ends_with("INFO  link up")), "{log}");
}

/// m4-mem's copy, move and fill routines, which both images link instead
/// of compiler-builtins', on the core they are written for: the
/// `mem-selftest` image (scripts/test's firmware stage builds it) calls each
/// entry point at every length up to 80 bytes and some long ones, at every
/// alignment and, for moves, every overlap of up to 9 bytes either way, in
/// QEMU's Cortex-M4, and exits 0 only if every byte of the buffer, around
/// the destination too, is what it must be after each call.
#[test]
fn the_copy_move_and_fill_routines_are_right_at_every_length_and_alignment() {
    const BUILD: &str =
        "cargo build -p mps2-an386 --release --target thumbv7em-none-eabihf --features mem-selftest --bin mem-selftest";
    let elf = qemu::image().with_file_name("mem-selftest");
    let built = std::fs::metadata(&elf).and_then(|m| m.modified());
    let built = built.unwrap_or_else(|_| panic!("{} is missing: run `{BUILD}`", elf.display()));
    for source in ["firmware/m4-mem/src/lib.rs", "firmware/mps2-an386/src/bin/mem-selftest.rs"] {
        let changed = std::fs::metadata(qemu::workspace().join(source)).and_then(|m| m.modified()).unwrap();
        assert!(changed <= built, "{} is older than {source}: run `{BUILD}` again", elf.display());
    }
    let output = std::process::Command::new("timeout")
        .args(["120", "qemu-system-arm", "-M", "mps2-an386", "-nographic", "-semihosting", "-monitor", "none"])
        .args(["-serial", "none", "-kernel"])
        .arg(&elf)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{}: {stdout}{}", output.status, String::from_utf8_lossy(&output.stderr));
    assert!(stdout.contains("mem-selftest: 22962 calls right"), "{stdout}");
}
