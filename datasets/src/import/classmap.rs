//! Class maps: TOML files that say which of our classes each source class becomes.
//!
//! ```toml
//! name = "camvid"
//! encoding = "index"            # index: the label PNG holds class indices (grey or palette)
//!                               # red: the red channel holds them (CARLA's raw renders)
//!                               # binary: zero / non-zero (lane masks), see [binary]
//! labelable = ["road", "vehicle", "human", "other"]
//! class = [
//!   { id = 3, name = "Road", target = "road" },
//!   { id = 11, name = "Unlabelled", target = "ignore" },
//! ]
//! # encoding = "binary" instead lists:
//! # [binary]
//! # zero = "ignore"
//! # nonzero = "lane_marking"
//! ```
//!
//! A source value the map does not list is an error (the label holds something the map's
//! author did not expect), never a silent default. The maps of the supported sets ship in
//! `datasets/classmaps/` and are built in by name.

use std::io::Cursor;
use std::path::Path;

use image::{DynamicImage, GrayImage};
use serde::{Deserialize, Serialize};

use crate::classes::{Class, label_from_name};
use crate::error::{DatasetError, Result};

/// How a label file holds the source class of a pixel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Encoding {
    /// One 8-bit (or smaller) index per pixel: grey or palette PNG, read without the palette.
    Index,
    /// The red channel of an RGB(A) image (CARLA's raw semantic camera).
    Red,
    /// Zero or not (lane masks); any channel non-zero counts.
    Binary,
}

/// One source class and what it becomes.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceClass {
    pub id: u8,
    pub name: String,
    /// A class name or `ignore`.
    pub target: String,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct BinaryTargets {
    zero: String,
    nonzero: String,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct ClassMapFile {
    name: String,
    encoding: Encoding,
    labelable: Vec<String>,
    #[serde(default)]
    class: Vec<SourceClass>,
    binary: Option<BinaryTargets>,
}

/// A parsed, checked class map.
#[derive(Debug, Clone, PartialEq)]
pub struct ClassMap {
    pub name: String,
    pub encoding: Encoding,
    /// Target classes the source can label at all (recorded in the card).
    pub labelable: Vec<Class>,
    /// The source classes, in the file's order (for binary maps: `zero` and `nonzero`).
    pub classes: Vec<SourceClass>,
    /// Source value -> index into `classes`.
    lookup: [Option<u16>; 256],
    /// Source value -> label value written.
    targets: [Option<u8>; 256],
}

/// Built-in maps: (name, TOML text).
const BUILTIN: &[(&str, &str)] = &[
    ("camvid", include_str!("../../classmaps/camvid.toml")),
    (
        "cityscapes_labelids",
        include_str!("../../classmaps/cityscapes_labelids.toml"),
    ),
    (
        "cityscapes_trainids",
        include_str!("../../classmaps/cityscapes_trainids.toml"),
    ),
    (
        "mapillary_v1.2",
        include_str!("../../classmaps/mapillary_v1.2.toml"),
    ),
    (
        "mapillary_v2.0",
        include_str!("../../classmaps/mapillary_v2.0.toml"),
    ),
    (
        "carla_pre_0.9.14",
        include_str!("../../classmaps/carla_pre_0.9.14.toml"),
    ),
    (
        "carla_0.9.14",
        include_str!("../../classmaps/carla_0.9.14.toml"),
    ),
    ("lane_mask", include_str!("../../classmaps/lane_mask.toml")),
    ("ids", include_str!("../../classmaps/ids.toml")),
];

/// Names of the built-in class maps.
pub fn builtin_names() -> Vec<&'static str> {
    BUILTIN.iter().map(|(n, _)| *n).collect()
}

impl ClassMap {
    /// A built-in map by name, or a TOML file.
    pub fn load(spec: &str) -> Result<ClassMap> {
        if let Some((name, text)) = BUILTIN.iter().find(|(n, _)| *n == spec) {
            return ClassMap::parse(Path::new(&format!("<built-in {name}>")), text);
        }
        let path = Path::new(spec);
        if !path.exists() {
            return Err(DatasetError::invalid(
                path,
                format!(
                    "no such class map file, and not a built-in map ({})",
                    builtin_names().join(", ")
                ),
            ));
        }
        let text = std::fs::read_to_string(path).map_err(|e| DatasetError::io(path, e))?;
        ClassMap::parse(path, &text)
    }

