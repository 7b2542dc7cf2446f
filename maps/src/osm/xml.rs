//! OSM XML (`.osm`, also gzip-compressed) with quick-xml.
//!
//! The file is read into memory first and parsed from the slice: quick-xml then borrows
//! every event from it instead of copying, which halves the parse time of a city extract.

use std::io::Read;
use std::path::Path;

use quick_xml::events::{BytesStart, Event};

use super::{Member, MemberKind, OsmData, OsmRelation, OsmWay, Tags};
use crate::error::MapError;

mod fast;

/// Reads an OSM XML file, plain or gzip-compressed.
pub fn read_xml(path: &Path) -> Result<OsmData, MapError> {
    let raw = std::fs::read(path).map_err(|e| MapError::io(path, e))?;
    let text = if raw.starts_with(&[0x1f, 0x8b]) {
        let mut out = Vec::with_capacity(raw.len() * 8);
        flate2::read::MultiGzDecoder::new(raw.as_slice())
            .read_to_end(&mut out)
            .map_err(|e| MapError::invalid(path, format!("corrupt gzip data: {e}")))?;
        out
    } else {
        raw
    };
    parse_xml(&text).map_err(|e| e.with_path(path))
}

#[derive(Default)]
enum Open {
    #[default]
    None,
    Node {
        id: i64,
        lat: f64,
        lon: f64,
        tags: Tags,
    },
    Way {
        id: i64,
        way: OsmWay,
    },
    Relation {
        id: i64,
        rel: OsmRelation,
    },
}

/// Parses OSM XML held in memory. Errors carry no path; [`read_xml`] adds it.
///
/// A large file is parsed as one piece per thread, side by side and without copying: the
/// pieces are cut just before top-level elements, the first holds the `<osm>` start tag and
/// the last stops before the `</osm>` that ends the file. The pieces' data is merged in file
/// order, so a later element wins as it does in one pass. Any error in any piece re-parses the
/// whole file in one pass, so the error message and its byte position are those of a plain
/// sequential parse.
pub fn parse_xml(input: &[u8]) -> Result<OsmData, MapError> {
    let Some(pieces) = split_into_pieces(input, rayon::current_num_threads()) else {
        return parse_xml_sequential(input);
    };
    let parsed = parse_pieces(input, &pieces);
    match parsed {
        Some(data) => Ok(data),
        None => parse_xml_sequential(input),
    }
}

/// The smallest piece worth a thread of its own.
const MIN_PIECE_BYTES: usize = 256 * 1024;

/// The byte ranges of the pieces of `input` (at most `threads`), or None when it is too small
/// to split or does not end with `</osm>`.
fn split_into_pieces(input: &[u8], threads: usize) -> Option<Vec<std::ops::Range<usize>>> {
    let count = threads.min(input.len() / MIN_PIECE_BYTES);
    if count < 2 {
        return None;
    }
    let end = input.trim_ascii_end().strip_suffix(b"</osm>")?.len();
    let mut starts = vec![0];
    for i in 1..count {
        let target = (end / count * i).max(*starts.last()?);
        if let Some(at) = next_top_level_element(&input[target..end]) {
            starts.push(target + at);
        }
    }
    starts.dedup();
    if starts.len() < 2 {
        return None;
    }
    let ends = starts.iter().skip(1).copied().chain([end]);
    Some(starts.iter().zip(ends).map(|(&s, e)| s..e).collect())
}

/// Where the next `<node `, `<way ` or `<relation ` start tag begins in `text`.
fn next_top_level_element(text: &[u8]) -> Option<usize> {
    let mut from = 0;
    while let Some(at) = memchr::memchr(b'<', &text[from..]) {
        let tag = &text[from + at..];
        if [b"<node ".as_slice(), b"<way ", b"<relation "]
            .iter()
            .any(|t| tag.starts_with(t))
        {
            return Some(from + at);
        }
        from += at + 1;
    }
    None
}

/// Parses the pieces on the thread pool and merges them in order; None when any piece fails
/// or the pieces do not fit together.
fn parse_pieces(input: &[u8], pieces: &[std::ops::Range<usize>]) -> Option<OsmData> {
    use rayon::prelude::*;
    let parsed: Vec<Result<Piece, MapError>> = pieces
        .par_iter()
        .map(|range| parse_piece(&input[range.clone()]))
        .collect();
    let mut merged: Option<OsmData> = None;
    for (i, piece) in parsed.into_iter().enumerate() {
        let piece = piece.ok()?;
        // Each piece must end where the one-pass parse would be between top-level
        // elements: inside the `<osm>` root after the first piece, at the top otherwise.
        let fits = if i == 0 {
            piece.open_elements == 1 && piece.outermost_is_osm
        } else {
            piece.open_elements == 0
        };
        if !fits || piece.ends_inside_element {
            return None;
        }
        let data = piece.data;
        match &mut merged {
            None => merged = Some(data),
            Some(all) => all.append(data),
        }
    }
    merged
}

