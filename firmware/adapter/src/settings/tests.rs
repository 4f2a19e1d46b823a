use super::*;

fn shown(settings: &Settings, field: Field) -> String {
    let mut text = String::new();
    settings.show(field, &mut text).unwrap();
    text
}

#[test]
fn the_table_is_whole_and_unambiguous() {
    assert_eq!(Field::ALL.len(), 23);
    for (i, a) in Field::ALL.iter().enumerate() {
        for b in &Field::ALL[i + 1..] {
            assert_ne!(a.key(), b.key());
            assert_ne!(a.env(), b.env());
            assert_ne!(a.flag(), b.flag());
        }
        assert_eq!(a.key(), format!("{}.{}", a.group(), a.name()));
        assert!(!a.rule().is_empty() && !a.flag().starts_with('-'));
    }
}

#[test]
fn every_default_shows_as_its_parser_takes_it_back() {
    let mut settings = Settings::DEFAULT;
    settings.device.name = Name::parse("io-7").unwrap();
    settings.network.address = Cidr::parse_optional("10.1.2.3/16").unwrap();
    settings.network.gateway = Ipv4::parse_optional("10.1.0.1").unwrap();
    settings.modbus.allow_write = parse::allow_list("10.1.0.0/16,10.2.0.9/32").unwrap();
    settings.robot.link = RobotLink::parse_optional("10.1.0.5:1502/3").unwrap();
    for settings in [Settings::DEFAULT, settings] {
        for &field in Field::ALL {
            let text = shown(&settings, field);
            let mut again = settings;
            again.set(field, &text).unwrap_or_else(|rule| panic!("{}={text}: {rule}", field.key()));
            assert_eq!(again, settings, "{}={text} sets what was shown", field.key());
            let mut fresh = Settings::DEFAULT;
            fresh.set(field, &text).unwrap();
            assert_eq!(shown(&fresh, field), text, "{}", field.key());
        }
    }
}

#[test]
fn each_field_keeps_its_range() {
    let mut s = Settings::DEFAULT;
    let cases: &[(Field, &[&str], &[&str])] = &[
        (Field::ModbusUnitId, &["any", "1", "247"], &["0", "248", "", "x"]),
        (Field::ModbusPort, &["1", "65535"], &["0", "65536"]),
        (Field::ModbusMaxConnections, &["1"], &["0", "33"]),
        (Field::ModbusIdleTimeout, &["0", "86400"], &["86401", "-1"]),
        (Field::ModbusWritePolicy, &["seed", "strict"], &["Seed", ""]),
        (Field::WatchdogTimeout, &["0", "100", "86400000"], &["1", "99", "86400001"]),
        (Field::WatchdogSafeDo, &["0xffff", "65535"], &["65536"]),
        (Field::WatchdogSafeToolDo, &["0x3f", "63"], &["64", "0x40"]),
        (Field::WatchdogSafeAo1, &["0", "20000"], &["20001"]),
        (Field::NetworkDhcpTimeout, &["5", "600"], &["4", "601"]),
        (Field::NetworkMode, &["dhcp", "static"], &["auto"]),
        (Field::RobotPollInterval, &["20", "1000"], &["19", "1001"]),
        (Field::DeviceName, &["a", "cell-4", ""], &["-a", "A"]),
    ];
    for (field, good, bad) in cases {
        for text in *good {
            assert_eq!(s.set(*field, text), Ok(()), "{}={text}", field.key());
        }
        for text in *bad {
            let before = s;
            assert_eq!(s.set(*field, text), Err(field.rule()), "{}={text}", field.key());
            assert_eq!(s, before, "a rejected value changes nothing");
        }
    }
    const { assert!(MAX_CONNECTIONS < 33) };
}

#[test]
fn the_whole_is_validated_with_an_error_per_field() {
    let mut s = Settings::DEFAULT;
    assert_eq!(s.validate(), Ok(()));
    s.set(Field::NetworkMode, "static").unwrap();
    s.set(Field::NetworkGateway, "10.0.0.1").unwrap();
    let errors = s.validate().unwrap_err();
    let fields: Vec<Field> = errors.iter().map(|(field, _)| *field).collect();
    assert_eq!(fields, [Field::NetworkAddress, Field::NetworkGateway]);
    assert_eq!(
        errors.to_string(),
        "network.address: required when the mode is static\nnetwork.gateway: needs an address"
    );
    s.set(Field::NetworkAddress, "192.168.1.50/24").unwrap();
    assert_eq!(s.validate().unwrap_err().to_string(), "network.gateway: must lie inside the address's network");
    s.set(Field::NetworkGateway, "192.168.1.1").unwrap();
    assert_eq!(s.validate(), Ok(()));
}

#[test]
fn the_defaults_make_the_documented_server() {
    let mac = [2, 0, 0, 0xab, 0xcd, 0xef];
    let config = Settings::DEFAULT.server_config(mac);
    assert_eq!(config, server::Config { name: Name::parse("mbio-abcdef").unwrap(), ..server::Config::DEFAULT });
    let mut named = Settings::DEFAULT;
    named.set(Field::DeviceName, "press-4").unwrap();
    assert_eq!(named.server_config(mac).name.as_str(), "press-4", "a name set wins over the MAC's");
    let mut s = Settings::DEFAULT;
    s.set(Field::WatchdogTimeout, "500").unwrap();
    s.set(Field::WatchdogSafeAo2, "4000").unwrap();
    s.set(Field::ModbusIdleTimeout, "0").unwrap();
    assert_eq!(s.watchdog().timeout, Some(Duration::from_millis(500)));
    assert_eq!(s.watchdog().safe_state.analog, [0, 4000]);
    assert_eq!(s.server_config(mac).idle_timeout, None);
    assert_eq!(Settings::DEFAULT.watchdog(), Watchdog::OFF);
}

#[test]
fn build_variables_apply_when_set() {
    // CI builds without them: the defaults stand.
    const BUILT: Settings = Settings::DEFAULT.with_build_env();
    for &field in Field::ALL {
        if std::env::var_os(field.env()).is_none() {
            assert_eq!(shown(&BUILT, field), shown(&Settings::DEFAULT, field), "{}", field.env());
        }
    }
}

#[test]
fn a_reboot_is_required_only_for_changed_after_reboot_fields() {
    let old = Settings::DEFAULT;
    let mut new = old;
    assert!(!old.reboot_required(&new));
    for &field in Field::ALL {
        assert!(!old.differs(&new, field));
    }
    new.set(Field::ModbusUnitId, "7").unwrap();
    new.set(Field::WatchdogTimeout, "500").unwrap();
    assert!(old.differs(&new, Field::ModbusUnitId) && !old.differs(&new, Field::ModbusPort));
    assert!(!old.reboot_required(&new), "both apply at once");
    new.set(Field::ModbusPort, "1502").unwrap();
    assert!(old.reboot_required(&new) && new.reboot_required(&old));
    let mut same_port = new;
    same_port.set(Field::ModbusPort, "502").unwrap();
    assert!(!old.reboot_required(&same_port), "set back to what it was: no change");
}
