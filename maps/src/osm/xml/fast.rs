//! A scanner for the plain XML that OSM writers produce, several times faster than the
//! event reader: start, end and self-closing tags with `key="value"` (or `'value'`)
//! attributes, whitespace between them, comments and `<?...?>` declarations.
//!
//! Text between tags is skipped, as the event reader's text events are. It gives up
//! (None) on anything else: CDATA, a DOCTYPE, a non-UTF-8 value, an
//! end tag that does not close the innermost open element, an attribute the element
//! reader rejects, odd spacing inside a tag. The caller then parses the same text with
//! quick-xml, so a file is read exactly as before, errors included; for the text it
//! accepts, this scanner feeds [`State`] the same elements and attribute values (unescaped
//! by quick-xml's own function) as the event reader would.

use super::{Attrs, Piece, State};

/// The piece as [`super::parse_piece_events`] reads it, or None to let that reader do it.
pub(super) fn parse_piece(input: &[u8]) -> Option<Piece> {
    let mut st = State::default();
    let mut open: Vec<&[u8]> = Vec::new();
    let mut attrs = Vec::new();
    let mut i = 0;
    loop {
        // Text between tags (an Overpass `<note>`, say) is skipped, as the event reader's
        // text events are.
        let Some(lt) = memchr::memchr(b'<', &input[i..]) else {
            return Some(st.finish());
        };
        i += lt + 1;
        match *input.get(i)? {
            b'?' => {
                let end = memchr::memmem::find(&input[i..], b"?>")?;
                i += end + 2;
            }
            b'!' => {
                if !input[i..].starts_with(b"!--") {
                    return None;
                }
                let end = memchr::memmem::find(&input[i + 3..], b"-->")?;
                i += 3 + end + 3;
            }
            b'/' => {
                let end = memchr::memchr(b'>', &input[i..])?;
                let name = &input[i + 1..i + end];
                if open.pop()? != name {
                    return None;
                }
                st.end_element(name);
                i += end + 1;
            }
            _ => {
                let tag = StartTag::scan(input, i, std::mem::take(&mut attrs))?;
                st.start_element(tag.name, tag.is_empty, || tag.read_attrs())
                    .ok()?;
                if !tag.is_empty {
                    open.push(tag.name);
                }
                i = tag.end;
                attrs = tag.attrs;
            }
        }
    }
}

/// A start tag: its name, its attributes (key and raw value), whether it closes itself,
/// and where it ends (just past the `>`).
struct StartTag<'a> {
    name: &'a [u8],
    attrs: Vec<(&'a [u8], &'a [u8])>,
    is_empty: bool,
    end: usize,
}

/// XML whitespace (quick-xml's definition: no form feed).
fn is_space(b: &u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\r' | b'\n')
}

fn is_name_end(b: u8) -> bool {
    is_space(&b) || b == b'/' || b == b'>'
}

