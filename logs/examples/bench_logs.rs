//! Times reading every message of a log with our reader, for the comparison with the Python
//! `mcap` reader and `rosbags` (`scripts/bench_logs.py` runs this in release mode beside them,
//! on the same files, in the same run).
//!
//! Two modes per log, each timed in this process after one untimed warm-up (so the file is in
//! the page cache for both sides):
//! - `raw`: every message record read in storage order (chunks decompressed and their CRCs
//!   checked, records parsed), the payload not decoded; the payload bytes are summed;
//! - `decoded`: every message also decoded from CDR into its typed struct and kept in one
//!   vector ([`read_decoded`], what the rest of the crate uses).
//!
//! Usage: `bench_logs [--runs 7] LOG...` (an .mcap file, a bag folder, or a .db3); prints one
//! JSON object per log on one line each.

#![allow(clippy::print_stdout)]

use std::ops::ControlFlow;
use std::path::PathBuf;
use std::time::Instant;

use logs::{Log, ReadOptions, read_decoded};

/// Times reading (and decoding) every message of each log.
#[derive(Debug, clap::Parser)]
struct Args {
    /// Timed runs of each mode (after one untimed warm-up).
    #[arg(long, default_value_t = 7)]
    runs: usize,
    /// The logs.
    logs: Vec<PathBuf>,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

/// One raw pass: (messages, payload bytes).
fn raw(path: &std::path::Path) -> Result<(u64, u64)> {
    let log = Log::open(path)?;
    let (mut n, mut bytes) = (0u64, 0u64);
    log.for_each_message(&ReadOptions::default(), |_, m| {
        n += 1;
        bytes += m.data.len() as u64;
        ControlFlow::Continue(())
    })?;
    Ok((n, bytes))
}

/// One decoding pass: (messages decoded, messages not decoded).
fn decoded(path: &std::path::Path) -> Result<(u64, u64)> {
    let log = Log::open(path)?;
    let decoded = read_decoded(&log, &ReadOptions::default())?;
    let undecoded = decoded.undecoded.values().map(|u| u.count).sum();
    Ok((decoded.messages.len() as u64, undecoded))
}

fn main() -> Result<()> {
    let args: Args = clap::Parser::parse();
    for path in &args.logs {
        let mut out = serde_json::Map::new();
        out.insert("log".into(), path.display().to_string().into());
        let (messages, bytes) = raw(path)?;
        let mut seconds = Vec::new();
        for _ in 0..args.runs {
            let t = Instant::now();
            let again = raw(path)?;
            seconds.push(t.elapsed().as_secs_f64());
            assert_eq!(again, (messages, bytes));
        }
        let m = median(seconds.clone());
        out.insert(
            "raw".into(),
            serde_json::json!({
                "messages": messages, "payload_bytes": bytes, "seconds": seconds,
                "median_s": m, "messages_per_s": messages as f64 / m,
            }),
        );
        let (ok, failed) = decoded(path)?;
        let mut seconds = Vec::new();
        for _ in 0..args.runs {
            let t = Instant::now();
            let again = decoded(path)?;
            seconds.push(t.elapsed().as_secs_f64());
            assert_eq!(again, (ok, failed));
        }
        let m = median(seconds.clone());
        out.insert(
            "decoded".into(),
            serde_json::json!({
                "messages": ok, "undecoded": failed, "seconds": seconds,
                "median_s": m, "messages_per_s": (ok + failed) as f64 / m,
            }),
        );
        println!("{}", serde_json::Value::Object(out));
    }
    Ok(())
}
