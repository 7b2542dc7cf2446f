//! The native map file, in two forms that [`load`] tells apart by their first bytes:
//!
//! - JSON ([`save_json`]): the [`Map`] as serde writes it, compact. Readable and diffable; every
//!   collection in the model is a `BTreeMap` or a `Vec`, so the bytes depend only on the map.
//! - Binary ([`save_binary`]): the magic bytes `DRVMAP`, the format version as a little-endian
//!   `u32`, then a postcard payload. About half the size of the JSON, and exact: floats are stored bit for bit.
//!
//! Both carry [`MAP_FORMAT_VERSION`]; a file of another version is refused with
//! [`MapError::Version`] instead of being half-read, so a stale map is re-imported rather than
//! misread.
//!
//! The model avoids internally tagged enums so that postcard, which is not self-describing,
//! can read the binary form back directly; floats are stored bit for bit, so a binary round
//! trip is exact.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::MapError;
use crate::model::{MAP_FORMAT_VERSION, Map};

/// First bytes of a binary map file.
pub const MAGIC: &[u8; 6] = b"DRVMAP";

/// Which form a map file is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MapFileForm {
    Json,
    Binary,
}

/// The map as compact JSON bytes.
pub fn to_json_bytes(map: &Map) -> Result<Vec<u8>, MapError> {
    serde_json::to_vec(map).map_err(|e| MapError::Serialise(e.to_string()))
}

/// The map as binary bytes: magic, version, postcard payload.
pub fn to_binary_bytes(map: &Map) -> Result<Vec<u8>, MapError> {
    let mut out = Vec::with_capacity(64 * 1024);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&map.format_version.to_le_bytes());
    let out = postcard::to_extend(map, out).map_err(|e| MapError::Serialise(e.to_string()))?;
    Ok(out)
}

/// Reads a map from bytes in either form; `path` only names the source in errors.
pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<(Map, MapFileForm), MapError> {
    if let Some(rest) = bytes.strip_prefix(MAGIC.as_slice()) {
        let Some((version, payload)) = rest.split_first_chunk::<4>() else {
            return Err(MapError::invalid(path, "truncated map file header"));
        };
        let found = u32::from_le_bytes(*version);
        check_version(found)?;
        let map: Map = postcard::from_bytes(payload).map_err(|e| MapError::Parse {
            path: Some(path.to_path_buf()),
            message: format!("corrupt binary map file: {e}"),
        })?;
        check_version(map.format_version)?;
        return Ok((map, MapFileForm::Binary));
    }
    let first = bytes.iter().find(|b| !b.is_ascii_whitespace());
    if first != Some(&b'{') {
        return Err(MapError::invalid(
            path,
            "not a map file (neither JSON nor a binary map starting with DRVMAP)",
        ));
    }
    // Read the version first, so a map of another version is reported as such and not as
    // whatever field happens to differ.
    #[derive(Deserialize)]
    struct Probe {
        format_version: Option<u32>,
    }
    let probe: Probe = serde_json::from_slice(bytes).map_err(|e| MapError::Parse {
        path: Some(path.to_path_buf()),
        message: format!("invalid map JSON: {e}"),
    })?;
    let Some(found) = probe.format_version else {
        return Err(MapError::invalid(
            path,
            "JSON without `format_version`: not a map file",
        ));
    };
    check_version(found)?;
    let map: Map = serde_json::from_slice(bytes).map_err(|e| MapError::Parse {
        path: Some(path.to_path_buf()),
        message: format!("invalid map JSON: {e}"),
    })?;
    Ok((map, MapFileForm::Json))
}

fn check_version(found: u32) -> Result<(), MapError> {
    if found == MAP_FORMAT_VERSION {
        Ok(())
    } else {
        Err(MapError::Version {
            found,
            expected: MAP_FORMAT_VERSION,
        })
    }
}

/// Writes the compact JSON form.
pub fn save_json(map: &Map, path: &Path) -> Result<(), MapError> {
    let bytes = to_json_bytes(map)?;
    std::fs::write(path, bytes).map_err(|e| MapError::io(path, e))
}

/// Writes the binary form.
pub fn save_binary(map: &Map, path: &Path) -> Result<(), MapError> {
    let bytes = to_binary_bytes(map)?;
    std::fs::write(path, bytes).map_err(|e| MapError::io(path, e))
}

/// Reads a map file in either form.
pub fn load(path: &Path) -> Result<Map, MapError> {
    load_with_form(path).map(|(map, _)| map)
}

