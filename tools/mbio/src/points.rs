//! Points by name over Modbus TCP (tokio-modbus), from the map the firmware
//! serves: `adapter::map::names` gives each name's registers, unit and
//! scale; the map's table what they hold, who may write them and which
//! coil views each pin.

use std::net::SocketAddr;

use adapter::map::names::{POINTS, Point, pin_coil};
use adapter::map::table::{RegisterRow, register_row};
use adapter::map::{Encoding, Permission};
use comfy_table::Table;
use serde_json::{Value, json};
use tokio_modbus::client::{Context as Modbus, Reader as _, Writer as _};

use crate::device::{Context, Device};
use crate::{Failure, Outcome};

/// A point as the user named it: the map's point, and one element of it
/// (a pin, counted from 1, or one register of several), or all of it.
#[derive(Debug, Clone, Copy)]
pub struct Target {
    pub point: &'static Point,
    pub row: &'static RegisterRow,
    pub index: Option<u16>,
}

impl Target {
    /// `name`, or `name.N` for element N.
    pub fn parse(spec: &str) -> Outcome<Self> {
        let unknown = || Failure::Usage(format!("{spec}: no such point (`mbio points` lists them)"));
        let (point, index) = match adapter::map::names::point(spec) {
            Some(point) => (point, None),
            None => {
                let (name, index) = spec.rsplit_once('.').ok_or_else(unknown)?;
                let point = adapter::map::names::point(name).ok_or_else(unknown)?;
                let index: u16 = index.parse().map_err(|_| unknown())?;
                (point, Some(index))
            }
        };
        let row = point.row().ok_or_else(unknown)?;
        if let Some(index) = index {
            let elements = match row.encoding {
                Encoding::Pins { pins } => u16::from(pins),
                _ if point.count > 1 => point.count,
                _ => return Err(Failure::Usage(format!("{spec}: {} has no elements", point.name))),
            };
            if index == 0 || index > elements {
                return Err(Failure::Usage(format!("{spec}: {} has elements 1-{elements}", point.name)));
            }
        }
        Ok(Self { point, row, index })
    }

    fn label(&self) -> String {
        match self.index {
            Some(index) => format!("{}.{index}", self.point.name),
            None => self.point.name.to_owned(),
        }
    }
}

/// `10^decimals`.
fn scale(point: &Point) -> f64 {
    10f64.powi(i32::from(point.decimals))
}

/// A register's value as the point's encoding reads it.
fn number(row: &RegisterRow, raw: u16) -> f64 {
    match row.encoding {
        Encoding::Signed => f64::from(raw as i16),
        _ => f64::from(raw),
    }
}

fn analog_unit(kind: u16) -> &'static str {
    if kind == adapter::map::table::ANALOG_VOLTAGE { "V" } else { "mA" }
}

/// One point read: lines for a person, a value for JSON.
fn show(target: &Target, registers: &[u16], analog_type: Option<u16>) -> (Vec<String>, Value) {
    let label = target.label();
    let point = target.point;
    let first = registers.first().copied().unwrap_or(0);
    match target.row.encoding {
        Encoding::Pins { pins } => match target.index {
            Some(pin) => {
                let on = first >> (pin - 1) & 1 == 1;
                (vec![format!("{label} = {}", if on { "on" } else { "off" })], json!(on))
            }
            None => {
                let states: Vec<bool> = (0..pins).map(|bit| first >> bit & 1 == 1).collect();
                let on: Vec<String> =
                    (1..=pins).filter(|pin| first >> (pin - 1) & 1 == 1).map(|p| p.to_string()).collect();
                let width = usize::from(pins);
                let line = format!(
                    "{label} = {first:0width$b} (on: {})",
                    if on.is_empty() { "none".into() } else { on.join(" ") }
                );
                (vec![line], json!(states))
            }
        },
        Encoding::Analog { .. } => {
            let kind = analog_type.unwrap_or(0);
            let value = f64::from(first) / scale(point);
            (
                vec![format!("{label} = {value} {}", analog_unit(kind))],
                json!({"value": value, "unit": analog_unit(kind)}),
            )
        }
        Encoding::AnalogType => {
            let name = if first == adapter::map::table::ANALOG_VOLTAGE { "voltage" } else { "current" };
            (vec![format!("{label} = {name}")], json!(name))
        }
        Encoding::Bool => (vec![format!("{label} = {}", if first != 0 { "on" } else { "off" })], json!(first != 0)),
        Encoding::RobotState => {
            let name = adapter::map::names::robot_state_name(first);
            (vec![format!("{label} = {name} ({first})")], json!({"code": first, "name": name}))
        }
        Encoding::SafetyStop | Encoding::Unsigned | Encoding::Signed | Encoding::Zero => {
            let values: Vec<f64> = registers.iter().map(|&raw| number(target.row, raw) / scale(point)).collect();
            let unit = if point.unit.is_empty() { String::new() } else { format!(" {}", point.unit) };
            if let (None, true) = (target.index, values.len() > 1) {
                let lines = values.iter().enumerate().map(|(i, v)| format!("{label}.{} = {v}{unit}", i + 1)).collect();
                (lines, json!({"values": values, "unit": point.unit}))
            } else {
                let value = values.first().copied().unwrap_or(0.0);
                (vec![format!("{label} = {value}{unit}")], json!({"value": value, "unit": point.unit}))
            }
        }
    }
}

