//! OSM PBF with the osmpbf crate.

use std::path::Path;

use osmpbf::{Element, ElementReader, RelMemberType};

use super::{Member, MemberKind, OsmData, OsmRelation, OsmWay, Tags};
use crate::error::MapError;

fn tags<'a>(iter: impl Iterator<Item = (&'a str, &'a str)>) -> Tags {
    let mut t: Vec<(String, String)> = iter.map(|(k, v)| (k.to_owned(), v.to_owned())).collect();
    t.sort();
    t.dedup_by(|a, b| a.0 == b.0);
    Tags(t)
}

/// Reads an `.osm.pbf` file. Corrupt or truncated blobs are errors.
pub fn read_pbf(path: &Path) -> Result<OsmData, MapError> {
    let reader = ElementReader::from_path(path)
        .map_err(|e| MapError::io(path, std::io::Error::other(e.to_string())))?;
    let mut data = OsmData::default();
    reader
        .for_each(|element| match element {
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
        })
        .map_err(|e| MapError::Parse {
            path: Some(path.to_path_buf()),
            message: format!("corrupt or truncated PBF: {e}"),
        })?;
    Ok(data)
}
