use super::*;
use crate::settings::{Field, Settings};

/// Settings with every field away from its default.
fn changed() -> Settings {
    let mut s = Settings::DEFAULT;
    for (field, text) in [
        (Field::DeviceName, "cell-4-io"),
        (Field::NetworkMode, "static"),
        (Field::NetworkAddress, "10.1.2.3/16"),
        (Field::NetworkGateway, "10.1.0.1"),
        (Field::NetworkDhcpTimeout, "45"),
        (Field::ModbusPort, "1502"),
        (Field::ModbusUnitId, "7"),
        (Field::ModbusMaxConnections, "3"),
        (Field::ModbusIdleTimeout, "0"),
        (Field::ModbusWritePolicy, "strict"),
        (Field::ModbusAllowConnect, "10.1.0.0/16"),
        (Field::ModbusAllowWrite, "10.1.0.9"),
        (Field::WatchdogTimeout, "500"),
        (Field::WatchdogSafeDo, "0x8001"),
        (Field::WatchdogSafeToolDo, "3"),
        (Field::WatchdogSafeAo1, "4000"),
        (Field::WatchdogSafeAo2, "20000"),
        (Field::RobotLinkAddress, "10.1.0.5:1502/3"),
        (Field::RobotPollInterval, "50"),
    ] {
        s.set(field, text).unwrap();
    }
    s.validate().unwrap();
    s
}

/// The longest settings there are: every text at its longest.
fn longest() -> Settings {
    let mut s = changed();
    let network = "223.255.255.255/32";
    let list = [network; 8].join(",");
    s.set(Field::DeviceName, &"a".repeat(32)).unwrap();
    s.set(Field::NetworkAddress, network).unwrap();
    s.set(Field::NetworkGateway, "223.255.255.255").unwrap();
    s.set(Field::ModbusAllowConnect, &list).unwrap();
    s.set(Field::ModbusAllowWrite, &list).unwrap();
    s.set(Field::ModbusIdleTimeout, "86400").unwrap();
    s.set(Field::WatchdogTimeout, "86400000").unwrap();
    s.set(Field::ModbusUnitId, "247").unwrap();
    s.set(Field::RobotLinkAddress, "255.255.255.255:65535/255").unwrap();
    s.set(Field::RobotPollInterval, "1000").unwrap();
    s.set(Field::NetworkDhcpTimeout, "600").unwrap();
    s.set(Field::ModbusPort, "65535").unwrap();
    s.set(Field::WatchdogSafeDo, "65535").unwrap();
    s.set(Field::WatchdogSafeToolDo, "63").unwrap();
    let role = |c: char| format!("{}=read_write", c.to_string().repeat(24));
    s.set(Field::TlsRoles, &['a', 'b', 'c', 'd'].map(role).join(",")).unwrap();
    s.set(Field::TlsPlainModbus, "off").unwrap();
    s.validate().unwrap();
    s
}

fn encoded(settings: &Settings) -> Vec<u8> {
    let mut out = [0xa5u8; MAX_RECORD_LEN];
    let len = encode(settings, &mut out).unwrap();
    out[..len].to_vec()
}

/// A record of `lines` (each without its newline).
fn record(lines: &[&str]) -> Vec<u8> {
    let mut out = vec![VERSION];
    for line in lines {
        out.extend_from_slice(line.as_bytes());
        out.push(b'\n');
    }
    out
}

#[test]
fn the_default_record_is_one_line_per_field() {
    let bytes = encoded(&Settings::DEFAULT);
    assert_eq!(bytes[0], 1, "version");
    let text = std::str::from_utf8(&bytes[1..]).unwrap();
    assert_eq!(
        text,
        "device.name=\n\
         network.mode=dhcp\n\
         network.address=none\n\
         network.gateway=none\n\
         network.dhcp_timeout_s=30\n\
         modbus.port=502\n\
         modbus.unit_id=any\n\
         modbus.max_connections=8\n\
         modbus.idle_timeout_s=60\n\
         modbus.write_policy=seed\n\
         modbus.allow_connect=any\n\
         modbus.allow_write=any\n\
         watchdog.timeout_ms=0\n\
         watchdog.safe_do=0\n\
         watchdog.safe_tool_do=0\n\
         watchdog.safe_ao1=0\n\
         watchdog.safe_ao2=0\n\
         robot.link=none\n\
         robot.poll_ms=100\n\
         tls.modbus=on\n\
         tls.roles=operator=read_write,viewer=read\n\
         tls.plain_modbus=on\n\
         tls.plain_http=on\n"
    );
}

#[test]
fn decode_of_encode_is_the_settings() {
    for settings in [Settings::DEFAULT, changed(), longest()] {
        let bytes = encoded(&settings);
        // Whatever the factory settings, a whole record gives the same.
        for factory in [Settings::DEFAULT, changed()] {
            assert_eq!(decode(&bytes, &factory), Ok(Decoded { settings, skipped: 0 }));
        }
    }
}

#[test]
fn the_longest_settings_fit_with_room_to_spare() {
    let len = encoded(&longest()).len();
    assert_eq!(len, 1008, "update MAX_RECORD_LEN's doc");
    assert!(len + 200 < MAX_RECORD_LEN);
    let mut small = [0u8; 1007];
    assert_eq!(encode(&longest(), &mut small), Err(RecordError::TooLong));
    assert_eq!(encode(&longest(), &mut []), Err(RecordError::TooLong));
}

