//! INTERACTION dataset track files (`vehicle_tracks_NNN.csv`, optionally gzipped): one row per
//! (vehicle, frame) with position, velocity and heading in the Lanelet2 map's local x/y frame.
//!
//! The header must be exactly the per-recording format's; every numeric field is parsed as
//! f64 (the files carry `-0` and float round-off digits); CRLF and a missing final newline are
//! accepted. A malformed row is skipped and counted with its line number.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

use maps::geometry::Point;
use serde::Serialize;

use super::error::{LogError, LogResult};

/// The header of a per-recording track file.
pub const TRACK_HEADER: &str =
    "track_id,frame_id,timestamp_ms,agent_type,x,y,vx,vy,psi_rad,length,width";

/// One row: a vehicle at one frame.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TrackRow {
    pub track_id: u32,
    pub frame_id: u32,
    pub timestamp_ms: u64,
    pub agent_type: String,
    /// Centre position, metres, map frame.
    pub x: f64,
    pub y: f64,
    /// Velocity, m/s, map frame.
    pub vx: f64,
    pub vy: f64,
    /// Heading, radians counter-clockwise from +x.
    pub psi_rad: f64,
    pub length: f64,
    pub width: f64,
}

/// A whole track file.
#[derive(Debug, Clone, Default)]
pub struct TrackFile {
    /// Rows in file order.
    pub rows: Vec<TrackRow>,
    /// Skipped rows: (line number, reason).
    pub skipped: Vec<(usize, String)>,
}

impl TrackFile {
    /// Row indices per timestamp (ms), in time order; within a frame in file order.
    pub fn frames(&self) -> BTreeMap<u64, Vec<usize>> {
        let mut frames: BTreeMap<u64, Vec<usize>> = BTreeMap::new();
        for (i, row) in self.rows.iter().enumerate() {
            frames.entry(row.timestamp_ms).or_default().push(i);
        }
        frames
    }

    /// Every row's position, in file order (what [`crate::on_map::check_on_map`] checks).
    pub fn positions(&self) -> impl Iterator<Item = Point> + '_ {
        self.rows.iter().map(|r| Point::new(r.x, r.y))
    }

    /// The distinct track ids, ascending.
    pub fn track_ids(&self) -> Vec<u32> {
        let mut ids: Vec<u32> = self.rows.iter().map(|r| r.track_id).collect();
        ids.sort_unstable();
        ids.dedup();
        ids
    }
}

/// Reads a track file (`.csv` or `.csv.gz`).
pub fn read_track_file(path: &Path) -> LogResult<TrackFile> {
    let raw = std::fs::read(path).map_err(|e| LogError::io(path, e))?;
    let text = if raw.starts_with(&[0x1f, 0x8b]) {
        let mut out = String::new();
        flate2::read::MultiGzDecoder::new(&raw[..])
            .read_to_string(&mut out)
            .map_err(|e| LogError::format(path, format!("gzip: {e}")))?;
        out
    } else {
        String::from_utf8(raw).map_err(|_| LogError::format(path, "not UTF-8 text"))?
    };
    parse_tracks(&text).map_err(|e| LogError::format(path, e.to_string()))
}

/// Parses the text of a track file.
pub fn parse_tracks(text: &str) -> Result<TrackFile, TrackFileError> {
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .from_reader(text.as_bytes());
    let mut records = reader.records();
    let header = match records.next() {
        Some(Ok(record)) => record.iter().collect::<Vec<_>>().join(","),
        Some(Err(e)) => e.to_string(),
        None => String::new(),
    };
    if header.trim_end_matches('\r') != TRACK_HEADER {
        return Err(TrackFileError::Header { found: header });
    }
    let mut file = TrackFile::default();
    // Line numbers from the records' byte offsets: csv's own line count lags by one after
    // CRLF line ends. A record starts at its first byte, or at the `\n` of a CRLF before it.
    let mut counted = (0usize, 1usize);
    let mut line_at = |byte: usize| {
        let (from, line) = counted;
        let end = (byte + 1).min(text.len()).max(from);
        let more = text.as_bytes()[from..end]
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        counted = (end, line + more);
        line + more
    };
    for record in records {
        match record {
            Ok(record) if record.iter().all(|f| f.trim().is_empty()) => {}
            Ok(record) => {
                let line = line_at(record.position().map_or(0, |p| p.byte() as usize));
                match parse_row(&record) {
                    Ok(row) => file.rows.push(row),
                    Err(reason) => file.skipped.push((line, reason)),
                }
            }
            Err(e) => {
                let line = line_at(e.position().map_or(0, |p| p.byte() as usize));
                file.skipped.push((line, e.to_string()));
            }
        }
    }
    if file.rows.is_empty() {
        return Err(TrackFileError::NoRows {
            first_problem: file.skipped.first().cloned(),
        });
    }
    Ok(file)
}