fn parse_xml_sequential(input: &[u8]) -> Result<OsmData, MapError> {
    let piece = parse_piece(input)?;
    if !piece.saw_root {
        return Err(MapError::Parse {
            path: None,
            message: "no <osm> root element: not an OSM XML file".into(),
        });
    }
    if piece.ends_inside_element {
        return Err(MapError::Parse {
            path: None,
            message: "the file ends inside an element (truncated?)".into(),
        });
    }
    Ok(piece.data)
}

/// What one piece of XML (or a whole file) holds.
struct Piece {
    data: OsmData,
    /// An `<osm>` or `<osmChange>` element was opened.
    saw_root: bool,
    /// How many elements are open at the end of the text, and whether the outermost of them
    /// is `<osm>`.
    open_elements: usize,
    outermost_is_osm: bool,
    /// The text ends before a `<node>`, `<way>` or `<relation>` is closed.
    ends_inside_element: bool,
}

/// Parses a whole file or one piece of it: with [`fast::parse_piece`] when the text keeps to
/// the plain form OSM writers produce, else (and for every error) with quick-xml.
fn parse_piece(input: &[u8]) -> Result<Piece, MapError> {
    match fast::parse_piece(input) {
        Some(piece) => Ok(piece),
        None => parse_piece_events(input),
    }
}

/// Parses a whole file or one piece of it with quick-xml's event reader.
fn parse_piece_events(input: &[u8]) -> Result<Piece, MapError> {
    let mut reader = quick_xml::Reader::from_reader(input);
    reader.config_mut().trim_text(true);
    let mut st = State::default();
    loop {
        let pos = reader.buffer_position();
        let event = reader.read_event().map_err(|e| MapError::Parse {
            path: None,
            message: format!("malformed XML near byte {pos}: {e}"),
        })?;
        let bad = |msg: String| MapError::Parse {
            path: None,
            message: format!("{msg} (near byte {pos})"),
        };
        match event {
            Event::Start(ref e) | Event::Empty(ref e) => {
                let is_empty = matches!(event, Event::Empty(_));
                st.start_element(e.name().as_ref(), is_empty, || Attrs::read(e))
                    .map_err(bad)?;
            }
            // quick-xml has checked that it closes the innermost open element.
            Event::End(ref e) => st.end_element(e.name().as_ref()),
            Event::Eof => break,
            _ => {}
        }
    }
    Ok(st.finish())
}

/// What a parse has read so far; both readers feed it the same element events.
#[derive(Default)]
struct State {
    data: OsmData,
    open: Open,
    saw_root: bool,
    depth: usize,
    outermost_is_osm: bool,
}

