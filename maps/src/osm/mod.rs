//! Raw OpenStreetMap data as read from a file, before any interpretation.
//!
//! Coordinates are kept as the `f64` nearest to the decimal value in the file. The XML
//! reader parses the decimal text and the PBF reader divides the integer nano-/decimicro
//! degrees by a power of ten; both give the correctly rounded double of the same number,
//! which is why an XML file and its PBF twin produce identical maps.

mod pbf;
mod xml;

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::MapError;
use crate::projection::LatLon;

pub use pbf::{read_pbf, read_pbf_bytes};
pub use xml::{parse_xml, read_xml};

/// Tags of an element, sorted by key.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Tags(pub Vec<(String, String)>);

impl Tags {
    /// Tags from `(key, value)` pairs (later pairs win), handy in code and tests.
    pub fn from_pairs(pairs: &[(&str, &str)]) -> Self {
        let mut t = Tags::default();
        for (k, v) in pairs {
            t.insert((*k).to_owned(), (*v).to_owned());
        }
        t
    }
    pub fn get(&self, key: &str) -> Option<&str> {
        self.0
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }
    pub fn is(&self, key: &str, value: &str) -> bool {
        self.get(key) == Some(value)
    }
    pub fn is_any(&self, key: &str, values: &[&str]) -> bool {
        self.get(key).is_some_and(|v| values.contains(&v))
    }
    pub fn insert(&mut self, key: String, value: String) {
        match self.0.binary_search_by(|(k, _)| k.as_str().cmp(&key)) {
            Ok(i) => self.0[i].1 = value,
            Err(i) => self.0.insert(i, (key, value)),
        }
    }
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct OsmNode {
    pub pos: LatLon,
    pub tags: Tags,
}

#[derive(Debug, Clone, PartialEq)]
pub struct OsmWay {
    pub nodes: Vec<i64>,
    pub tags: Tags,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MemberKind {
    Node,
    Way,
    Relation,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Member {
    pub kind: MemberKind,
    pub id: i64,
    pub role: String,
}

#[derive(Debug, Clone, PartialEq)]
pub struct OsmRelation {
    pub members: Vec<Member>,
    pub tags: Tags,
}

/// Everything read from one OSM file.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OsmData {
    pub nodes: BTreeMap<i64, OsmNode>,
    pub ways: BTreeMap<i64, OsmWay>,
    pub relations: BTreeMap<i64, OsmRelation>,
    /// Nodes dropped because their coordinates were outside WGS84's range or not numbers.
    pub invalid_nodes: Vec<i64>,
}

impl OsmData {
    /// Whether this is a Lanelet2 map (it has `type=lanelet` relations).
    pub fn is_lanelet2(&self) -> bool {
        self.relations
            .values()
            .any(|r| r.tags.is("type", "lanelet"))
    }

    /// Adds what was read after `self` in the same file: its elements replace those of
    /// the same id, as a later element does in one file.
    pub(crate) fn append(&mut self, mut later: OsmData) {
        self.nodes.append(&mut later.nodes);
        self.ways.append(&mut later.ways);
        self.relations.append(&mut later.relations);
        self.invalid_nodes.append(&mut later.invalid_nodes);
    }

    pub(crate) fn add_node(&mut self, id: i64, lat: f64, lon: f64, tags: Tags) {
        if lat.is_finite() && lon.is_finite() && lat.abs() <= 90.0 && lon.abs() <= 180.0 {
            self.nodes.insert(
                id,
                OsmNode {
                    pos: LatLon { lat, lon },
                    tags,
                },
            );
        } else {
            self.invalid_nodes.push(id);
        }
    }
}

/// The input formats `read_osm_file` understands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InputFormat {
    OsmXml,
    OsmXmlGz,
    OsmPbf,
}

/// Reads `.osm`, `.osm.gz` or `.osm.pbf`, telling them apart by their first bytes (a PBF
/// starts with a blob header naming `OSMHeader`, gzip with 1f 8b), not by the file name.
pub fn read_osm_file(path: &Path) -> Result<(OsmData, InputFormat), MapError> {
    let format = sniff_format(path)?;
    let data = match format {
        InputFormat::OsmPbf => read_pbf(path)?,
        InputFormat::OsmXml | InputFormat::OsmXmlGz => read_xml(path)?,
    };
    Ok((data, format))
}

fn sniff_format(path: &Path) -> Result<InputFormat, MapError> {
    use std::io::Read;
    let mut head = [0u8; 64];
    let mut file = std::fs::File::open(path).map_err(|e| MapError::io(path, e))?;
    let mut n = 0;
    while n < head.len() {
        match file.read(&mut head[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) => return Err(MapError::io(path, e)),
        }
    }
    let head = &head[..n];
    if n == 0 {
        return Err(MapError::invalid(path, "the file is empty"));
    }
    if head.starts_with(&[0x1f, 0x8b]) {
        return Ok(InputFormat::OsmXmlGz);
    }
    if head.windows(9).any(|w| w == b"OSMHeader") {
        return Ok(InputFormat::OsmPbf);
    }
    let name = path.to_string_lossy();
    if name.ends_with(".pbf") {
        // Named like a PBF but without a PBF header: let the PBF reader say what is wrong.
        return Ok(InputFormat::OsmPbf);
    }
    Ok(InputFormat::OsmXml)
}
