//! `mbio update`: a signed update file to one, several or every device
//! found, `--parallel` at a time, each with a progress bar; each device's
//! new version read back through Modbus 0x2B (Read Device Identification)
//! after its reboot; a summary table. The rollout stops at the first
//! failure (the devices already going finish) unless `--keep-going`.

use std::net::SocketAddr;
use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use comfy_table::Table;
use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use serde_json::{Value, json};
use tokio_modbus::client::Reader as _;
use tokio_modbus::prelude::ReadCode;

use crate::device::{Context, Device, errors, text};
use crate::{Failure, Outcome};

/// How long a device that took an update may keep answering before its reboot.
const REBOOT_WAIT: Duration = Duration::from_secs(10);

#[derive(Debug)]
pub struct Options {
    pub parallel: usize,
    pub keep_going: bool,
    pub timeout: Duration,
    pub json: bool,
}

/// How one device's update went.
#[derive(Debug, Clone)]
struct Report {
    device: String,
    address: Option<String>,
    before: Option<String>,
    after: Option<String>,
    result: &'static str,
    note: String,
}

impl Report {
    fn new(device: &str) -> Self {
        Self {
            device: device.to_owned(),
            address: None,
            before: None,
            after: None,
            result: "skipped",
            note: String::new(),
        }
    }

    fn ok(&self) -> bool {
        self.result == "updated"
    }
}

/// The objects 0x00-0x02 of Read Device Identification: the firmware version (0x02).
async fn identified_version(addr: SocketAddr) -> Option<String> {
    let attempt = async {
        let mut modbus = tokio_modbus::client::tcp::connect(addr).await.ok()?;
        let reply = modbus.read_device_identification(ReadCode::Basic, 0).await.ok()?.ok()?;
        let version = reply.device_id_objects.iter().find(|o| o.id == 0x02)?.value_as_str()?.to_owned();
        let _ = tokio_modbus::client::Client::disconnect(&mut modbus).await;
        Some(version)
    };
    tokio::time::timeout(Duration::from_secs(3), attempt).await.ok().flatten()
}

/// Waits until the device reports `expected` in 0x2B, or `timeout` passes;
/// the version it last reported.
fn wait_for_version(
    ctx: &Context,
    device: &Device,
    expected: &str,
    timeout: Duration,
    bar: &ProgressBar,
) -> Option<String> {
    let runtime = crate::points::runtime().ok()?;
    let addr = SocketAddr::from((device.ip, ctx.modbus_port));
    let deadline = Instant::now() + timeout;
    let mut last = None;
    // The device reboots once its response has gone out: wait until it
    // stops answering (at most REBOOT_WAIT), so that the old image, which
    // may carry the same version, is not taken for the new one.
    let down_by = Instant::now() + REBOOT_WAIT;
    while Instant::now() < down_by && runtime.block_on(identified_version(addr)).is_some() {
        bar.tick();
        std::thread::sleep(Duration::from_millis(200));
    }
    while Instant::now() < deadline {
        if let Some(version) = runtime.block_on(identified_version(addr)) {
            if version == expected {
                return Some(version);
            }
            last = Some(version);
        }
        bar.tick();
        std::thread::sleep(Duration::from_millis(500));
    }
    last
}

/// One device's update, start to end.
fn update_one(ctx: &Context, target: &str, file: &Path, len: u64, bars: &MultiProgress, options: &Options) -> Report {
    let mut report = Report::new(target);
    let bar = bars.add(ProgressBar::new(len));
    let style = ProgressStyle::with_template("{prefix:>16} [{bar:30}] {bytes}/{total_bytes} {msg}")
        .unwrap_or_else(|_| ProgressStyle::default_bar());
    bar.set_style(style.progress_chars("=> "));
    bar.set_prefix(target.to_owned());
    let fail = |mut report: Report, result: &'static str, note: String| {
        bar.abandon_with_message(format!("{result}: {}", note.lines().next().unwrap_or_default()));
        report.result = result;
        report.note = note;
        report
    };
    let device = match ctx.resolve(target) {
        Ok(device) => device,
        Err(failure) => return fail(report, "failed", failure.message().to_owned()),
    };
    report.address = Some(device.ip.to_string());
    match ctx.get(&device, "/api/status") {
        Ok(status) => report.before = status.get("device").and_then(|d| d.get("firmware")).map(text),
        Err(failure) => return fail(report, "failed", failure.message().to_owned()),
    }
    let reader = match std::fs::File::open(file) {
        Ok(reader) => reader,
        Err(e) => return fail(report, "failed", format!("{}: {e}", file.display())),
    };
    bar.set_message("sending");
    let reply = match ctx.upload(&device, len, bar.wrap_read(reader)) {
        Ok(reply) => reply,
        Err(failure) => return fail(report, "failed", failure.message().to_owned()),
    };
    if reply.status != 202 {
        let mut note = format!("refused ({})", reply.status);
        for line in errors(&reply.body) {
            note.push_str(": ");
            note.push_str(&line);
        }
        return fail(report, "refused", note);
    }
    let Some(expected) = reply.body.get("firmware").and_then(|f| f.get("version")).and_then(Value::as_str) else {
        return fail(report, "failed", format!("taken, but the reply names no version: {}", reply.body));
    };
    bar.set_message(format!("taken ({expected}), rebooting"));
    let after = wait_for_version(ctx, &device, expected, options.timeout, &bar);
    report.after.clone_from(&after);
    if after.as_deref() == Some(expected) {
        bar.finish_with_message(format!("running {expected}"));
        report.result = "updated";
        report.note = "version checked in 0x2B".into();
        report
    } else {
        let note = match after {
            Some(version) => format!("still reports {version} in 0x2B, not {expected} (rolled back?)"),
            None => format!("did not answer 0x2B within {} s of the reboot", options.timeout.as_secs()),
        };
        fail(report, "failed", note)
    }
}