impl State {
    /// A start tag (`is_empty`: self-closing); `attrs` reads its attributes, only for the
    /// elements whose attributes matter.
    fn start_element(
        &mut self,
        name: &[u8],
        is_empty: bool,
        attrs: impl FnOnce() -> Result<Attrs, String>,
    ) -> Result<(), String> {
        if !is_empty {
            if self.depth == 0 {
                self.outermost_is_osm = name == b"osm";
            }
            self.depth += 1;
        }
        let (data, open) = (&mut self.data, &mut self.open);
        match name {
            b"osm" | b"osmChange" => self.saw_root = true,
            b"node" => {
                let a = attrs()?;
                if a.deleted {
                    return Ok(());
                }
                let id = a.id.ok_or("a <node> has no id")?;
                let (lat, lon) = match (a.lat, a.lon) {
                    (Some(lat), Some(lon)) => (lat, lon),
                    _ => (f64::NAN, f64::NAN),
                };
                *open = Open::Node {
                    id,
                    lat,
                    lon,
                    tags: Tags::default(),
                };
                if is_empty {
                    close(data, open);
                }
            }
            b"way" => {
                let a = attrs()?;
                let id = a.id.ok_or("a <way> has no id")?;
                *open = Open::Way {
                    id,
                    way: OsmWay {
                        nodes: Vec::new(),
                        tags: Tags::default(),
                    },
                };
                if is_empty || a.deleted {
                    close(data, open);
                }
            }
            b"relation" => {
                let a = attrs()?;
                let id = a.id.ok_or("a <relation> has no id")?;
                *open = Open::Relation {
                    id,
                    rel: OsmRelation {
                        members: Vec::new(),
                        tags: Tags::default(),
                    },
                };
                if is_empty || a.deleted {
                    close(data, open);
                }
            }
            b"tag" => {
                let a = attrs()?;
                if let (Some(k), Some(v)) = (a.k, a.v) {
                    match open {
                        Open::Node { tags, .. } => tags.insert(k, v),
                        Open::Way { way, .. } => way.tags.insert(k, v),
                        Open::Relation { rel, .. } => rel.tags.insert(k, v),
                        Open::None => {}
                    }
                }
            }
            b"nd" => {
                let a = attrs()?;
                if let (Open::Way { way, .. }, Some(r)) = (open, a.reference) {
                    way.nodes.push(r);
                }
            }
            b"member" => {
                let a = attrs()?;
                if let (Open::Relation { rel, .. }, Some(r), Some(kind)) =
                    (open, a.reference, a.member_kind)
                {
                    rel.members.push(Member {
                        kind,
                        id: r,
                        role: a.role.unwrap_or_default(),
                    });
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// An end tag; the reader has checked that it closes the innermost open element.
    fn end_element(&mut self, name: &[u8]) {
        self.depth = self.depth.saturating_sub(1);
        if matches!(name, b"node" | b"way" | b"relation") {
            close(&mut self.data, &mut self.open);
        }
    }

    fn finish(self) -> Piece {
        Piece {
            ends_inside_element: !matches!(self.open, Open::None),
            data: self.data,
            saw_root: self.saw_root,
            open_elements: self.depth,
            outermost_is_osm: self.outermost_is_osm,
        }
    }
}

fn close(data: &mut OsmData, open: &mut Open) {
    match std::mem::replace(open, Open::None) {
        Open::Node { id, lat, lon, tags } => data.add_node(id, lat, lon, tags),
        Open::Way { id, way } => {
            data.ways.insert(id, way);
        }
        Open::Relation { id, rel } => {
            data.relations.insert(id, rel);
        }
        Open::None => {}
    }
}

#[derive(Default)]
pub(super) struct Attrs {
    id: Option<i64>,
    lat: Option<f64>,
    lon: Option<f64>,
    k: Option<String>,
    v: Option<String>,
    reference: Option<i64>,
    member_kind: Option<MemberKind>,
    role: Option<String>,
    deleted: bool,
}

impl Attrs {
    fn read(e: &BytesStart) -> Result<Self, String> {
        let mut a = Attrs::default();
        // Duplicate-attribute checks cost a quarter of the parse and change nothing we read.
        for attr in e.attributes().with_checks(false) {
            let attr = attr.map_err(|err| format!("bad attribute: {err}"))?;
            let raw = || -> Result<String, String> {
                attr.unescape_value()
                    .map(|v| v.into_owned())
                    .map_err(|err| format!("bad attribute value: {err}"))
            };
            let text = || {
                std::str::from_utf8(&attr.value).map_err(|_| "attribute is not UTF-8".to_string())
            };
            a.set(attr.key.as_ref(), &attr.value, text, raw)?;
        }
        Ok(a)
    }

    /// Takes one attribute (a later one of the same name wins): `value` is its raw bytes,
    /// `text` the same as UTF-8 and `unescaped` its unescaped text, both computed only for
    /// the attributes read.
    pub(super) fn set<'v>(
        &mut self,
        key: &[u8],
        value: &[u8],
        text: impl FnOnce() -> Result<&'v str, String>,
        unescaped: impl FnOnce() -> Result<String, String>,
    ) -> Result<(), String> {
        match key {
            b"id" => self.id = Some(parse_int(text()?)?),
            b"ref" => self.reference = Some(parse_int(text()?)?),
            b"lat" => self.lat = Some(parse_float(text()?)?),
            b"lon" => self.lon = Some(parse_float(text()?)?),
            b"k" => self.k = Some(unescaped()?),
            b"v" => self.v = Some(unescaped()?),
            b"role" => self.role = Some(unescaped()?),
            b"type" => {
                self.member_kind = match value {
                    b"node" => Some(MemberKind::Node),
                    b"way" => Some(MemberKind::Way),
                    b"relation" => Some(MemberKind::Relation),
                    _ => None,
                }
            }
            b"action" => self.deleted |= value == b"delete",
            b"visible" => self.deleted |= value == b"false",
            _ => {}
        }
        Ok(())
    }
}

fn parse_int(s: &str) -> Result<i64, String> {
    s.trim()
        .parse()
        .map_err(|_| format!("{s:?} is not an integer id"))
}

fn parse_float(s: &str) -> Result<f64, String> {
    s.trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a coordinate"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_nodes_ways_relations_and_tags() {
        let xml = r#"<?xml version="1.0"?>
<osm version="0.6">
  <node id="1" lat="10.5" lon="20.25"><tag k="highway" v="stop"/></node>
  <node id="2" lat="10.6" lon="20.35"/>
  <way id="7"><nd ref="1"/><nd ref="2"/><tag k="highway" v="residential"/><tag k="name" v="A &amp; B"/></way>
  <relation id="9"><member type="way" ref="7" role="from"/><tag k="type" v="restriction"/></relation>
</osm>"#;
        let d = parse_xml(xml.as_bytes()).expect("parses");
        assert_eq!(d.nodes.len(), 2);
        assert_eq!(d.nodes[&1].tags.get("highway"), Some("stop"));
        assert_eq!(d.ways[&7].nodes, vec![1, 2]);
        assert_eq!(d.ways[&7].tags.get("name"), Some("A & B"));
        assert_eq!(d.relations[&9].members[0].role, "from");
    }

    #[test]
    fn split_parse_equals_sequential_parse() {
        // Large enough to be split: many nodes, then ways and a relation.
        let mut xml = String::from("<?xml version=\"1.0\"?>\n<osm version=\"0.6\">\n");
        for i in 0..12000 {
            xml += &format!(
                "  <node id=\"{i}\" lat=\"{}\" lon=\"{}\"><tag k=\"n\" v=\"{i}\"/></node>\n",
                10.0 + f64::from(i) * 1e-5,
                20.0
            );
        }
        for i in 0..2000 {
            xml += &format!(
                "  <way id=\"{i}\"><nd ref=\"{}\"/><nd ref=\"{}\"/><tag k=\"highway\" v=\"residential\"/></way>\n",
                2 * i,
                2 * i + 1
            );
        }
        xml += "  <relation id=\"1\"><member type=\"way\" ref=\"1\" role=\"from\"/></relation>\n</osm>\n";
        assert!(xml.len() > 3 * 256 * 1024, "large enough for three pieces");
        let split = parse_xml(xml.as_bytes()).expect("parses");
        let whole = parse_xml_sequential(xml.as_bytes()).expect("parses");
        assert_eq!(split, whole);
        for threads in [2, 3] {
            let pieces = split_into_pieces(xml.as_bytes(), threads).expect("splits");
            assert_eq!(pieces.len(), threads);
            let pieced = parse_pieces(xml.as_bytes(), &pieces).expect("pieces fit");
            assert_eq!(pieced, whole);
        }
        assert_eq!(
            (split.nodes.len(), split.ways.len(), split.relations.len()),
            (12000, 2000, 1)
        );
        // A broken way section gives the sequential parser's error, not a half-read map.
        let broken = xml.replace("<way id=\"1999\">", "<way id=\"1999\"></node>");
        assert!(parse_xml(broken.as_bytes()).is_err());
        // So does an element left open across pieces, which no single piece can see.
        let unclosed = xml.replace("<way id=\"1000\">", "<extra><way id=\"1000\">");
        let pieces = split_into_pieces(unclosed.as_bytes(), 2).expect("splits");
        assert!(parse_pieces(unclosed.as_bytes(), &pieces).is_none());
        assert!(parse_xml(unclosed.as_bytes()).is_err());
    }

    #[test]
    fn malformed_and_truncated_inputs_are_errors() {
        assert!(parse_xml(&b"<osm><node id=\"1\" lat=\"1\" lon=\"2\"></way></osm>"[..]).is_err());
        assert!(parse_xml(&b"<osm><way id=\"1\"><nd ref=\"1\"/>"[..]).is_err());
        assert!(parse_xml(&b"hello"[..]).is_err());
        assert!(parse_xml(&b"<osm><node id=\"x\" lat=\"1\" lon=\"2\"/></osm>"[..]).is_err());
    }

    #[test]
    fn absurd_coordinates_are_dropped_and_counted() {
        let d = parse_xml(&b"<osm><node id=\"1\" lat=\"95\" lon=\"2\"/><node id=\"2\" lat=\"1\" lon=\"2\"/></osm>"[..])
            .expect("parses");
        assert_eq!(d.invalid_nodes, vec![1]);
        assert_eq!(d.nodes.len(), 1);
    }
}
