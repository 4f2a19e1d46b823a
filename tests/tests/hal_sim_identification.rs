//! Read Device Identification (2B/0E) and Diagnostics (08) of hal-sim over
//! real TCP in its network namespace: pymodbus' client
//! (`tests/peers/pymodbus_identification.py`), raw frames for what no client
//! library sends, the device name changed through the settings API, and a
//! client outside the write allow-list (docs/data-map.md).

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use system_tests::hal_sim::{HalSim, PORT, read_frame};
use system_tests::netns::DEVICE_IP;
use test_support::framer::adu;
use tokio::io::AsyncWriteExt;
use tokio_modbus::client::{Context, Reader as _};
use tokio_modbus::prelude::{ConformityLevel, ExceptionCode, ReadCode};

/// hal-sim's firmware version as `hal-sim --version` prints it (`A.B.C`).
fn firmware_version() -> String {
    system_tests::hal_sim::firmware_version().map(|part| part.to_string()).join(".")
}

/// One Read Device Identification object (code 04) through tokio-modbus,
/// which implements 2B/0E itself: a second client of it, besides pymodbus.
async fn object(ctx: &mut Context, id: u8) -> Result<Vec<u8>, ExceptionCode> {
    let reply = ctx.read_device_identification(ReadCode::Specific, id).await.unwrap()?;
    assert_eq!(reply.read_code, ReadCode::Specific);
    assert_eq!(reply.conformity_level, ConformityLevel::RegularIdentification, "0x82");
    assert_eq!((reply.more_follows, reply.next_object_id), (false, 0));
    let [object] = &reply.device_id_objects[..] else { panic!("one object: {reply:?}") };
    assert_eq!(object.id, id);
    Ok(object.value.to_vec())
}

/// Sends `pdu` (unit 1) on `raw` and returns the reply's PDU. tokio-modbus
/// knows function 08 but sends none of its sub-functions: these are raw frames.
async fn ask(raw: &mut tokio::net::TcpStream, transaction: u16, pdu: &[u8]) -> Vec<u8> {
    raw.write_all(&adu(transaction, 0, 1, pdu)).await.unwrap();
    let reply = read_frame(raw, Duration::from_secs(2)).await.expect("a reply");
    assert_eq!(reply[..7], adu(transaction, 0, 1, &reply[7..])[..7], "the header of {reply:02x?}");
    reply[7..].to_vec()
}

/// Diagnostics' counter `sub` (08/00xx).
async fn count(raw: &mut tokio::net::TcpStream, sub: u8) -> u16 {
    let reply = ask(raw, 0x0800 + u16::from(sub), &[0x08, 0x00, sub, 0x00, 0x00]).await;
    assert_eq!((reply.len(), &reply[..3]), (5, &[0x08, 0x00, sub][..]), "{reply:02x?}");
    u16::from_be_bytes([reply[3], reply[4]])
}

/// Clear Counters (08/000A): its reply.
async fn clear(raw: &mut tokio::net::TcpStream) -> Vec<u8> {
    ask(raw, 0x080a, &[0x08, 0x00, 0x0a, 0x00, 0x00]).await
}

#[test]
fn pymodbus_reads_the_identification_and_the_diagnostics() {
    let probe = Command::new("python3").args(["-c", "import pymodbus"]).output();
    assert!(
        probe.as_ref().is_ok_and(|o| o.status.success()),
        "this test needs python3 with pymodbus: `pip install pymodbus` ({probe:?})"
    );
    let sim = HalSim::start(&["--robot", "idle", "--name", "cell-7"]);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("peers/pymodbus_identification.py");
    let output = sim
        .ns()
        .command("python3")
        .arg(&script)
        .args([DEVICE_IP, &PORT.to_string(), &firmware_version(), "cell-7"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    println!("{stdout}");
    assert!(output.status.success(), "pymodbus failed:\n{stdout}\n{}", String::from_utf8_lossy(&output.stderr));
    assert!(stdout.contains(" passed, 0 failed"), "{stdout}");
}

#[test]
fn raw_frames_get_the_exceptions_the_specification_gives() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let mut raw = sim.raw().await;
        #[rustfmt::skip]
        let cases: [(&[u8], &[u8]); 12] = [
            (&[0x2b, 0x0d, 0x01, 0x00], &[0xab, 0x01]),       // MEI type 0D (CANopen): not served
            (&[0x2b], &[0xab, 0x01]),                         // no MEI type
            (&[0x2b, 0x0e, 0x01], &[0xab, 0x03]),             // no object id
            (&[0x2b, 0x0e, 0x01, 0x00, 0x00], &[0xab, 0x03]), // a byte too many
            (&[0x2b, 0x0e, 0x00, 0x00], &[0xab, 0x03]),       // read code 00
            (&[0x2b, 0x0e, 0x04, 0xff], &[0xab, 0x02]),       // no object 0xFF
            (&[0x08, 0x00, 0x0b, 0x00, 0x01], &[0x88, 0x03]), // a count's data is 0000
            (&[0x08, 0x00, 0x0a, 0x12, 0x34], &[0x88, 0x03]), // so is the clear's
            (&[0x08, 0x00], &[0x88, 0x03]),                   // no whole sub-function
            (&[0x08, 0x00, 0x04, 0x00, 0x00], &[0x88, 0x01]), // force listen only: not served
            (&[0x08, 0xff, 0xff], &[0x88, 0x01]),             // nor any other
            (&[0x07], &[0x87, 0x01]),                         // FC 07: serial line only
        ];
        for (i, (pdu, want)) in cases.iter().enumerate() {
            let transaction = 0x0700 + i as u16;
            raw.write_all(&adu(transaction, 0, 1, pdu)).await.unwrap();
            let reply = read_frame(&mut raw, Duration::from_secs(2)).await;
            assert_eq!(reply, Some(adu(transaction, 0, 1, want)), "{pdu:02x?}");
        }
        // An empty query is echoed; the largest fills the largest ADU.
        let empty = adu(0x0800, 0, 1, &[0x08, 0x00, 0x00]);
        raw.write_all(&empty).await.unwrap();
        assert_eq!(read_frame(&mut raw, Duration::from_secs(2)).await, Some(empty));
        let largest = adu(0x0801, 0, 1, &[&[0x08, 0x00, 0x00][..], &[0xa5; 250]].concat());
        raw.write_all(&largest).await.unwrap();
        let reply = read_frame(&mut raw, Duration::from_secs(2)).await.unwrap();
        assert_eq!((reply.len(), &reply), (260, &largest));
    });
}

