//! Finding devices: DNS-SD browsing of `_modbus._tcp` and `_http._tcp`
//! and `NAME.local` resolution (mdns-sd), then each one's `/api/status`.

use std::collections::BTreeMap;
use std::net::Ipv4Addr;
use std::time::{Duration, Instant};

use comfy_table::Table;
use mdns_sd::{HostnameResolutionEvent, ServiceDaemon, ServiceEvent};
use serde_json::{Value, json};

use crate::device::{Context, Device, text};
use crate::{Failure, Outcome};

const SERVICES: [&str; 2] = ["_modbus._tcp.local.", "_http._tcp.local."];

/// A device as DNS-SD showed it.
#[derive(Debug, Clone, Default)]
pub struct Found {
    pub name: String,
    pub address: Option<Ipv4Addr>,
    pub model: Option<String>,
    pub version: Option<String>,
    pub modbus_port: Option<u16>,
    pub http_port: Option<u16>,
}

fn daemon() -> Outcome<ServiceDaemon> {
    ServiceDaemon::new().map_err(|e| Failure::Unreachable(format!("mDNS cannot start: {e}")))
}

fn stop(daemon: ServiceDaemon) {
    if let Ok(done) = daemon.shutdown() {
        let _ = done.recv_timeout(Duration::from_secs(1));
    }
}

/// The devices that answer within `wait`, by name.
pub fn browse(wait: Duration) -> Outcome<Vec<Found>> {
    let daemon = daemon()?;
    let receivers: Vec<_> = SERVICES.iter().filter_map(|service| daemon.browse(service).ok()).collect();
    if receivers.is_empty() {
        stop(daemon);
        return Err(Failure::Unreachable("mDNS browsing could not start".into()));
    }
    let mut found: BTreeMap<String, Found> = BTreeMap::new();
    let deadline = Instant::now() + wait;
    while Instant::now() < deadline {
        for receiver in &receivers {
            while let Ok(event) = receiver.try_recv() {
                let ServiceEvent::ServiceResolved(service) = event else { continue };
                // The instance name is the device name (docs/discovery.md).
                let fullname = service.get_fullname();
                let Some(name) = SERVICES.iter().find_map(|s| fullname.strip_suffix(&format!(".{s}"))) else {
                    continue;
                };
                let entry =
                    found.entry(name.to_owned()).or_insert_with(|| Found { name: name.to_owned(), ..Found::default() });
                if let Some(address) = service.get_addresses_v4().into_iter().min() {
                    entry.address = Some(address);
                }
                if let Some(model) = service.get_property_val_str("model") {
                    entry.model = Some(model.to_owned());
                }
                if let Some(version) = service.get_property_val_str("version") {
                    entry.version = Some(version.to_owned());
                }
                if fullname.ends_with(SERVICES[0]) {
                    entry.modbus_port = Some(service.get_port());
                } else {
                    entry.http_port = Some(service.get_port());
                }
            }
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    stop(daemon);
    Ok(found.into_values().collect())
}

/// `NAME.local`'s IPv4 address, asked within `wait`.
pub fn resolve_name(name: &str, wait: Duration) -> Option<Ipv4Addr> {
    let daemon = daemon().ok()?;
    let millis = u64::try_from(wait.as_millis()).unwrap_or(u64::MAX);
    let receiver = daemon.resolve_hostname(&format!("{name}.local."), Some(millis)).ok()?;
    let deadline = Instant::now() + wait;
    let mut address = None;
    while address.is_none() {
        let left = deadline.saturating_duration_since(Instant::now());
        match receiver.recv_timeout(left) {
            Ok(HostnameResolutionEvent::AddressesFound(_, addresses)) => {
                address = addresses
                    .iter()
                    .filter_map(|a| match a.to_ip_addr() {
                        std::net::IpAddr::V4(v4) => Some(v4),
                        std::net::IpAddr::V6(_) => None,
                    })
                    .min();
            }
            Ok(HostnameResolutionEvent::SearchStopped(_)) | Err(_) => break,
            Ok(_) => {}
        }
    }
    stop(daemon);
    address
}

/// `mbio find`: browse, then read each device's status (in parallel).
pub fn find(ctx: &Context, wait: f64, json: bool) -> Outcome {
    let wait = Duration::from_secs_f64(if wait.is_finite() && wait > 0.0 { wait.min(600.0) } else { 3.0 });
    let found = browse(wait)?;
    let statuses: Vec<Option<Value>> = std::thread::scope(|scope| {
        let handles: Vec<_> = found
            .iter()
            .map(|f| {
                scope.spawn(move || {
                    let ip = f.address?;
                    ctx.get(&Device { label: f.name.clone(), ip }, "/api/status").ok()
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().ok().flatten()).collect()
    });
    let rows: Vec<Value> = found
        .iter()
        .zip(&statuses)
        .map(|(f, status)| {
            let status = status.as_ref();
            let pick = |path: &[&str]| status.and_then(|s| path.iter().try_fold(s, |v, key| v.get(*key))).cloned();
            json!({
                "name": f.name,
                "address": f.address.map(|a| a.to_string()),
                "model": pick(&["device", "model"]).unwrap_or_else(|| json!(f.model)),
                "firmware": pick(&["device", "firmware"]).unwrap_or_else(|| json!(f.version)),
                "robot_state": pick(&["robot", "state"]),
                "link": pick(&["network", "link"]),
                "modbus_port": f.modbus_port,
                "http_port": f.http_port,
                "answered": status.is_some(),
            })
        })
        .collect();
    if json {
        crate::print_json(&Value::Array(rows));
        return Ok(());
    }
    if rows.is_empty() {
        eprintln!("no device answered within {:.1} s", wait.as_secs_f64());
        return Ok(());
    }
    let mut table = Table::new();
    table.load_style(comfy_table::presets::NOTHING);
    table.set_header(["NAME", "ADDRESS", "MODEL", "FIRMWARE", "ROBOT", "LINK"]);
    for row in &rows {
        let link = match row.get("link") {
            Some(Value::Bool(true)) => "up".to_owned(),
            Some(Value::Bool(false)) => "down".to_owned(),
            _ => "?".to_owned(),
        };
        let robot = if row["answered"] == true { text(&row["robot_state"]) } else { "(no API answer)".into() };
        table.add_row([
            text(&row["name"]),
            text(&row["address"]),
            text(&row["model"]),
            text(&row["firmware"]),
            robot,
            link,
        ]);
    }
    say!("{table}");
    Ok(())
}