/// `mbio update FILE NAME...|--all`.
pub fn rollout(ctx: &Context, file: &Path, targets: &[String], all: Option<f64>, options: &Options) -> Outcome {
    let len = std::fs::metadata(file).map_err(|e| Failure::Usage(format!("{}: {e}", file.display())))?.len();
    let targets: Vec<String> = match all {
        Some(wait) => {
            let wait = Duration::from_secs_f64(if wait.is_finite() && wait > 0.0 { wait.min(600.0) } else { 3.0 });
            let found = crate::discover::browse(wait)?;
            found.into_iter().filter_map(|f| f.address.map(|a| a.to_string())).collect()
        }
        None => targets.to_vec(),
    };
    if targets.is_empty() {
        return Err(Failure::Unreachable("no device to update".into()));
    }
    // Asked once, before the progress bars start.
    ctx.password()?;
    let reports: Vec<Mutex<Report>> = targets.iter().map(|t| Mutex::new(Report::new(t))).collect();
    let next = Mutex::new(0usize);
    let stop = AtomicBool::new(false);
    let bars = MultiProgress::new();
    std::thread::scope(|scope| {
        for _ in 0..options.parallel.min(targets.len()) {
            scope.spawn(|| {
                loop {
                    if stop.load(Ordering::SeqCst) && !options.keep_going {
                        return;
                    }
                    let index = {
                        let Ok(mut next) = next.lock() else { return };
                        let index = *next;
                        *next += 1;
                        index
                    };
                    let (Some(target), Some(slot)) = (targets.get(index), reports.get(index)) else { return };
                    let report = update_one(ctx, target, file, len, &bars, options);
                    if !report.ok() {
                        stop.store(true, Ordering::SeqCst);
                    }
                    if let Ok(mut slot) = slot.lock() {
                        *slot = report;
                    }
                }
            });
        }
    });
    let reports: Vec<Report> = reports.into_iter().filter_map(|r| r.into_inner().ok()).collect();
    let failed = reports.iter().filter(|r| !r.ok()).count();
    if options.json {
        let rows: Vec<Value> = reports
            .iter()
            .map(|r| json!({"device": r.device, "address": r.address, "before": r.before, "after": r.after, "result": r.result, "note": r.note}))
            .collect();
        crate::print_json(&Value::Array(rows));
    } else {
        let mut table = Table::new();
        table.load_style(comfy_table::presets::NOTHING);
        table.set_header(["DEVICE", "ADDRESS", "BEFORE", "AFTER", "RESULT", "NOTE"]);
        for r in &reports {
            let cell = |v: &Option<String>| v.clone().unwrap_or_else(|| "-".into());
            table.add_row([
                r.device.clone(),
                cell(&r.address),
                cell(&r.before),
                cell(&r.after),
                r.result.to_owned(),
                r.note.clone(),
            ]);
        }
        say!("{table}");
    }
    let skipped = reports.iter().filter(|r| r.result == "skipped").count();
    let updated = reports.len() - failed;
    if failed == 0 {
        Ok(())
    } else if skipped > 0 {
        Err(Failure::Refused(format!(
            "rollout stopped at the first failure: {updated} updated, {} failed, {skipped} not tried (--keep-going tries every one)",
            failed - skipped
        )))
    } else {
        Err(Failure::Refused(format!("{updated} updated, {failed} failed")))
    }
}