#[test]
fn the_counters_are_hal_sim_s_own_and_a_clear_empties_them() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        ctx.read_holding_registers(128, 2).await.unwrap().unwrap();
        assert_eq!(ctx.read_holding_registers(436, 1).await.unwrap(), Err(ExceptionCode::IllegalDataAddress));
        let mut raw = sim.raw().await;
        raw.write_all(&adu(1, 5, 1, &[0x03, 0x00, 0x80, 0x00, 0x01])).await.unwrap(); // protocol 5: skipped
        assert_eq!(ask(&mut raw, 2, &[0x03, 0x00, 0x80, 0x00, 0x01]).await, [0x03, 0x02, 0x00, 0x00]);
        let counters = sim.stats();
        assert_eq!(count(&mut raw, 0x0b).await, (counters["requests"] + counters["bad_protocol"]) as u16);
        assert_eq!(count(&mut raw, 0x0d).await, 1, "the read past the end");
        assert_eq!(count(&mut raw, 0x0e).await, counters["requests"] as u16 + 2, "with the two reads since");
        assert_eq!(count(&mut raw, 0x0f).await, 1, "the frame of protocol 5");
        assert_eq!((count(&mut raw, 0x0c).await, count(&mut raw, 0x12).await), (0, 0));
        assert_eq!(clear(&mut raw).await, [0x08, 0x00, 0x0a, 0x00, 0x00]);
        assert_eq!(count(&mut raw, 0x0b).await, 1, "only the clear since");
        assert_eq!(count(&mut raw, 0x0d).await, 0);
    });
    let counters = sim.stats();
    assert_eq!((counters["requests"], counters["bad_address"], counters["bad_protocol"]), (3, 0, 0));
}

#[test]
fn the_user_application_name_follows_the_settings_api_at_once() {
    let sim = HalSim::start(&["--robot", "idle"]);
    sim.run(|| async {
        let mut ctx = sim.connect().await;
        assert_eq!(object(&mut ctx, 0x05).await, Ok(b"hal-sim".to_vec()), "the model");
        assert_eq!(object(&mut ctx, 0x02).await, Ok(firmware_version().into_bytes()), "the firmware's version");
        let default = object(&mut ctx, 0x06).await.unwrap();
        assert_eq!(default, b"mbio-53494d", "the default name, from hal-sim's MAC");
        assert_eq!(object(&mut ctx, 0x07).await, Err(ExceptionCode::IllegalDataAddress));
        let reply = sim.put("/api/settings", r#"{"device": {"name": "press-9"}}"#, Some(sim.claim()));
        assert_eq!(reply.status, 200, "{}", reply.body);
        assert_eq!(reply.json()["reboot_required"], false);
        // The same connection, the next request: the new name.
        assert_eq!(object(&mut ctx, 0x06).await, Ok(b"press-9".to_vec()));
        let status = sim.get("/api/status").json();
        assert_eq!(status["device"]["name"], "press-9", "the page's name and 0x2B's agree");
        assert_eq!(status["device"]["firmware"], firmware_version());
        assert_eq!(status["device"]["model"], "hal-sim");
    });
}

#[test]
fn a_client_outside_the_write_allow_list_may_read_but_not_clear_the_counters() {
    let sim = HalSim::start(&["--robot", "idle", "--allow-write", "198.18.0.200"]);
    sim.run(|| async {
        let mut raw = sim.raw().await;
        assert_eq!(clear(&mut raw).await, [0x88, 0x01], "a change: refused");
        assert_eq!(count(&mut raw, 0x0b).await, 1, "not cleared: the refused clear came before");
        let mut ctx = sim.connect().await;
        assert_eq!(object(&mut ctx, 0x00).await, Ok(b"mbio".to_vec()), "identification is a read");
    });
    let counters = sim.stats();
    assert_eq!((counters["requests"], counters["refused_writes"], counters["bad_function"]), (3, 1, 0));
}