/// Reads a map file in either form and says which it was.
pub fn load_with_form(path: &Path) -> Result<(Map, MapFileForm), MapError> {
    let bytes = std::fs::read(path).map_err(|e| MapError::io(path, e))?;
    from_bytes(&bytes, path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Point;
    use crate::model::*;
    use crate::projection::{LatLon, Projection};

    /// A small map touching every element kind and every tagged enum of the model.
    fn sample_map() -> Map {
        let mut map = Map::new(
            Projection::utm(LatLon::new(47.64, -122.30)),
            DrivingSide::Right,
            "car",
        );
        let (j0, j1) = (JunctionId(0), JunctionId(1));
        let line = vec![
            Point::new(0.0, 0.0),
            Point::new(10.0, 0.1),
            Point::new(20.000_000_000_1, -3.25),
        ];
        map.roads.insert(
            RoadId(7),
            Road {
                id: RoadId(7),
                source: RoadSource::Lanelet { relation_id: -42 },
                osm_way_ids: vec![1, -2, i64::MAX],
                highway: "residential".into(),
                name: Some("Ünïcødé Street \"quoted\"".into()),
                reference_line: line.clone(),
                start_junction: j0,
                end_junction: j1,
                lanes_forward: vec![LaneId(3)],
                lanes_backward: vec![],
                speed_limit_kmh: 40.233_6,
                speed_limit_is_default: false,
                is_roundabout: true,
                allows_cars: true,
            },
        );
        map.lanes.insert(
            LaneId(3),
            Lane {
                id: LaneId(3),
                road: RoadId(7),
                direction: Direction::Forward,
                index_from_centre: 0,
                centre: line.clone(),
                left: line.clone(),
                right: line.clone(),
                width_m: 3.5,
                length_m: 20.5,
                speed_limit_kmh: 40.0,
                turns: vec!["left".into(), "through".into()],
                from_junction: j0,
                to_junction: j1,
            },
        );
        for (id, kind) in [
            (j0, JunctionKind::DeadEnd),
            (j1, JunctionKind::Intersection),
        ] {
            map.junctions.insert(
                id,
                Junction {
                    id,
                    kind,
                    osm_node_id: Some(99),
                    point: Point::new(1.0 / 3.0, -0.1),
                    polygon: vec![
                        Point::new(0.0, 0.0),
                        Point::new(1.0, 0.0),
                        Point::new(0.0, 1.0),
                    ],
                    roads: vec![RoadId(7)],
                    control: None,
                },
            );
        }
        map.stop_lines.insert(
            StopLineId(0),
            StopLine {
                id: StopLineId(0),
                kind: StopKind::GiveWay,
                source: StopLineSource::RoundaboutEntry {
                    roundabout: RoundaboutId(0),
                },
                lanes: vec![LaneId(3)],
                line: vec![Point::new(0.0, 1.0), Point::new(0.0, -1.0)],
                s_on_lane_m: 19.0,
            },
        );
        map.markings.push(Marking {
            road: RoadId(7),
            kind: MarkingKind::SolidEdge,
            line,
        });
        map.report.notes.push("a note".into());
        map
    }

    fn temp_dir() -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!(
            "maps-io-test-{}-{:?}",
            std::process::id(),
            std::thread::current().id()
        ));
        let _ = std::fs::create_dir_all(&dir);
        dir
    }

    #[test]
    fn json_and_binary_round_trip_exactly() -> Result<(), MapError> {
        let map = sample_map();
        let dir = temp_dir();
        let (json, bin) = (dir.join("map.json"), dir.join("map.bin"));
        save_json(&map, &json)?;
        save_binary(&map, &bin)?;
        assert_eq!(load_with_form(&json)?, (map.clone(), MapFileForm::Json));
        assert_eq!(load_with_form(&bin)?, (map.clone(), MapFileForm::Binary));
        // Deterministic bytes, and the binary form is the smaller one.
        assert_eq!(
            std::fs::read(&json).map_err(|e| MapError::io(&json, e))?,
            to_json_bytes(&map)?
        );
        assert_eq!(
            std::fs::read(&bin).map_err(|e| MapError::io(&bin, e))?,
            to_binary_bytes(&map)?
        );
        assert!(to_binary_bytes(&map)?.len() < to_json_bytes(&map)?.len());
        let _ = std::fs::remove_dir_all(&dir);
        Ok(())
    }

    #[test]
    fn binary_header_is_magic_then_version() -> Result<(), MapError> {
        let bytes = to_binary_bytes(&sample_map())?;
        assert_eq!(&bytes[..6], b"DRVMAP");
        assert_eq!(bytes[6..10], MAP_FORMAT_VERSION.to_le_bytes());
        Ok(())
    }

    #[test]
    fn other_versions_are_refused() -> Result<(), MapError> {
        let map = sample_map();
        let path = Path::new("old.map");
        let mut bin = to_binary_bytes(&map)?;
        bin[6..10].copy_from_slice(&(MAP_FORMAT_VERSION + 1).to_le_bytes());
        assert!(matches!(
            from_bytes(&bin, path),
            Err(MapError::Version { found, expected }) if found == MAP_FORMAT_VERSION + 1 && expected == MAP_FORMAT_VERSION
        ));
        let mut old = map.clone();
        old.format_version = 0;
        let json = to_json_bytes(&old)?;
        assert!(matches!(
            from_bytes(&json, path),
            Err(MapError::Version { found: 0, .. })
        ));
        // A version-only stub is still reported as a version problem, not a parse error.
        assert!(matches!(
            from_bytes(br#"{"format_version": 99}"#, path),
            Err(MapError::Version { found: 99, .. })
        ));
        Ok(())
    }

    #[test]
    fn garbage_is_an_error_not_a_panic() {
        let path = Path::new("bad.map");
        for bytes in [
            &b""[..],
            b"DRVMAP",
            b"DRVMAP\x01\x00\x00\x00\xff\xff",
            b"<osm/>",
            b"{\"format_version\":1",
            b"{}",
        ] {
            assert!(from_bytes(bytes, path).is_err(), "{bytes:?}");
        }
        // Every truncation of a valid binary file fails cleanly.
        if let Ok(bin) = to_binary_bytes(&sample_map()) {
            for n in (0..bin.len()).step_by(7) {
                assert!(from_bytes(&bin[..n], path).is_err());
            }
        }
    }
}
