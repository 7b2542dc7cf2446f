//! `pipeline logs info`: a `ros2 bag info`-style summary, or JSON.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Result;
use logs::Log;
use logs::info::{LogInfo, log_info};
use logs::roles::{Assignment, Role, TopicRoles};

use super::{InfoArgs, log_error, topic_roles};
use crate::commands::Context;

pub fn run(ctx: &Context<'_>, args: &InfoArgs) -> Result<()> {
    let log = Log::open(&args.log).map_err(log_error)?;
    let info = log_info(&log).map_err(log_error)?;
    let roles = topic_roles(
        &args.log,
        info.topics
            .iter()
            .map(|t| (t.name.as_str(), t.type_name.as_str(), t.encoding.as_str())),
        &args.roles.over(&ctx.config.logs.roles),
    )?;
    for warning in info_warnings(&info) {
        ctx.ui.warn(&warning);
    }
    if args.json {
        let mut value = serde_json::to_value(&info)?;
        if let Some(object) = value.as_object_mut() {
            object.insert("roles".into(), serde_json::to_value(&roles)?);
        }
        ctx.ui.result(&serde_json::to_string_pretty(&value)?);
    } else {
        let mut text = render(&info);
        text.push_str(&render_roles(&roles));
        ctx.ui.result(&text);
    }
    Ok(())
}

/// One line per role: its topic and how it was chosen.
fn render_roles(roles: &TopicRoles) -> String {
    let mut s = String::new();
    for (i, role) in Role::ALL.into_iter().enumerate() {
        let value = match roles.get(role) {
            Assignment::Given { topic } => format!("{topic} (given)"),
            Assignment::Detected { topic } => format!("{topic} (detected)"),
            Assignment::Ambiguous { candidates } => {
                format!("ambiguous: {} (name one)", candidates.join(", "))
            }
            Assignment::Absent => "-".into(),
        };
        let key = if i == 0 { "Topic roles:" } else { "" };
        let _ = writeln!(s, "{key:<19}{:<9} {value}", role.name());
    }
    s
}

/// What the reader had to skip or found inconsistent.
fn info_warnings(info: &LogInfo) -> Vec<String> {
    let mut out: Vec<String> = info
        .skipped_chunks
        .iter()
        .map(|r| format!("{}: skipped a chunk: {r}", info.path))
        .collect();
    if info.messages_without_channel > 0 {
        out.push(format!(
            "{}: {} messages name an undefined channel or topic and were skipped",
            info.path, info.messages_without_channel
        ));
    }
    if info.skipped_messages > 0 {
        out.push(format!(
            "{}: {} unreadable messages were skipped",
            info.path, info.skipped_messages
        ));
    }
    if info.stated_count_agrees == Some(false) {
        out.push(format!(
            "{}: the file's own message count differs from the {} messages read",
            info.path, info.message_count
        ));
    }
    out.extend(info.warnings.iter().map(|w| format!("{}: {w}", info.path)));
    out
}