/// Why a text is not a track file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TrackFileError {
    #[error(
        "not an INTERACTION per-recording track file: the header is `{found}`, expected `{TRACK_HEADER}`"
    )]
    Header { found: String },
    #[error("{}", match first_problem {
        Some((line, reason)) => format!("no readable rows (line {line}: {reason})"),
        None => "no rows".to_owned(),
    })]
    NoRows {
        /// The first row that could not be read: its line and why.
        first_problem: Option<(usize, String)>,
    },
}

fn parse_row(fields: &csv::StringRecord) -> Result<TrackRow, String> {
    if fields.len() != 11 {
        return Err(format!("{} fields, expected 11", fields.len()));
    }
    let field = |i: usize| fields.get(i).unwrap_or("").trim_end_matches('\r');
    let int = |i: usize, name: &str| -> Result<u64, String> {
        field(i)
            .trim()
            .parse::<u64>()
            .map_err(|_| format!("{name} `{}` is not a whole number", field(i)))
    };
    let num = |i: usize, name: &str| -> Result<f64, String> {
        let v: f64 = field(i)
            .trim()
            .parse()
            .map_err(|_| format!("{name} `{}` is not a number", field(i)))?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(format!("{name} is not finite"))
        }
    };
    let small =
        |v: u64, name: &str| u32::try_from(v).map_err(|_| format!("{name} {v} is too large"));
    Ok(TrackRow {
        track_id: small(int(0, "track_id")?, "track_id")?,
        frame_id: small(int(1, "frame_id")?, "frame_id")?,
        timestamp_ms: int(2, "timestamp_ms")?,
        agent_type: field(3).trim().to_owned(),
        x: num(4, "x")?,
        y: num(5, "y")?,
        vx: num(6, "vx")?,
        vy: num(7, "vy")?,
        psi_rad: num(8, "psi_rad")?,
        length: num(9, "length")?,
        width: num(10, "width")?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crlf_negative_zero_round_off_and_a_bad_row() -> Result<(), TrackFileError> {
        let text = format!(
            "{TRACK_HEADER}\r\n1,1,100,car,1011.3889999999999,980.5,-0,0.5,-0,4.5,1.8\r\n\
             1,2,200,car,1011.4,980.6,0.1,0.5,0.1,4.5,1.8\r\n2,2,200,car,x,1,1,1,1,1,1\r\n\
             2,3,300,car,1000,1000,1,0,0,5.3420000000000005,2"
        );
        let file = parse_tracks(&text)?;
        assert_eq!(file.rows.len(), 3);
        assert_eq!(file.skipped.len(), 1);
        assert_eq!(file.skipped[0].0, 4);
        assert!((file.rows[0].x - 1011.389).abs() < 1e-9);
        assert_eq!(file.rows[0].vx, 0.0);
        assert!((file.rows[2].length - 5.342).abs() < 1e-12);
        assert_eq!(file.frames().len(), 3);
        assert_eq!(file.track_ids(), vec![1, 2]);
        Ok(())
    }

    #[test]
    fn wrong_header_is_an_error() {
        assert!(parse_tracks("case_id,track_id,frame_id\n1,2,3").is_err());
        assert!(parse_tracks("").is_err());
    }

    #[test]
    fn quoted_fields_blank_lines_and_short_rows() -> Result<(), TrackFileError> {
        let text = format!(
            "{TRACK_HEADER}\n\n1,1,100,\"car\",1,2,0,0,0,4.5,1.8\n1,2,200,car,1\n\n\
             1,3,300,car,1,2,0,0,0,4.5,1.8\n"
        );
        let file = parse_tracks(&text)?;
        assert_eq!(file.rows.len(), 2);
        assert_eq!(file.rows[0].agent_type, "car");
        assert_eq!(file.skipped, vec![(4, "5 fields, expected 11".to_owned())]);
        let only_bad = format!("{TRACK_HEADER}\n1,2\n");
        assert_eq!(
            parse_tracks(&only_bad).map(|_| ()),
            Err(TrackFileError::NoRows {
                first_problem: Some((2, "2 fields, expected 11".to_owned()))
            })
        );
        Ok(())
    }
}
