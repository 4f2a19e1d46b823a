//! Status, settings, backup and restore over the HTTP API.

use std::io::BufRead as _;
use std::path::Path;

use comfy_table::Table;
use serde_json::{Map, Value, json};

use crate::device::{Context, errors, refusal, text};
use crate::{Failure, Outcome};

/// The backup file's format version (docs/mbio.md, "Backup files").
pub const BACKUP_FORMAT: u64 = 1;
/// Groups a backup leaves out: secrets and read-only state never leave the device.
const NOT_BACKED_UP: [&str; 1] = ["admin"];

/// `mbio status`.
pub fn status(ctx: &Context, target: &str, json: bool) -> Outcome {
    let device = ctx.resolve(target)?;
    let status = ctx.get(&device, "/api/status")?;
    if json {
        crate::print_json(&status);
        return Ok(());
    }
    let mut table = Table::new();
    table.load_style(comfy_table::presets::NOTHING);
    let field = |group: &str, key: &str| text(status.get(group).and_then(|g| g.get(key)).unwrap_or(&Value::Null));
    let rows: [(&str, String); 12] = [
        ("name", field("device", "name")),
        ("model", field("device", "model")),
        ("firmware", field("device", "firmware")),
        ("uptime", format!("{} s", field("device", "uptime_s"))),
        ("mac", field("device", "mac")),
        (
            "network",
            format!("{} {} link {}", field("network", "mode"), field("network", "address"), field("network", "link")),
        ),
        (
            "robot",
            format!(
                "{} ({}) source {}",
                field("robot", "state"),
                field("robot", "state_code"),
                field("robot", "source")
            ),
        ),
        ("digital in/out", format!("{:016b} / {:016b}", number(&status, "io", "di"), number(&status, "io", "do"))),
        ("tool in/out", format!("{:06b} / {:06b}", number(&status, "io", "tool_di"), number(&status, "io", "tool_do"))),
        ("connections", status.get("connections").and_then(Value::as_array).map_or(0, Vec::len).to_string()),
        ("watchdog", format!("{} ms, tripped {}", field("watchdog", "timeout_ms"), field("watchdog", "tripped"))),
        (
            "admin password",
            if status.get("admin").and_then(|a| a.get("password_set")) == Some(&Value::Bool(true)) {
                "set".into()
            } else {
                "NOT SET".into()
            },
        ),
    ];
    for (name, value) in rows {
        table.add_row([name.to_owned(), value]);
    }
    if let Some(update) = status.get("update").filter(|u| !u.is_null()) {
        table.add_row([
            "update".to_owned(),
            format!("{} (previous {})", text(&update["state"]), text(&update["previous"])),
        ]);
    }
    say!("{table}");
    Ok(())
}

fn number(status: &Value, group: &str, key: &str) -> u64 {
    status.get(group).and_then(|g| g.get(key)).and_then(Value::as_u64).unwrap_or(0)
}

/// The settings groups of a `GET /api/settings` document, without the read-only ones.
fn groups(settings: &Value) -> Outcome<&Map<String, Value>> {
    settings.as_object().ok_or_else(|| Failure::BadReply("the settings are not a JSON object".into()))
}

/// `mbio get NAME [group.field]`.
pub fn get(ctx: &Context, target: &str, key: Option<&str>, json: bool) -> Outcome {
    let device = ctx.resolve(target)?;
    let settings = ctx.get(&device, "/api/settings")?;
    let groups = groups(&settings)?;
    if let Some(key) = key {
        let (group, field) = key.split_once('.').ok_or_else(|| Failure::Usage(format!("{key}: not group.field")))?;
        let value = groups
            .get(group)
            .and_then(|g| g.get(field))
            .ok_or_else(|| Failure::Usage(format!("{key}: no such setting on {}", device.label)))?;
        if json {
            crate::print_json(value);
        } else {
            say!("{}", text(value));
        }
        return Ok(());
    }
    if json {
        crate::print_json(&settings);
        return Ok(());
    }
    for (group, fields) in groups {
        for (field, value) in fields.as_object().into_iter().flatten() {
            say!("{group}.{field}={}", text(value));
        }
    }
    Ok(())
}