/// A Modbus connection to the device.
async fn connect(ctx: &Context, device: &Device) -> Outcome<Modbus> {
    let addr = SocketAddr::from((device.ip, ctx.modbus_port));
    let connect = tokio_modbus::client::tcp::connect(addr);
    match tokio::time::timeout(std::time::Duration::from_secs(5), connect).await {
        Ok(Ok(modbus)) => Ok(modbus),
        Ok(Err(e)) => Err(Failure::Unreachable(format!("{} ({addr}): Modbus: {e}", device.label))),
        Err(_) => Err(Failure::Unreachable(format!("{} ({addr}): Modbus: no connection within 5 s", device.label))),
    }
}

/// One request's outcome as mbio's: an exception is the device's refusal.
fn answer<T>(device: &Device, what: &str, result: tokio_modbus::Result<T>) -> Outcome<T> {
    match result {
        Ok(Ok(value)) => Ok(value),
        Ok(Err(exception)) => Err(Failure::Refused(format!("{}: {what}: exception {exception}", device.label))),
        Err(e) => Err(Failure::Unreachable(format!("{}: {what}: {e}", device.label))),
    }
}

/// A current-thread tokio runtime for the Modbus client.
pub fn runtime() -> Outcome<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| Failure::Refused(format!("no async runtime: {e}")))
}

/// Reads `target`: its registers, and an analog value's type register.
async fn read_one(modbus: &mut Modbus, device: &Device, target: &Target) -> Outcome<(Vec<u16>, Option<u16>)> {
    let (first, count) = match (target.index, target.row.encoding) {
        (Some(index), encoding) if !matches!(encoding, Encoding::Pins { .. }) => (target.point.register + index - 1, 1),
        _ => (target.point.register, target.point.count),
    };
    let what = format!("read {}", target.label());
    let request = modbus.read_holding_registers(first, count).await;
    let registers = answer(device, &what, request)?;
    if registers.len() != usize::from(count) {
        return Err(Failure::BadReply(format!("{}: {what}: {} registers for {count}", device.label, registers.len())));
    }
    let analog_type = match target.row.encoding {
        Encoding::Analog { type_register } => {
            let request = modbus.read_holding_registers(type_register, 1).await;
            answer(device, &what, request)?.first().copied()
        }
        _ => None,
    };
    Ok((registers, analog_type))
}

/// `mbio read NAME POINT...`.
pub fn read(ctx: &Context, target: &str, specs: &[String], json: bool) -> Outcome {
    let targets = specs.iter().map(|s| Target::parse(s)).collect::<Outcome<Vec<_>>>()?;
    let device = ctx.resolve(target)?;
    let results = runtime()?.block_on(async {
        let mut modbus = connect(ctx, &device).await?;
        let mut results = Vec::new();
        for target in &targets {
            let (registers, analog_type) = read_one(&mut modbus, &device, target).await?;
            results.push((target.label(), show(target, &registers, analog_type)));
        }
        Outcome::Ok(results)
    })?;
    if json {
        let map: serde_json::Map<String, Value> =
            results.into_iter().map(|(label, (_, value))| (label, value)).collect();
        crate::print_json(&Value::Object(map));
    } else {
        for (_, (lines, _)) in results {
            for line in lines {
                say!("{line}");
            }
        }
    }
    Ok(())
}

/// What a write does on the wire.
#[derive(Debug, PartialEq, Eq)]
pub enum Write {
    Coil {
        address: u16,
        on: bool,
    },
    /// A register; for an analog value, checked against its type on the device.
    Register {
        address: u16,
        value: u16,
    },
}

fn parse_bool(value: &str) -> Option<bool> {
    match value.to_ascii_lowercase().as_str() {
        "on" | "1" | "true" | "yes" => Some(true),
        "off" | "0" | "false" | "no" => Some(false),
        _ => None,
    }
}

fn parse_u16(value: &str) -> Option<u16> {
    match value.strip_prefix("0x").or_else(|| value.strip_prefix("0X")) {
        Some(hex) => u16::from_str_radix(hex, 16).ok(),
        None => value.strip_prefix("0b").map_or_else(|| value.parse().ok(), |bin| u16::from_str_radix(bin, 2).ok()),
    }
}

