//! OSM PBF with the osmpbf crate.

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::Path;

use osmpbf::{Blob, BlobDecode, BlobReader, Element, RelMemberType};
use rayon::prelude::*;

use super::{Member, MemberKind, OsmData, OsmRelation, OsmWay, Tags};
use crate::error::MapError;

fn tags<'a>(iter: impl Iterator<Item = (&'a str, &'a str)>) -> Tags {
    let mut t: Vec<(String, String)> = iter.map(|(k, v)| (k.to_owned(), v.to_owned())).collect();
    t.sort();
    t.dedup_by(|a, b| a.0 == b.0);
    Tags(t)
}

/// Reads an `.osm.pbf` file. Corrupt or truncated blobs are errors.
///
/// The file's blobs are decoded side by side on the thread pool, then merged in file order,
/// so the data and the first error reported are those of reading the blobs one by one.
pub fn read_pbf(path: &Path) -> Result<OsmData, MapError> {
    let file = File::open(path).map_err(|e| MapError::io(path, e))?;
    read_blobs(BlobReader::new(BufReader::new(file)), Some(path))
}

/// Reads PBF data held in memory (a map embedded in a program), exactly as [`read_pbf`]
/// reads the same bytes from a file. Corrupt or truncated blobs are errors naming no file.
pub fn read_pbf_bytes(bytes: &[u8]) -> Result<OsmData, MapError> {
    read_blobs(BlobReader::new(bytes), None)
}

/// The elements of every blob `reader` gives, decoded in parallel and merged in order;
/// errors name `path` when there is one.
fn read_blobs<R: Read + Send>(
    reader: BlobReader<R>,
    path: Option<&Path>,
) -> Result<OsmData, MapError> {
    let corrupt = |e: osmpbf::Error| MapError::Parse {
        path: path.map(Path::to_path_buf),
        message: format!("corrupt or truncated PBF: {e}"),
    };
    // The reader stops after its first error; that error stays in place among the blobs.
    let blobs: Vec<osmpbf::Result<Blob>> = reader.collect();
    let decoded: Vec<osmpbf::Result<OsmData>> = blobs
        .into_par_iter()
        .map(|blob| read_blob(&blob?))
        .collect();
    let mut data = OsmData::default();
    for piece in decoded {
        data.append(piece.map_err(corrupt)?);
    }
    Ok(data)
}

/// The elements of one blob (none for a header blob).
fn read_blob(blob: &Blob) -> osmpbf::Result<OsmData> {
    let mut data = OsmData::default();
    let BlobDecode::OsmData(block) = blob.decode()? else {
        return Ok(data);
    };
    block.for_each_element(|element| match element {
        // Divide the integer by 1e7 (exact operands, one correctly rounded division) so
        // the value equals the XML reader's parse of the same decimal text.
        Element::Node(n) => data.add_node(
            n.id(),
            n.decimicro_lat() as f64 / 1e7,
            n.decimicro_lon() as f64 / 1e7,
            tags(n.tags()),
        ),
        Element::DenseNode(n) => data.add_node(
            n.id(),
            n.decimicro_lat() as f64 / 1e7,
            n.decimicro_lon() as f64 / 1e7,
            tags(n.tags()),
        ),
        Element::Way(w) => {
            data.ways.insert(
                w.id(),
                OsmWay {
                    nodes: w.refs().collect(),
                    tags: tags(w.tags()),
                },
            );
        }
        Element::Relation(r) => {
            let members = r
                .members()
                .map(|m| Member {
                    kind: match m.member_type {
                        RelMemberType::Node => MemberKind::Node,
                        RelMemberType::Way => MemberKind::Way,
                        RelMemberType::Relation => MemberKind::Relation,
                    },
                    id: m.member_id,
                    role: m.role().unwrap_or_default().to_owned(),
                })
                .collect();
            data.relations.insert(
                r.id(),
                OsmRelation {
                    members,
                    tags: tags(r.tags()),
                },
            );
        }
    });
    Ok(data)
}