#[test]
fn missing_fields_keep_their_factory_value() {
    let factory = changed();
    let decoded = decode(&record(&["modbus.unit_id=9"]), &factory).unwrap();
    let mut expected = factory;
    expected.set(Field::ModbusUnitId, "9").unwrap();
    assert_eq!(decoded.settings, expected);
    assert_eq!(decode(&[VERSION], &factory).unwrap().settings, factory, "no lines: the factory settings");
}

#[test]
fn unknown_keys_are_skipped_and_counted() {
    let decoded = decode(
        &record(&["modbus.unit_id=9", "http.port=8080", "mdns.enabled=yes=no", "modbus.future=x"]),
        &Settings::DEFAULT,
    )
    .unwrap();
    assert_eq!(decoded.skipped, 3);
    assert_eq!(decoded.settings.modbus.unit_id, Some(9));
}

#[test]
fn one_bad_line_rejects_the_whole_record() {
    let good = "modbus.unit_id=9";
    let cases: &[(&[u8], RecordError)] = &[
        (b"", RecordError::Empty),
        (b"\x02modbus.unit_id=9\n", RecordError::Version(2)),
        (b"\xffmodbus.unit_id=9\n", RecordError::Version(0xff)),
        (b"\x01modbus.unit_id=9", RecordError::Malformed { line: 1 }),
        (b"\x01modbus.unit_id=9\nmodbus.port=1", RecordError::Malformed { line: 2 }),
        (b"\x01modbus.unit_id=9\n\n", RecordError::Malformed { line: 2 }),
        (b"\x01modbus.unit_id\n", RecordError::Malformed { line: 1 }),
        (b"\x01=9\n", RecordError::Malformed { line: 1 }),
        (b"\x01modbus=9\n", RecordError::Malformed { line: 1 }),
        (b"\x01modbus.=9\n", RecordError::Malformed { line: 1 }),
        (b"\x01.unit_id=9\n", RecordError::Malformed { line: 1 }),
        (b"\x01Modbus.unit_id=9\n", RecordError::Malformed { line: 1 }),
        (b"\x01modbus.unit id=9\n", RecordError::Malformed { line: 1 }),
        (b"\x01a.b.c=9\n", RecordError::Malformed { line: 1 }),
        (b"\x01modbus.unit_id=\xff\n", RecordError::Malformed { line: 1 }),
        (b"\x01modbus.unit_id=9\r\n", RecordError::Invalid(Field::ModbusUnitId)),
        (b"\x01modbus.unit_id=248\n", RecordError::Invalid(Field::ModbusUnitId)),
        (b"\x01modbus.unit_id=9\nmodbus.unit_id=9\n", RecordError::Duplicate(Field::ModbusUnitId)),
        (b"\x01network.mode=static\n", RecordError::Inconsistent(Field::NetworkAddress)),
        (b"\x01network.gateway=10.0.0.1\n", RecordError::Inconsistent(Field::NetworkGateway)),
    ];
    let factory = Settings::DEFAULT;
    for (bytes, error) in cases {
        assert_eq!(decode(bytes, &factory), Err(*error), "{:?}", String::from_utf8_lossy(bytes));
        // The same line after a good one: still the whole record.
        if let [VERSION, rest @ ..] = bytes {
            let mut late = record(&[good]);
            late.extend_from_slice(rest);
            assert!(decode(&late, &factory).is_err(), "{:?}", String::from_utf8_lossy(&late));
        }
    }
    assert_eq!(
        decode(b"\x01network.mode=static\nnetwork.address=10.0.0.2/8\n", &Settings::DEFAULT)
            .unwrap()
            .settings
            .network
            .mode,
        crate::settings::NetMode::Static,
        "fields that fit together"
    );
}

#[test]
fn every_prefix_is_whole_lines_or_rejected() {
    let bytes = encoded(&longest());
    for len in 0..=bytes.len() {
        let prefix = &bytes[..len];
        match decode(prefix, &Settings::DEFAULT) {
            Ok(decoded) => {
                assert!(len == 1 || prefix.ends_with(b"\n"), "a cut line was taken at {len}");
                // Taken: each field is the record's or the factory's, never a mix within one.
                for &field in Field::ALL {
                    let mut value = String::new();
                    decoded.settings.show(field, &mut value).unwrap();
                    let line = format!("{}={value}\n", field.key());
                    let mut default = String::new();
                    Settings::DEFAULT.show(field, &mut default).unwrap();
                    let ours = std::str::from_utf8(&prefix[1..]).unwrap();
                    assert!(ours.contains(&line) || value == default, "{}", field.key());
                }
            }
            Err(_) => assert!(len == 0 || !prefix.ends_with(b"\n") || len < bytes.len()),
        }
    }
}

#[test]
fn errors_tell_the_field_and_the_rule() {
    assert_eq!(RecordError::Invalid(Field::ModbusUnitId).to_string(), "modbus.unit_id: must be any, or 1-247");
    assert_eq!(RecordError::Malformed { line: 3 }.to_string(), "line 3 is not group.field=value");
    assert_eq!(RecordError::Version(2).to_string(), "record format 2, this firmware reads 1");
}