/// `POINT=VALUE` as a write, checked against the map before anything is
/// sent: the point writable, the value in its encoding's range. An analog
/// value's range depends on its type, which the device holds: `analog_type`.
pub fn plan(spec: &str, analog_type: impl FnOnce(u16) -> Outcome<u16>) -> Outcome<Write> {
    let (name, value) = spec.split_once('=').ok_or_else(|| Failure::Usage(format!("{spec}: not POINT=VALUE")))?;
    let target = Target::parse(name)?;
    if !target.row.access.writable() || target.row.access == Permission::Reserved {
        return Err(Failure::Usage(format!("{name}: read only")));
    }
    let bad = |why: &str| Failure::Usage(format!("{spec}: {why}"));
    let register = target.point.register + target.index.filter(|_| target.point.count > 1).map_or(0, |i| i - 1);
    match target.row.encoding {
        Encoding::Pins { pins } => match target.index {
            Some(pin) => {
                let on = parse_bool(value).ok_or_else(|| bad("on or off"))?;
                let pin = u8::try_from(pin).map_err(|_| bad("no such pin"))?;
                let address = pin_coil(target.point.register, pin).ok_or_else(|| bad("no coil views this pin"))?;
                Ok(Write::Coil { address, on })
            }
            None => {
                let mask = parse_u16(value).ok_or_else(|| bad("a mask: decimal, 0x hex or 0b binary"))?;
                if !target.row.encoding.accepts(mask, 0) {
                    return Err(bad(&format!("{pins} pins: bits above them must be 0")));
                }
                Ok(Write::Register { address: register, value: mask })
            }
        },
        Encoding::AnalogType => {
            let kind = match value {
                "current" | "0" => adapter::map::table::ANALOG_CURRENT,
                "voltage" | "1" => adapter::map::table::ANALOG_VOLTAGE,
                _ => return Err(bad("current or voltage")),
            };
            Ok(Write::Register { address: register, value: kind })
        }
        Encoding::Analog { type_register } => {
            let kind = analog_type(type_register)?;
            let number: f64 = value.trim_end_matches(analog_unit(kind)).trim().parse().map_err(|_| bad("a number"))?;
            let raw = (number * scale(target.point)).round();
            if !(0.0..=f64::from(u16::MAX)).contains(&raw) || !target.row.encoding.accepts(raw as u16, kind) {
                let max = if kind == adapter::map::table::ANALOG_VOLTAGE { "10 V" } else { "20 mA" };
                return Err(bad(&format!("0 to {max} (its type now)")));
            }
            Ok(Write::Register { address: register, value: raw as u16 })
        }
        Encoding::Bool => Ok(Write::Register {
            address: register,
            value: u16::from(parse_bool(value).ok_or_else(|| bad("on or off"))?),
        }),
        Encoding::Unsigned | Encoding::Signed | Encoding::SafetyStop | Encoding::RobotState | Encoding::Zero => {
            if target.point.count > 1 && target.index.is_none() {
                return Err(bad(&format!(
                    "name one of its {} registers ({}.N)",
                    target.point.count, target.point.name
                )));
            }
            let number: f64 = value.trim_end_matches(target.point.unit).trim().parse().map_err(|_| bad("a number"))?;
            let raw = (number * scale(target.point)).round();
            let value = match target.row.encoding {
                Encoding::Signed if (f64::from(i16::MIN)..=f64::from(i16::MAX)).contains(&raw) => raw as i16 as u16,
                Encoding::Signed => return Err(bad("out of range")),
                _ if (0.0..=f64::from(u16::MAX)).contains(&raw) => raw as u16,
                _ => return Err(bad("out of range")),
            };
            if !target.row.encoding.accepts(value, 0) {
                return Err(bad("out of range"));
            }
            Ok(Write::Register { address: register, value })
        }
    }
}

/// `mbio write NAME POINT=VALUE...`: each checked first, then written in order.
pub fn write(ctx: &Context, target: &str, specs: &[String]) -> Outcome {
    // Points and values are checked before the device is asked anything
    // (the analog ones again once their type is read).
    for spec in specs {
        plan(spec, |_| Ok(0))?;
    }
    let device = ctx.resolve(target)?;
    runtime()?.block_on(async {
        let mut modbus = connect(ctx, &device).await?;
        for spec in specs {
            let mut analog_type = None;
            if let Some(Encoding::Analog { type_register }) =
                spec.split_once('=').and_then(|(name, _)| Target::parse(name).ok()).map(|t| t.row.encoding)
            {
                let request = modbus.read_holding_registers(type_register, 1).await;
                analog_type = answer(&device, spec, request)?.first().copied();
            }
            let write = plan(spec, |_| Ok(analog_type.unwrap_or(0)))?;
            match write {
                Write::Coil { address, on } => answer(&device, spec, modbus.write_single_coil(address, on).await)?,
                Write::Register { address, value } => {
                    answer(&device, spec, modbus.write_single_register(address, value).await)?;
                }
            }
            say!("{}: {spec}", device.label);
        }
        Outcome::Ok(())
    })
}