    /// Parses and checks a class map (`path` names it in errors).
    pub fn parse(path: &Path, text: &str) -> Result<ClassMap> {
        let bad = |m: String| DatasetError::invalid(path, format!("not a usable class map: {m}"));
        let file: ClassMapFile = toml::from_str(text).map_err(|e| bad(e.message().to_owned()))?;
        let labelable = file
            .labelable
            .iter()
            .map(|n| {
                Class::from_name(n).ok_or_else(|| bad(format!("labelable: unknown class `{n}`")))
            })
            .collect::<Result<Vec<_>>>()?;
        let target_of = |t: &str| {
            label_from_name(t).ok_or_else(|| {
                bad(format!(
                    "unknown target `{t}` (expected road, lane_marking, vehicle, human, other or ignore)"
                ))
            })
        };
        let mut lookup = [None; 256];
        let mut targets = [None; 256];
        let classes = match (file.encoding, file.binary) {
            (Encoding::Binary, Some(b)) => {
                if !file.class.is_empty() {
                    return Err(bad("a binary map lists [binary], not classes".into()));
                }
                let (zero, nonzero) = (target_of(&b.zero)?, target_of(&b.nonzero)?);
                lookup[0] = Some(0);
                targets[0] = Some(zero);
                for v in 1..256 {
                    lookup[v] = Some(1);
                    targets[v] = Some(nonzero);
                }
                vec![
                    SourceClass {
                        id: 0,
                        name: "zero".into(),
                        target: b.zero,
                    },
                    SourceClass {
                        id: 1,
                        name: "nonzero".into(),
                        target: b.nonzero,
                    },
                ]
            }
            (Encoding::Binary, None) => {
                return Err(bad("encoding = \"binary\" needs a [binary] table".into()));
            }
            (_, Some(_)) => return Err(bad("[binary] is only for encoding = \"binary\"".into())),
            (_, None) => {
                if file.class.is_empty() {
                    return Err(bad("no classes".into()));
                }
                for (i, c) in file.class.iter().enumerate() {
                    let slot = usize::from(c.id);
                    if lookup[slot].is_some() {
                        return Err(bad(format!("source id {} is listed twice", c.id)));
                    }
                    lookup[slot] = Some(i as u16);
                    targets[slot] = Some(target_of(&c.target)?);
                }
                file.class
            }
        };
        Ok(ClassMap {
            name: file.name,
            encoding: file.encoding,
            labelable,
            classes,
            lookup,
            targets,
        })
    }

    /// The source class a source value belongs to.
    pub fn source_class(&self, value: u8) -> Option<&SourceClass> {
        self.lookup[usize::from(value)].and_then(|i| self.classes.get(usize::from(i)))
    }

    /// Index of the source class of a value (into `classes`).
    pub fn source_class_index(&self, value: u8) -> Option<usize> {
        self.lookup[usize::from(value)].map(usize::from)
    }

    /// The label value a source value becomes; None if the map does not list it.
    pub fn target(&self, value: u8) -> Option<u8> {
        self.targets[usize::from(value)]
    }