/// The text form, laid out like `ros2 bag info` with rate and decoder added per topic.
pub fn render(info: &LogInfo) -> String {
    let mut s = String::new();
    let names: Vec<String> = info
        .files
        .iter()
        .map(|f| {
            Path::new(&f.path)
                .file_name()
                .map_or(f.path.clone(), |n| n.to_string_lossy().into_owned())
        })
        .collect();
    let label = |s: &mut String, key: &str, value: &str| {
        let _ = writeln!(s, "{:<19}{value}", format!("{key}:"));
    };
    label(&mut s, "Files", &names.join(", "));
    label(
        &mut s,
        "Bag size",
        &format!(
            "{} ({} bytes)",
            human_bytes(info.total_bytes),
            thousands(info.total_bytes)
        ),
    );
    label(&mut s, "Storage id", info.storage.label());
    if let Some(distro) = &info.ros_distro {
        label(&mut s, "ROS Distro", distro);
    }
    if let Some(profile) = &info.mcap_profile {
        let library = info.mcap_library.as_deref().unwrap_or("");
        label(
            &mut s,
            "MCAP",
            &format!("profile `{profile}`, library `{library}`"),
        );
    }
    let chunks: u64 = info.chunk_compressions.values().sum();
    let compression = if chunks > 0 {
        format!("{} ({chunks} chunks)", info.compression)
    } else {
        info.compression.clone()
    };
    label(&mut s, "Compression", &compression);
    label(
        &mut s,
        "Duration",
        &format!("{}s", seconds(info.duration_ns)),
    );
    if let (Some(start), Some(end)) = (info.start_ns, info.end_ns) {
        label(
            &mut s,
            "Start",
            &format!("{} ({})", utc(start), seconds(start)),
        );
        label(&mut s, "End", &format!("{} ({})", utc(end), seconds(end)));
    }
    label(&mut s, "Messages", &info.message_count.to_string());
    for (i, t) in info.topics.iter().enumerate() {
        let key = if i == 0 { "Topic information" } else { "" };
        let rate = t.rate_hz.map_or("-".to_owned(), |r| format!("{r:.3} Hz"));
        let decoder = match &t.decoder {
            Ok(kind) => kind.clone(),
            Err(why) => format!("none ({why})"),
        };
        let _ = writeln!(
            s,
            "{:<19}Topic: {} | Type: {} | Count: {} | Serialization Format: {} | Rate: {rate} | Decoder: {decoder}",
            if key.is_empty() {
                String::new()
            } else {
                format!("{key}:")
            },
            t.name,
            t.type_name,
            t.count,
            t.encoding,
        );
    }
    if !info.metadata_records.is_empty() {
        label(&mut s, "Metadata", &info.metadata_records.join(", "));
    }
    if info.attachments > 0 {
        label(&mut s, "Attachments", &info.attachments.to_string());
    }
    s
}

fn seconds(ns: u64) -> String {
    format!("{}.{:09}", ns / 1_000_000_000, ns % 1_000_000_000)
}

fn human_bytes(bytes: u64) -> String {
    let units = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut value = bytes as f64;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < units.len() {
        value /= 1024.0;
        unit += 1;
    }
    if unit == 0 {
        format!("{bytes} B")
    } else {
        format!("{value:.1} {}", units[unit])
    }
}

fn thousands(n: u64) -> String {
    let digits = n.to_string();
    let mut out = String::new();
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// `May 21 2015 19:11:38.025043042 UTC`.
fn utc(ns: u64) -> String {
    const MONTHS: [&str; 12] = [
        "Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec",
    ];
    let secs = ns / 1_000_000_000;
    let (days, rem) = (secs / 86_400, secs % 86_400);
    let (year, month, day) = civil_from_days(days as i64);
    format!(
        "{} {day:02} {year} {:02}:{:02}:{:02}.{:09} UTC",
        MONTHS[(month - 1) as usize],
        rem / 3600,
        rem % 3600 / 60,
        rem % 60,
        ns % 1_000_000_000
    )
}

/// Days since 1970-01-01 to (year, month, day) in the proleptic Gregorian calendar
/// (H. Hinnant's `civil_from_days`).
fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let month = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let year = yoe + era * 400 + i64::from(month <= 2);
    (year, month, day)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_and_sizes() {
        assert_eq!(
            utc(1_432_235_498_025_043_042),
            "May 21 2015 19:11:38.025043042 UTC"
        );
        assert_eq!(utc(0), "Jan 01 1970 00:00:00.000000000 UTC");
        assert_eq!(
            utc(951_782_400_000_000_000),
            "Feb 29 2000 00:00:00.000000000 UTC"
        );
        assert_eq!(human_bytes(8_364_032), "8.0 MiB");
        assert_eq!(thousands(8_364_032), "8,364,032");
        assert_eq!(thousands(989), "989");
        assert_eq!(seconds(395_307_116_140), "395.307116140");
    }
}