/// `mbio points`: every name, its registers, unit and access.
pub fn list(json: bool) -> Outcome {
    let rows: Vec<Value> = POINTS
        .iter()
        .map(|p| {
            let row = register_row(p.register);
            let access = match row.map(|r| r.access) {
                Some(Permission::ReadWrite) => "read/write",
                Some(Permission::Write) => "write (reads back)",
                Some(Permission::Read) => "read",
                _ => "-",
            };
            let unit = match row.map(|r| r.encoding) {
                Some(Encoding::Analog { .. }) => "mA or V",
                Some(Encoding::Pins { .. }) => "on/off per pin",
                _ => p.unit,
            };
            let last = p.register + p.count - 1;
            json!({"name": p.name, "registers": format!("{}-{last}", p.register), "unit": unit, "access": access, "about": p.about})
        })
        .collect();
    if json {
        crate::print_json(&Value::Array(rows));
        return Ok(());
    }
    let mut table = Table::new();
    table.load_style(comfy_table::presets::NOTHING);
    table.set_header(["POINT", "REGISTERS", "UNIT", "ACCESS", "WHAT"]);
    for row in rows {
        table.add_row(
            ["name", "registers", "unit", "access", "about"]
                .map(|k| crate::device::text(row.get(k).unwrap_or(&Value::Null))),
        );
    }
    say!("{table}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_become_registers_and_coils_from_the_map() {
        assert_eq!(plan("do.3=on", |_| unreachable!()).unwrap(), Write::Coil { address: 18, on: true });
        assert_eq!(plan("tool_do.6=off", |_| unreachable!()).unwrap(), Write::Coil { address: 43, on: false });
        assert_eq!(plan("do=0x8001", |_| unreachable!()).unwrap(), Write::Register { address: 1, value: 0x8001 });
        assert_eq!(plan("gp.2=7", |_| unreachable!()).unwrap(), Write::Register { address: 129, value: 7 });
        assert_eq!(plan("ao.1.type=voltage", |_| unreachable!()).unwrap(), Write::Register { address: 17, value: 1 });
        assert_eq!(
            plan("ao.2=12.5", |t| Ok(if t == 19 { 0 } else { 9 })).unwrap(),
            Write::Register { address: 18, value: 12_500 }
        );
        assert_eq!(plan("ao.1=7.5V", |_| Ok(1)).unwrap(), Write::Register { address: 16, value: 7_500 });
    }

    #[test]
    fn bad_writes_are_refused_before_anything_is_sent() {
        for spec in [
            "di.1=on",
            "robot.joint_position.1=3",
            "do.17=on",
            "do.0=on",
            "do.3=maybe",
            "tool_do=0x40",
            "ao.1=25",
            "gp.1=70000",
            "gp=1",
            "nothing=1",
            "do.3",
        ] {
            assert!(matches!(plan(spec, |_| Ok(0)), Err(Failure::Usage(_))), "{spec}");
        }
        assert!(matches!(plan("ao.1=12", |_| Ok(1)), Err(Failure::Usage(_))), "12 V is over 10 V");
    }

    #[test]
    fn values_are_shown_in_their_units() {
        let joints = Target::parse("robot.joint_position").unwrap();
        let (lines, value) = show(&joints, &[900, (-455i16) as u16, 0, 1, 2, 3], None);
        assert_eq!(lines.first().unwrap(), "robot.joint_position.1 = 90 deg");
        assert_eq!(lines.get(1).unwrap(), "robot.joint_position.2 = -45.5 deg");
        assert_eq!(value["values"].as_array().unwrap().len(), 6);
        let pin = Target::parse("do.3").unwrap();
        assert_eq!(show(&pin, &[0b100], None).0, ["do.3 = on"]);
        let analog = Target::parse("ai.2").unwrap();
        assert_eq!(show(&analog, &[4_250], Some(1)).0, ["ai.2 = 4.25 V"]);
        let state = Target::parse("robot.state").unwrap();
        assert_eq!(show(&state, &[15], None).0, ["robot.state = not_ready (15)"]);
        assert!(Target::parse("robot.state.1").is_err());
        assert!(Target::parse("robot.joint_position.7").is_err());
    }
}