    /// Checks the map's names against a Mapillary-style config JSON (`{"labels": [{"name":
    /// ...}, ...]}`, the index being the id), so a map for another version is caught.
    pub fn check_source_config(&self, path: &Path, json: &str) -> Result<()> {
        #[derive(Deserialize)]
        struct Label {
            name: String,
        }
        #[derive(Deserialize)]
        struct Config {
            labels: Vec<Label>,
        }
        let config: Config = serde_json::from_str(json)
            .map_err(|e| DatasetError::invalid(path, format!("not a label config JSON: {e}")))?;
        if config.labels.len() != self.classes.len() {
            return Err(DatasetError::invalid(
                path,
                format!(
                    "lists {} labels but class map `{}` has {}: a config of another version?",
                    config.labels.len(),
                    self.name,
                    self.classes.len()
                ),
            ));
        }
        for (id, label) in config.labels.iter().enumerate() {
            let ours = u8::try_from(id).ok().and_then(|v| self.source_class(v));
            if ours.map(|c| c.name.as_str()) != Some(label.name.as_str()) {
                return Err(DatasetError::invalid(
                    path,
                    format!(
                        "label {id} is `{}` but class map `{}` says `{}`",
                        label.name,
                        self.name,
                        ours.map_or("nothing", |c| c.name.as_str())
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The source values of a label file's bytes, as this map's encoding reads them.
    pub fn source_values(&self, path: &Path, bytes: &[u8]) -> Result<GrayImage> {
        match self.encoding {
            Encoding::Index => read_index_png(path, bytes),
            Encoding::Red => {
                let image = crate::image_io::decode_image(path, bytes)?;
                if image.color().channel_count() < 3 {
                    return Err(DatasetError::image(
                        path,
                        format!(
                            "expected an RGB render with tags in red, not {:?}",
                            image.color()
                        ),
                    ));
                }
                let rgb = image.into_rgb8();
                let red = rgb.as_raw().chunks_exact(3).map(|p| p[0]).collect();
                GrayImage::from_raw(rgb.width(), rgb.height(), red)
                    .ok_or_else(|| DatasetError::image(path, "image buffer size mismatch"))
            }
            Encoding::Binary => match crate::image_io::decode_image(path, bytes)? {
                DynamicImage::ImageLuma8(l) => Ok(l),
                other => {
                    let rgb = other.into_rgb8();
                    let any = rgb
                        .as_raw()
                        .chunks_exact(3)
                        .map(|p| u8::from(p.iter().any(|&v| v > 0)))
                        .collect();
                    GrayImage::from_raw(rgb.width(), rgb.height(), any)
                        .ok_or_else(|| DatasetError::image(path, "image buffer size mismatch"))
                }
            },
        }
    }

    /// Maps source values into label values; the first value the map does not list is an
    /// error naming the file.
    pub fn apply(&self, path: &Path, source: &GrayImage) -> Result<GrayImage> {
        let mut out = Vec::with_capacity(source.as_raw().len());
        for &v in source.as_raw() {
            match self.targets[usize::from(v)] {
                Some(t) => out.push(t),
                None => {
                    return Err(DatasetError::invalid(
                        path,
                        format!(
                            "label value {v} is not a class of class map `{}`",
                            self.name
                        ),
                    ));
                }
            }
        }
        GrayImage::from_raw(source.width(), source.height(), out)
            .ok_or_else(|| DatasetError::image(path, "label buffer size mismatch"))
    }
}

/// Reads the raw indices of an 8-bit-or-less grey or palette PNG (the palette is not
/// applied: the index is the class).
fn read_index_png(path: &Path, bytes: &[u8]) -> Result<GrayImage> {
    let not_label = |m: String| DatasetError::image(path, m);
    let mut decoder = png::Decoder::new(Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::IDENTITY);
    let mut reader = decoder
        .read_info()
        .map_err(|e| not_label(format!("not a readable PNG label: {e}")))?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| not_label("PNG too large".into()))?;
    let mut buf = vec![0; size];
    let info = reader
        .next_frame(&mut buf)
        .map_err(|e| not_label(format!("not a readable PNG label: {e}")))?;
    if !matches!(
        info.color_type,
        png::ColorType::Grayscale | png::ColorType::Indexed
    ) {
        return Err(not_label(format!(
            "a label of class indices must be a grey or palette PNG, not {:?}",
            info.color_type
        )));
    }
    let bits = match info.bit_depth {
        png::BitDepth::One => 1,
        png::BitDepth::Two => 2,
        png::BitDepth::Four => 4,
        png::BitDepth::Eight => 8,
        png::BitDepth::Sixteen => {
            return Err(not_label(
                "a 16-bit label cannot hold 8-bit class indices".into(),
            ));
        }
    };
    let (w, h) = (info.width as usize, info.height as usize);
    let mut values = Vec::with_capacity(w * h);
    for row in buf.chunks(info.line_size).take(h) {
        if bits == 8 {
            values.extend_from_slice(&row[..w]);
        } else {
            let per_byte = 8 / bits;
            let mask = (1u8 << bits) - 1;
            values.extend((0..w).map(|x| {
                let byte = row[x / per_byte];
                let shift = 8 - bits * (x % per_byte + 1);
                (byte >> shift) & mask
            }));
        }
    }
    GrayImage::from_raw(info.width, info.height, values)
        .ok_or_else(|| not_label("PNG rows shorter than its width".into()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_builtin_map_parses_and_is_complete() -> Result<()> {
        for name in builtin_names() {
            let map = ClassMap::load(name)?;
            assert!(!map.labelable.is_empty(), "{name}");
            // Every listed target is a valid label value.
            for c in &map.classes {
                assert!(label_from_name(&c.target).is_some(), "{name}: {c:?}");
            }
        }
        let camvid = ClassMap::load("camvid")?;
        assert_eq!(camvid.classes.len(), 12);
        assert_eq!(camvid.target(3), Some(0));
        assert_eq!(camvid.target(11), Some(255));
        assert_eq!(camvid.target(12), None);
        assert!(!camvid.labelable.contains(&Class::LaneMarking));
        assert_eq!(ClassMap::load("mapillary_v1.2")?.classes.len(), 66);
        assert_eq!(ClassMap::load("mapillary_v2.0")?.classes.len(), 124);
        assert_eq!(ClassMap::load("carla_pre_0.9.14")?.classes.len(), 23);
        let carla = ClassMap::load("carla_0.9.14")?;
        assert_eq!(carla.classes.len(), 29);
        assert_eq!(carla.target(24), Some(Class::LaneMarking.id()));
        let lanes = ClassMap::load("lane_mask")?;
        assert_eq!((lanes.target(0), lanes.target(4)), (Some(255), Some(1)));
        Ok(())
    }

    #[test]
    fn broken_maps_are_refused_with_the_file_named() {
        let p = Path::new("maps/bad.toml");
        for text in [
            "name = 1",
            "name = \"x\"\nencoding = \"index\"\nlabelable = []\nclass = [{ id = 1, name = \"a\", target = \"sky\" }]",
            "name = \"x\"\nencoding = \"index\"\nlabelable = [\"road\"]\nclass = [{ id = 1, name = \"a\", target = \"road\" }, { id = 1, name = \"b\", target = \"road\" }]",
            "name = \"x\"\nencoding = \"binary\"\nlabelable = [\"road\"]",
            "name = \"x\"\nencoding = \"index\"\nlabelable = [\"road\"]\nclass = [{ id = 300, name = \"a\", target = \"road\" }]",
        ] {
            let err = ClassMap::parse(p, text).err().map(|e| e.to_string());
            assert!(
                err.as_deref()
                    .is_some_and(|e| e.starts_with("maps/bad.toml:")),
                "{err:?}"
            );
        }
    }

    #[test]
    fn mapillary_config_names_are_checked() -> Result<()> {
        let map = ClassMap::load("mapillary_v1.2")?;
        let names: Vec<_> = map
            .classes
            .iter()
            .map(|c| serde_json::json!({ "name": c.name }))
            .collect();
        let good = serde_json::json!({ "labels": names }).to_string();
        map.check_source_config(Path::new("config_v1.2.json"), &good)?;
        let v2 = ClassMap::load("mapillary_v2.0")?;
        assert!(
            v2.check_source_config(Path::new("config_v1.2.json"), &good)
                .is_err()
        );
        Ok(())
    }

    #[test]
    fn palette_pngs_are_read_as_indices() -> Result<()> {
        // A 1x3 palette PNG whose palette colours are all white: only the indices differ.
        let mut bytes = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut bytes, 3, 1);
            enc.set_color(png::ColorType::Indexed);
            enc.set_depth(png::BitDepth::Eight);
            enc.set_palette(vec![255u8; 3 * 12]);
            let mut w = enc
                .write_header()
                .map_err(|e| DatasetError::Config(e.to_string()))?;
            w.write_image_data(&[3, 8, 11])
                .map_err(|e| DatasetError::Config(e.to_string()))?;
        }
        let map = ClassMap::load("camvid")?;
        let values = map.source_values(Path::new("l.png"), &bytes)?;
        assert_eq!(values.as_raw(), &vec![3, 8, 11]);
        let label = map.apply(Path::new("l.png"), &values)?;
        assert_eq!(label.as_raw(), &vec![0, 2, 255]);
        Ok(())
    }
}
