//! Inputs shared by the commands: the one map loader every command uses, so every command
//! accepts the same map arguments (a `map import` folder, `map.json` / `map.bin`, or an
//! OpenStreetMap / Lanelet2 file imported on the fly).

use std::path::{Path, PathBuf};

use anyhow::Result;
use maps::Map;
use maps::io::MapFileForm;

use crate::error::{CliError, FileRole, map_error};

/// The native map files `map import` writes.
pub const MAP_JSON: &str = "map.json";
pub const MAP_BIN: &str = "map.bin";

/// The file name of the bundled campus (Northwestern University and downtown Evanston), as
/// in the repository's `data/osm/`.
pub const BUNDLED_CAMPUS_FILE: &str = "northwestern_nu.osm.pbf";
/// How outputs record the bundled campus as their map: the embedded copy, not a path.
pub const BUNDLED_CAMPUS_NAME: &str = "bundled:northwestern_nu.osm.pbf";
/// The bundled campus's PBF bytes, embedded in the binary so that commands defaulting to it
/// work from any folder (© OpenStreetMap contributors, ODbL 1.0; see data/osm/README.md).
const BUNDLED_CAMPUS: &[u8] = include_bytes!("../../data/osm/northwestern_nu.osm.pbf");

/// The file endings read as OpenStreetMap input (XML, gzip'd XML, PBF; Lanelet2 is XML).
const OSM_ENDINGS: [&str; 5] = [".osm", ".osm.gz", ".osm.xml", ".osm.pbf", ".pbf"];

/// Whether a path names an OSM file (by its ending) rather than a native map.
pub fn is_osm_file(path: &Path) -> bool {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    OSM_ENDINGS.iter().any(|ending| name.ends_with(ending))
}

/// A native map from a file (JSON or binary) or from a map folder (its map.bin, else
/// map.json), with the file it came from and its form.
pub fn load_map(path: &Path) -> Result<(Map, PathBuf, MapFileForm)> {
    let file = if path.is_dir() {
        [MAP_BIN, MAP_JSON]
            .iter()
            .map(|n| path.join(n))
            .find(|p| p.is_file())
            .ok_or_else(|| {
                CliError::file(
                    path,
                    format!("no {MAP_BIN} or {MAP_JSON} in this folder"),
                    "give a folder written by `pipeline map import`, or a map file",
                )
            })?
    } else {
        path.to_path_buf()
    };
    let (map, form) =
        maps::io::load_with_form(&file).map_err(|e| map_error(&file, e, FileRole::MapFile))?;
    Ok((map, file, form))
}

/// A map from a `map import` folder or file, or imported from an OSM / Lanelet2 file with
/// the default options: what every command's `--map` takes.
pub fn load_or_import_map(path: &Path) -> Result<Map> {
    if !path.exists() {
        return Err(CliError::file(
            path,
            "no such file or folder",
            "give a map folder, map.json / map.bin, or an .osm / .osm.pbf file",
        )
        .into());
    }
    if is_osm_file(path) && path.is_file() {
        maps::import_file(path, &maps::ImportOptions::default())
            .map_err(|e| map_error(path, e, FileRole::OsmInput))
    } else {
        Ok(load_map(path)?.0)
    }
}

/// The bundled campus imported from the copy embedded in the binary, with the default options:
/// the map `load_or_import_map` makes of `data/osm/northwestern_nu.osm.pbf`.
pub fn bundled_campus() -> Result<Map> {
    maps::import_pbf_bytes(BUNDLED_CAMPUS, &maps::ImportOptions::default()).map_err(|e| {
        CliError::new(
            format!("{BUNDLED_CAMPUS_NAME}: {e}"),
            "this is a bug in this build of pipeline: please report it; meanwhile give a map with --map",
        )
        .into()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn osm_files_are_told_by_their_ending() {
        for name in [
            "data/osm/northwestern_nu.osm.pbf",
            "x.OSM",
            "A.OSM.GZ",
            "c.pbf",
            "d.osm.xml",
        ] {
            assert!(is_osm_file(Path::new(name)), "{name}");
        }
        for name in ["map.json", "runs/campus/map.bin", "runs/campus", "osm"] {
            assert!(!is_osm_file(Path::new(name)), "{name}");
        }
    }

    #[test]
    fn a_missing_map_names_the_path() {
        let err = load_or_import_map(Path::new("no/such/map.json"))
            .expect_err("a missing map is an error");
        assert!(err.to_string().contains("no/such/map.json"), "{err}");
    }
}