impl<'a> StartTag<'a> {
    /// The tag whose name starts at `from`, or None when it is not plain: whitespace before
    /// each `key="value"` (or single quotes), nothing around the `=`, no `<` in a value.
    /// `attrs` is a buffer to reuse.
    fn scan(
        input: &'a [u8],
        from: usize,
        mut attrs: Vec<(&'a [u8], &'a [u8])>,
    ) -> Option<StartTag<'a>> {
        attrs.clear();
        let mut i = from;
        while !is_name_end(*input.get(i)?) {
            i += 1;
        }
        let name = &input[from..i];
        if name.is_empty() || name.contains(&b'<') {
            return None;
        }
        loop {
            let c = *input.get(i)?;
            if c == b'>' {
                return Some(StartTag {
                    name,
                    attrs,
                    is_empty: false,
                    end: i + 1,
                });
            }
            if c == b'/' {
                return (input.get(i + 1) == Some(&b'>')).then_some(StartTag {
                    name,
                    attrs,
                    is_empty: true,
                    end: i + 2,
                });
            }
            // Each attribute follows whitespace.
            if !is_space(&c) {
                return None;
            }
            while is_space(input.get(i)?) {
                i += 1;
            }
            if matches!(input[i], b'>' | b'/') {
                continue;
            }
            let key_start = i;
            loop {
                let b = *input.get(i)?;
                if b == b'=' {
                    break;
                }
                if is_name_end(b) || matches!(b, b'<' | b'"' | b'\'') {
                    return None;
                }
                i += 1;
            }
            let key = &input[key_start..i];
            let quote = *input.get(i + 1)?;
            if (quote != b'"' && quote != b'\'') || key.is_empty() {
                return None;
            }
            let value_start = i + 2;
            i = value_start;
            loop {
                let b = *input.get(i)?;
                if b == quote {
                    break;
                }
                if b == b'<' {
                    return None;
                }
                i += 1;
            }
            attrs.push((key, &input[value_start..i]));
            i += 1;
            if !is_name_end(*input.get(i)?) {
                return None;
            }
        }
    }

    /// The attributes the element reader takes, read as it reads them.
    fn read_attrs(&self) -> Result<Attrs, String> {
        let mut a = Attrs::default();
        for &(key, value) in &self.attrs {
            let text = || std::str::from_utf8(value).map_err(|_| "not UTF-8".to_string());
            let unescaped = || -> Result<String, String> {
                let text = text()?;
                if value.contains(&b'&') {
                    quick_xml::escape::unescape(text)
                        .map(|v| v.into_owned())
                        .map_err(|e| e.to_string())
                } else {
                    Ok(text.to_owned())
                }
            };
            a.set(key, value, text, unescaped)?;
        }
        Ok(a)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::super::{parse_piece_events, split_into_pieces};
    use super::*;
    use crate::osm::OsmData;

    /// The scanner's result, and the event reader's, on the same text.
    fn both(xml: &[u8]) -> (Option<Piece>, Result<Piece, crate::MapError>) {
        (parse_piece(xml), parse_piece_events(xml))
    }

    fn same(a: &Piece, b: &Piece) -> bool {
        a.data == b.data
            && a.saw_root == b.saw_root
            && a.open_elements == b.open_elements
            && a.outermost_is_osm == b.outermost_is_osm
            && a.ends_inside_element == b.ends_inside_element
    }

    /// Whenever the scanner answers, the event reader reads the same.
    fn check(xml: &[u8]) -> Option<OsmData> {
        let (fast, events) = both(xml);
        let fast = fast?;
        let events = events.unwrap_or_else(|e| {
            panic!(
                "the scanner accepted what the event reader rejects ({e}): {}",
                String::from_utf8_lossy(xml)
            )
        });
        assert!(same(&fast, &events), "{}", String::from_utf8_lossy(xml));
        Some(fast.data)
    }

    #[test]
    fn reads_what_the_event_reader_reads() {
        let xml = r#"<?xml version="1.0" encoding="UTF-8"?>
<!-- a comment with <node id="5"/> inside -->
<osm version="0.6" generator='test'>
  <bounds minlat="1" minlon="2" maxlat="3" maxlon="4"/>
  <node id="1" lat="10.5" lon="20.25"><tag k="highway" v="stop"/></node>
  <node id="2" lat='10.6' lon="20.35" visible="true"/>
  <node id="3" lat="10.6" lon="20.35" action="delete"><tag k="a" v="b"/></node>
  <way id="7"><nd ref="1"/><nd ref="2"/><tag k="highway" v="residential"/><tag k="name" v="A &amp; B &#233; &lt;x&gt; 'q' &quot;"/></way>
  <way id="8" visible="false"><nd ref="1"/></way>
  <relation id="9"><member type="way" ref="7" role="from"/><member type="node" ref="1" role=""/><tag k="type" v="restriction"/></relation>
  <node id="4" lat="1" lon="2"><tag k="note" v="a > b"/><tag k="note" v="later wins"/></node>
</osm>
"#;
        let d = check(xml.as_bytes()).expect("the scanner reads plain OSM XML");
        assert_eq!(d.ways[&7].tags.get("name"), Some("A & B é <x> 'q' \""));
        assert_eq!(d.nodes[&4].tags.get("note"), Some("later wins"));
        assert!(!d.nodes.contains_key(&3));
    }

    #[test]
    fn gives_up_on_what_it_does_not_know_and_never_accepts_more() {
        let cases: &[&str] = &[
            "<osm><node id=\"1\" lat=\"1\" lon=\"2\"></way></osm>",
            "<osm><way id=\"1\"><nd ref=\"1\"/>",
            "hello",
            "<osm>text &amp; more</osm>",
            "<osm><note>a < b</note></osm>",
            "<osm><node id=\"x\" lat=\"1\" lon=\"2\"/></osm>",
            "<osm><node id=\"1\" lat=\"1\" lon=\"2\"/></osm>trailing",
            "<osm><node id = \"1\" lat=\"1\" lon=\"2\"/></osm>",
            "<osm><node id=\"1\"lat=\"1\" lon=\"2\"/></osm>",
            "<osm><node id=1 lat=\"1\" lon=\"2\"/></osm>",
            "<osm><node id=\"1\" lat=\"1\" lon=\"2\" /></osm >",
            "<!DOCTYPE osm><osm></osm>",
            "<osm><![CDATA[x]]></osm>",
            "<osm><tag k=\"a&bogus;\" v=\"1\"/></osm>",
            "<osm><way id=\"1\"><tag k=\"a\" v=\"b\x0c\"/></way></osm>",
            "<osm><node id=\"1\" lat=\"1\" lon=\"2\"/>\x0c</osm>",
            "<osm><node/><way/></osm>",
            "<osm></osm></osm>",
            "<osm><a/b></osm>",
            "< osm></osm>",
            "<osm><!-- unclosed </osm>",
            "<?xml version=\"1.0\"",
            "\u{feff}<osm></osm>",
            "<osm>\r\n\t<node id=\"1\" lat=\"1\" lon=\"2\"\r\n/>\r\n</osm>",
        ];
        for xml in cases {
            check(xml.as_bytes());
        }
        let mut bad_utf8 = b"<osm><way id=\"1\"><tag k=\"a\" v=\"".to_vec();
        bad_utf8.extend_from_slice(&[0xff, 0xfe]);
        bad_utf8.extend_from_slice(b"\"/></way></osm>");
        assert!(parse_piece(&bad_utf8).is_none());
        check(&bad_utf8);
    }

    /// Every OSM XML file at hand, whole and in pieces: the scanner must read all of them,
    /// exactly as the event reader does.
    #[test]
    fn real_files_read_alike_whole_and_in_pieces() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let mut files = Vec::new();
        for dir in [
            root.join("../shared/data/osm"),
            root.join("../shared/data/trajectories/interaction/maps"),
        ]
        .into_iter()
        .chain(
            std::fs::read_dir(root.join("tests/golden"))
                .into_iter()
                .flatten()
                .flatten()
                .map(|e| e.path()),
        ) {
            for entry in std::fs::read_dir(&dir).into_iter().flatten().flatten() {
                let path = entry.path();
                if path.extension().is_some_and(|e| e == "osm") {
                    files.push(path);
                }
            }
        }
        assert!(!files.is_empty(), "no OSM XML files found");
        for path in files {
            let xml = std::fs::read(&path).unwrap();
            assert!(
                check(&xml).is_some(),
                "{}: the scanner gave up",
                path.display()
            );
            for threads in [2, 3] {
                for range in split_into_pieces(&xml, threads).into_iter().flatten() {
                    check(&xml[range]);
                }
            }
        }
    }
}
