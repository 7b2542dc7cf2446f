//! What `map import` writes: the native map (JSON and binary), its GeoJSON and preview, and
//! `summary.json` with what was read and how.

use std::io::Read;
use std::path::Path;

use anyhow::{Context as _, Result};
use maps::osm::InputFormat;
use maps::summary::MapSummary;
use maps::{ImportOptions, Map};
use serde::Serialize;
use sha2::{Digest, Sha256};

use crate::error::{CliError, FileRole, map_error};

/// The files `map import` writes.
pub use crate::inputs::{MAP_BIN, MAP_JSON};
pub const MAP_GEOJSON: &str = "map.geojson";
pub const PREVIEW_PNG: &str = "preview.png";
pub const SUMMARY_JSON: &str = "summary.json";

/// Longer side of `preview.png`, pixels.
const PREVIEW_MAX_PX: u32 = 1024;

/// What `summary.json` says about the input file.
#[derive(Debug, Clone, Serialize)]
pub struct InputInfo {
    /// File name only, so the summary does not depend on where the file was.
    pub file: String,
    pub format: InputFormat,
    pub lanelet2: bool,
    pub bytes: u64,
    pub sha256: String,
}

/// How the map was made: the effective options and the seed.
#[derive(Debug, Clone, Serialize)]
pub struct ImportRecord<'a> {
    pub options: &'a ImportOptions,
    pub profile_source: &'a str,
    pub seed: u64,
    pub pipeline_version: &'static str,
    pub map_format_version: u32,
}

/// `summary.json`: the map's summary, then the input and how it was imported.
#[derive(Debug, Serialize)]
struct SummaryFile<'a> {
    #[serde(flatten)]
    summary: &'a MapSummary,
    input: &'a InputInfo,
    import: ImportRecord<'a>,
}

pub(super) fn sha256_file(path: &Path) -> Result<(u64, String)> {
    let read_err = |e: std::io::Error| {
        anyhow::Error::new(CliError::file(
            path,
            format!("cannot read: {e}"),
            "check that the path exists and is readable",
        ))
    };
    let mut file = std::fs::File::open(path).map_err(read_err)?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    let mut bytes = 0u64;
    loop {
        let n = file.read(&mut buf).map_err(read_err)?;
        if n == 0 {
            break;
        }
        bytes += n as u64;
        hasher.update(&buf[..n]);
    }
    let hex = hasher
        .finalize()
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    Ok((bytes, hex))
}

pub(super) fn write_outputs(
    dir: &Path,
    map: &Map,
    summary: &MapSummary,
    input: &InputInfo,
    import: ImportRecord<'_>,
) -> Result<()> {
    let write = |name: &str, bytes: &[u8]| -> Result<()> {
        let path = dir.join(name);
        std::fs::write(&path, bytes).map_err(|e| {
            anyhow::Error::new(CliError::file(
                &path,
                format!("cannot write: {e}"),
                "check free disk space and permissions",
            ))
        })
    };
    let encode_and_write = |name: &str, encoded: Result<Vec<u8>, maps::MapError>| {
        write(
            name,
            &encoded.map_err(|e| map_error(dir, e, FileRole::Output))?,
        )
    };
    // The four files are independent: encode and write them side by side; a failure is
    // reported in this fixed order.
    let ((json, bin), (geojson, png)) = rayon::join(
        || {
            rayon::join(
                || encode_and_write(MAP_JSON, maps::io::to_json_bytes(map)),
                || encode_and_write(MAP_BIN, maps::io::to_binary_bytes(map)),
            )
        },
        || {
            rayon::join(
                || {
                    let text = maps::geojson::to_geojson_string(map);
                    encode_and_write(MAP_GEOJSON, text.map(String::into_bytes))
                },
                || {
                    let png = maps::preview::render_preview_png(map, PREVIEW_MAX_PX);
                    encode_and_write(PREVIEW_PNG, png)
                },
            )
        },
    );
    json?;
    bin?;
    geojson?;
    png?;
    let file = SummaryFile {
        summary,
        input,
        import,
    };
    let mut text =
        serde_json::to_string_pretty(&file).context("summary.json: serialisation failed")?;
    text.push('\n');
    write(SUMMARY_JSON, text.as_bytes())?;
    Ok(())
}