/// `group.field=value` pairs as the API's grouped document; a key twice or
/// without its group is a usage error.
pub fn change_document(changes: &[String]) -> Outcome<Value> {
    let mut document = Map::new();
    for change in changes {
        let (key, value) =
            change.split_once('=').ok_or_else(|| Failure::Usage(format!("{change}: not group.field=value")))?;
        let (group, field) = key.split_once('.').ok_or_else(|| Failure::Usage(format!("{key}: not group.field")))?;
        if group.is_empty() || field.is_empty() {
            return Err(Failure::Usage(format!("{key}: not group.field")));
        }
        let fields = document.entry(group).or_insert_with(|| Value::Object(Map::new()));
        let Value::Object(fields) = fields else { return Err(Failure::Usage(format!("{key}: not group.field"))) };
        if fields.insert(field.to_owned(), Value::String(value.to_owned())).is_some() {
            return Err(Failure::Usage(format!("{key} given twice")));
        }
    }
    Ok(Value::Object(document))
}

/// Sends `change` with `PUT /api/settings`: the saved settings, or the device's
/// per-field errors (nothing saved).
fn put_settings(ctx: &Context, device: &crate::device::Device, change: &Value) -> Outcome<Value> {
    let reply = ctx.put(device, "/api/settings", change)?;
    if reply.status == 200 {
        Ok(reply.body)
    } else {
        if reply.status == 400 {
            return Err(Failure::Refused(format!(
                "{} refused the change, nothing was saved:\n  {}",
                device.label,
                errors(&reply.body).join("\n  ")
            )));
        }
        Err(refusal(device, &reply))
    }
}

/// `mbio set NAME group.field=value ...`: all or nothing.
pub fn set(ctx: &Context, target: &str, changes: &[String], json: bool) -> Outcome {
    let change = change_document(changes)?;
    let device = ctx.resolve(target)?;
    let saved = put_settings(ctx, &device, &change)?;
    if json {
        crate::print_json(&saved);
    } else {
        say!("{}: saved {} setting(s)", device.label, changes.len());
        if saved.get("reboot_required") == Some(&Value::Bool(true)) {
            say!("a reboot is needed for the change to apply (network.*, modbus.port)");
        }
    }
    Ok(())
}

/// `mbio password NAME`: the first password (no credentials needed, only
/// within the device's window), or a new one with the current one.
pub fn password(ctx: &Context, target: &str, new_file: Option<&Path>) -> Outcome {
    let device = ctx.resolve(target)?;
    let status = ctx.get(&device, "/api/status")?;
    let set = status.get("admin").and_then(|a| a.get("password_set")) == Some(&Value::Bool(true));
    let (new, authorized) = if set {
        let new = crate::device::read_password(new_file, crate::device::NEW_PASSWORD_ENV, "new admin password: ")
            .map_err(Failure::Usage)?;
        (new, true)
    } else {
        (ctx.password()?, false)
    };
    let reply = ctx.put_as(&device, "/api/password", &json!({"password": new}), authorized)?;
    if reply.status != 200 {
        return Err(crate::device::refusal(&device, &reply));
    }
    say!("{}: admin password {}", device.label, if set { "changed" } else { "set" });
    Ok(())
}

/// `mbio backup NAME`: the settings (no secret: the password never leaves
/// the device) and where they came from, as JSON on stdout.
pub fn backup(ctx: &Context, target: &str) -> Outcome {
    let device = ctx.resolve(target)?;
    let status = ctx.get(&device, "/api/status")?;
    let settings = ctx.get(&device, "/api/settings")?;
    let mut groups = groups(&settings)?.clone();
    for group in NOT_BACKED_UP {
        groups.remove(group);
    }
    let from = status.get("device").cloned().unwrap_or(Value::Null);
    let document = json!({
        "mbio_backup": BACKUP_FORMAT,
        "from": {
            "name": from.get("name"),
            "model": from.get("model"),
            "firmware": from.get("firmware"),
            "mac": from.get("mac"),
            "address": device.ip.to_string(),
        },
        "settings": groups,
    });
    crate::print_json(&document);
    Ok(())
}

/// The settings of a backup file (checked for its format).
pub fn read_backup(path: &Path) -> Outcome<Map<String, Value>> {
    let text = std::fs::read_to_string(path).map_err(|e| Failure::Usage(format!("{}: {e}", path.display())))?;
    let document: Value =
        serde_json::from_str(&text).map_err(|e| Failure::Usage(format!("{}: not JSON: {e}", path.display())))?;
    if document.get("mbio_backup").and_then(Value::as_u64) != Some(BACKUP_FORMAT) {
        return Err(Failure::Usage(format!("{}: not an mbio backup (format {BACKUP_FORMAT})", path.display())));
    }
    match document.get("settings") {
        Some(Value::Object(settings)) => Ok(settings.clone()),
        _ => Err(Failure::Usage(format!("{}: the backup has no settings", path.display()))),
    }
}

