//! PBF data read from memory (a map embedded in a program, as `pipeline dataset generate`
//! embeds the campus) gives the same map as the file holding those bytes, and damaged bytes
//! are an error. Uses the repository's bundled `data/osm` extracts: needs no shared data.
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;

use maps::{ImportOptions, MapError, import_file, import_pbf_bytes};

fn bundled(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../data/osm")
        .join(name)
}

#[test]
fn pbf_bytes_import_to_the_same_map_as_their_file() {
    for name in ["northwestern_nu.osm.pbf", "montlake_roundabout.osm.pbf"] {
        let path = bundled(name);
        let options = ImportOptions::default();
        let from_file = import_file(&path, &options).unwrap();
        let from_bytes = import_pbf_bytes(&std::fs::read(&path).unwrap(), &options).unwrap();
        assert!(!from_bytes.lanes.is_empty(), "{name}: no lanes");
        assert!(
            maps::io::to_binary_bytes(&from_file).unwrap()
                == maps::io::to_binary_bytes(&from_bytes).unwrap(),
            "{name}: the map from the bytes differs from the map from the file"
        );
    }
}

#[test]
fn damaged_pbf_bytes_are_a_parse_error() {
    let bytes = std::fs::read(bundled("montlake_roundabout.osm.pbf")).unwrap();
    let cut = &bytes[..bytes.len() / 2];
    let err = import_pbf_bytes(cut, &ImportOptions::default()).unwrap_err();
    assert!(
        matches!(&err, MapError::Parse { path: None, message } if message.contains("corrupt or truncated PBF")),
        "{err:?}"
    );
    let err = import_pbf_bytes(b"not a PBF at all", &ImportOptions::default()).unwrap_err();
    assert!(matches!(err, MapError::Parse { path: None, .. }), "{err:?}");
}
