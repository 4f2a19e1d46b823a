//! `mbio watch`: a live view of a device's I/O and robot, redrawn with
//! ANSI escapes from `/api/status` (one request at a time, as the page does).

use std::time::Duration;

use serde_json::Value;

use crate::Outcome;
use crate::device::{Context, text};

fn lamps(mask: u64, count: u32) -> String {
    (0..count).map(|bit| if mask >> bit & 1 == 1 { '#' } else { '.' }).collect()
}

/// The screen for one status document.
pub fn screen(label: &str, status: &Value) -> String {
    let get = |group: &str, key: &str| status.get(group).and_then(|g| g.get(key)).cloned().unwrap_or(Value::Null);
    let mask = |key: &str| get("io", key).as_u64().unwrap_or(0);
    let pair = |key: &str| {
        let values = get("io", key);
        let types = get("io", &format!("{key}_types"));
        (0..2)
            .map(|i| {
                let value = values.get(i).and_then(Value::as_f64).unwrap_or(0.0) / 1000.0;
                let unit = if types.get(i).and_then(Value::as_str) == Some("voltage") { "V" } else { "mA" };
                format!("{value:.3} {unit}")
            })
            .collect::<Vec<_>>()
            .join("   ")
    };
    let flag = |key: &str| if get("robot", key) == Value::Bool(true) { key.to_owned() } else { String::new() };
    let flags: Vec<String> = ["servo_on", "emergency_stop", "direct_teach", "power_button"]
        .iter()
        .map(|k| flag(k))
        .filter(|f| !f.is_empty())
        .collect();
    let mut out = String::new();
    out.push_str(&format!(
        "{label}: {} {} firmware {}, up {} s\n\n",
        text(&get("device", "name")),
        text(&get("network", "address")),
        text(&get("device", "firmware")),
        text(&get("device", "uptime_s"))
    ));
    out.push_str("              1234567890123456\n");
    out.push_str(&format!("digital in    {}\n", lamps(mask("di"), 16)));
    out.push_str(&format!("digital out   {}\n", lamps(mask("do"), 16)));
    out.push_str(&format!("tool in       {}\n", lamps(mask("tool_di"), 6)));
    out.push_str(&format!("tool out      {}\n", lamps(mask("tool_do"), 6)));
    out.push_str(&format!("analog in     {}\n", pair("ai")));
    out.push_str(&format!("analog out    {}\n\n", pair("ao")));
    out.push_str(&format!(
        "robot         {} ({}) from {}, safety stop {}\n",
        text(&get("robot", "state")),
        text(&get("robot", "state_code")),
        text(&get("robot", "source")),
        text(&get("robot", "safety_stop"))
    ));
    out.push_str(&format!("flags         {}\n", if flags.is_empty() { "-".into() } else { flags.join(" ") }));
    out.push_str(&format!(
        "modbus        {} connection(s), {} request(s)\n",
        status.get("connections").and_then(Value::as_array).map_or(0, Vec::len),
        text(&get("counters", "requests"))
    ));
    out
}

pub fn watch(ctx: &Context, target: &str, interval: f64, count: u64) -> Outcome {
    let device = ctx.resolve(target)?;
    let interval =
        Duration::from_secs_f64(if interval.is_finite() && interval >= 0.1 { interval.min(3600.0) } else { 0.5 });
    let mut shown = 0u64;
    loop {
        let body = match ctx.get(&device, "/api/status") {
            Ok(status) => screen(&device.label, &status),
            Err(failure) => format!("{}: offline ({})\n", device.label, failure.message()),
        };
        // Home, clear, the screen.
        print!("\x1b[H\x1b[2J{body}");
        use std::io::Write as _;
        let _ = std::io::stdout().flush();
        shown += 1;
        if count != 0 && shown >= count {
            return Ok(());
        }
        std::thread::sleep(interval);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_screen_shows_lamps_and_units_and_survives_anything() {
        let status = serde_json::json!({"device": {"name": "cell-3"}, "io": {"di": 5, "do": 32769, "ai": [4000, 2500], "ai_types": ["current", "voltage"]},
            "robot": {"state": "standby", "servo_on": true}});
        let screen = screen("cell-3", &status);
        assert!(screen.contains("digital in    #.#............."), "{screen}");
        assert!(screen.contains("digital out   #..............#"), "{screen}");
        assert!(screen.contains("4.000 mA   2.500 V"), "{screen}");
        assert!(screen.contains("flags         servo_on"), "{screen}");
        let _ = super::screen("x", &Value::Null);
        let _ = super::screen("x", &serde_json::json!({"io": {"ai": "x", "di": -1}}));
    }
}