/// What a restore would change: (group, field, now, backup), for every
/// field of the backup that differs from the device's, leaving out the
/// read-only groups and, unless `network`, the network group.
pub fn difference(
    current: &Map<String, Value>,
    backup: &Map<String, Value>,
    network: bool,
) -> Vec<(String, String, Value, Value)> {
    let mut changes = Vec::new();
    for (group, fields) in backup {
        if NOT_BACKED_UP.contains(&group.as_str()) || (group == "network" && !network) {
            continue;
        }
        for (field, value) in fields.as_object().into_iter().flatten() {
            let now = current.get(group).and_then(|g| g.get(field)).cloned().unwrap_or(Value::Null);
            if text(&now) != text(value) {
                changes.push((group.clone(), field.clone(), now, value.clone()));
            }
        }
    }
    changes
}

/// `mbio restore NAME FILE`.
pub fn restore(ctx: &Context, target: &str, file: &Path, yes: bool, network: bool) -> Outcome {
    let backup = read_backup(file)?;
    let device = ctx.resolve(target)?;
    let current = ctx.get(&device, "/api/settings")?;
    let changes = difference(groups(&current)?, &backup, network);
    if !network && backup.contains_key("network") {
        eprintln!("network settings left as they are (--network to restore them too)");
    }
    if changes.is_empty() {
        say!("{}: nothing to change, its settings are the backup's", device.label);
        return Ok(());
    }
    let mut table = Table::new();
    table.load_style(comfy_table::presets::NOTHING);
    table.set_header(["SETTING", "NOW", "BACKUP"]);
    for (group, field, now, value) in &changes {
        table.add_row([format!("{group}.{field}"), text(now), text(value)]);
    }
    say!("{}: {} setting(s) would change:\n{table}", device.label, changes.len());
    if !yes {
        eprint!("restore them? [y/N] ");
        let mut answer = String::new();
        let _ = std::io::stdin().lock().read_line(&mut answer);
        if !matches!(answer.trim(), "y" | "Y" | "yes") {
            return Err(Failure::Cancelled("nothing restored".into()));
        }
    }
    let mut document = Map::new();
    for (group, field, _, value) in changes {
        if let Value::Object(fields) = document.entry(group).or_insert_with(|| Value::Object(Map::new())) {
            fields.insert(field, value);
        }
    }
    let saved = put_settings(ctx, &device, &Value::Object(document))?;
    say!("{}: restored", device.label);
    if saved.get("reboot_required") == Some(&Value::Bool(true)) {
        say!("a reboot is needed for some of it to apply (network.*, modbus.port)");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn changes_become_one_grouped_document() {
        let doc =
            change_document(&["modbus.unit_id=7".into(), "modbus.idle_timeout_s=30".into(), "device.name=a=b".into()])
                .unwrap();
        assert_eq!(doc, json!({"modbus": {"unit_id": "7", "idle_timeout_s": "30"}, "device": {"name": "a=b"}}));
        assert!(matches!(change_document(&["modbus.unit_id".into()]), Err(Failure::Usage(_))));
        assert!(matches!(change_document(&["unit_id=7".into()]), Err(Failure::Usage(_))));
        assert!(matches!(change_document(&["a.b=1".into(), "a.b=2".into()]), Err(Failure::Usage(_))));
        assert!(matches!(change_document(&[".b=1".into()]), Err(Failure::Usage(_))));
    }

    #[test]
    fn a_restore_changes_only_what_differs_and_leaves_the_network_alone() {
        let current = json!({"device": {"name": "a"}, "network": {"mode": "static"}, "modbus": {"unit_id": "any", "port": 502}, "admin": {"password_set": true}});
        let backup = json!({"device": {"name": "b"}, "network": {"mode": "dhcp"}, "modbus": {"unit_id": 7, "port": 502}, "admin": {"password_set": false}});
        let (current, backup) = (current.as_object().unwrap(), backup.as_object().unwrap());
        let keys = |network| {
            difference(current, backup, network).into_iter().map(|(g, f, _, _)| format!("{g}.{f}")).collect::<Vec<_>>()
        };
        assert_eq!(keys(false), ["device.name", "modbus.unit_id"]);
        assert_eq!(keys(true), ["device.name", "modbus.unit_id", "network.mode"]);
    }
}
