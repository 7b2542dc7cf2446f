//! The one dataset format every command reads and writes.
//!
//! ```text
//! <dataset>/
//!   manifest.jsonl     one JSON object per line, sorted by id (see [`Item`])
//!   card.json          name, class table, labelable classes, provenance, config, seed ([`Card`])
//!   images/<id>.png    RGB8 (imports may keep .jpg)
//!   labels/<id>.png    single-channel L8 class ids (0-4, 255 ignore)
//!   previews/          optional colour previews, never read back
//! ```
//!
//! Paths inside the manifest are relative to the dataset folder. The writer is
//! deterministic: items sorted by id, struct fields in declaration order, `params` objects
//! with sorted keys (serde_json's map is ordered), so the same items give the same bytes.

use std::collections::HashSet;
use std::path::{Component, Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::classes::{Class, ClassEntry, class_table};
use crate::error::{DatasetError, Result};

pub const MANIFEST_FILE: &str = "manifest.jsonl";
pub const CARD_FILE: &str = "card.json";
pub const IMAGES_DIR: &str = "images";
pub const LABELS_DIR: &str = "labels";
pub const PREVIEWS_DIR: &str = "previews";

/// One image and its label.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Item {
    /// Unique in the dataset; also the file stem of its image and label.
    pub id: String,
    /// Image path relative to the dataset folder.
    pub image: String,
    /// Label path relative to the dataset folder.
    pub label: String,
    pub width: u32,
    pub height: u32,
    /// Where the item comes from: `generate`, `camvid`, ...; an augmented copy has
    /// `augment:<its source item's source>` (e.g. `augment:generate`).
    pub source: String,
    /// `train`, `val` or `test` once split.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub split: Option<String>,
    /// What made this item (seed, transform parameters, source file names...), enough to
    /// make it again.
    #[serde(default)]
    pub params: serde_json::Value,
}

impl Item {
    /// An item with the standard file names `images/<id>.png`, `labels/<id>.png`.
    pub fn new(
        id: impl Into<String>,
        source: impl Into<String>,
        (width, height): (u32, u32),
        params: serde_json::Value,
    ) -> Item {
        let id = id.into();
        Item {
            image: format!("{IMAGES_DIR}/{id}.png"),
            label: format!("{LABELS_DIR}/{id}.png"),
            id,
            width,
            height,
            source: source.into(),
            split: None,
            params,
        }
    }
}

/// What a dataset is, where it comes from and what it can label.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Card {
    pub name: String,
    /// The class table the labels use (always [`class_table`]).
    pub classes: Vec<ClassEntry>,
    /// Ids of the classes this source labels at all. A class outside this list may be
    /// present in the images but is labelled as something else (CamVid's lane markings
    /// are road), so training should mask its loss on such a dataset.
    pub labelable: Vec<u8>,
    /// Where the data comes from: tool and version, source dataset, class map, inputs.
    #[serde(default)]
    pub provenance: serde_json::Value,
    /// The configuration that made it.
    #[serde(default)]
    pub config: serde_json::Value,
    /// The global seed of every random draw.
    #[serde(default)]
    pub seed: u64,
}

impl Card {
    pub fn new(
        name: impl Into<String>,
        labelable: &[Class],
        provenance: serde_json::Value,
        config: serde_json::Value,
        seed: u64,
    ) -> Card {
        let mut labelable: Vec<u8> = labelable.iter().map(|c| c.id()).collect();
        labelable.sort_unstable();
        labelable.dedup();
        Card {
            name: name.into(),
            classes: class_table(),
            labelable,
            provenance,
            config,
            seed,
        }
    }

    /// Whether the source labels `class` at all.
    pub fn labels(&self, class: Class) -> bool {
        self.labelable.contains(&class.id())
    }
}

/// A dataset folder read into memory (the files stay on disk).
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    pub root: PathBuf,
    pub card: Card,
    pub items: Vec<Item>,
}

impl Dataset {
    /// Reads `card.json` and `manifest.jsonl` of a dataset folder.
    pub fn open(root: &Path) -> Result<Dataset> {
        if !root.is_dir() {
            return Err(DatasetError::invalid(
                root,
                "is not a dataset folder (expected a folder with manifest.jsonl and card.json)",
            ));
        }
        let card = read_card(&root.join(CARD_FILE))?;
        let items = read_manifest(&root.join(MANIFEST_FILE))?;
        Ok(Dataset {
            root: root.to_path_buf(),
            card,
            items,
        })
    }

    pub fn image_path(&self, item: &Item) -> PathBuf {
        self.root.join(&item.image)
    }

    pub fn label_path(&self, item: &Item) -> PathBuf {
        self.root.join(&item.label)
    }
}

/// Whether an id can name files: ASCII letters, digits, `_`, `-`, `.`, not starting with `.`.
pub fn is_valid_id(id: &str) -> bool {
    !id.is_empty()
        && !id.starts_with('.')
        && id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'-' | b'.'))
}

/// A relative path that stays inside the dataset folder.
fn is_inside(path: &str) -> bool {
    let p = Path::new(path);
    !path.is_empty()
        && p.components()
            .all(|c| matches!(c, Component::Normal(_) | Component::CurDir))
}

/// Checks one item's own fields (`what` names it in the error).
fn check_item(item: &Item) -> std::result::Result<(), String> {
    if !is_valid_id(&item.id) {
        return Err(format!(
            "id `{}` must be ASCII letters, digits, `_`, `-` or `.`",
            item.id
        ));
    }
    for (field, path) in [("image", &item.image), ("label", &item.label)] {
        if !is_inside(path) {
            return Err(format!(
                "{field} `{path}` must be a relative path inside the dataset folder"
            ));
        }
    }
    if item.width == 0 || item.height == 0 {
        return Err(format!("item `{}` has an empty size", item.id));
    }
    Ok(())
}

/// The manifest's text: items sorted by id, one compact JSON object per line.
/// `path` only names the file in errors (duplicate or invalid ids).
pub fn manifest_text(path: &Path, items: &[Item]) -> Result<String> {
    let mut sorted: Vec<&Item> = items.iter().collect();
    sorted.sort_by(|a, b| a.id.cmp(&b.id));
    let mut text = String::new();
    for pair in sorted.windows(2) {
        if pair[0].id == pair[1].id {
            return Err(DatasetError::invalid(
                path,
                format!("duplicate item id `{}`", pair[0].id),
            ));
        }
    }
    for item in sorted {
        check_item(item).map_err(|m| DatasetError::invalid(path, m))?;
        let line = serde_json::to_string(item)
            .map_err(|e| DatasetError::invalid(path, format!("cannot encode item: {e}")))?;
        text.push_str(&line);
        text.push('\n');
    }
    Ok(text)
}

/// Writes `manifest.jsonl` (sorted by id).
pub fn write_manifest(path: &Path, items: &[Item]) -> Result<()> {
    let text = manifest_text(path, items)?;
    crate::image_io::write_bytes(path, text.as_bytes())
}

/// The card's text: pretty JSON, fields in declaration order, trailing newline.
pub fn card_text(card: &Card) -> String {
    // A Card holds only strings, numbers and JSON values: encoding cannot fail.
    let mut text = serde_json::to_string_pretty(card).unwrap_or_default();
    text.push('\n');
    text
}

/// Writes `card.json`.
pub fn write_card(path: &Path, card: &Card) -> Result<()> {
    crate::image_io::write_bytes(path, card_text(card).as_bytes())
}

/// Writes both files of a dataset into `dir` (images and labels are written by the caller).
pub fn write_dataset_files(dir: &Path, card: &Card, items: &[Item]) -> Result<()> {
    write_manifest(&dir.join(MANIFEST_FILE), items)?;
    write_card(&dir.join(CARD_FILE), card)
}

/// Reads a manifest; errors name the file and line. Blank lines are allowed.
pub fn read_manifest(path: &Path) -> Result<Vec<Item>> {
    let text = std::fs::read_to_string(path).map_err(|e| DatasetError::io(path, e))?;
    parse_manifest(path, &text)
}

/// Parses a manifest's text (`path` names it in errors).
pub fn parse_manifest(path: &Path, text: &str) -> Result<Vec<Item>> {
    let mut items = Vec::new();
    let mut ids = HashSet::new();
    for (index, line) in text.lines().enumerate() {
        let line_no = index + 1;
        let at = |message: String| DatasetError::Line {
            path: path.to_path_buf(),
            line: line_no,
            message,
        };
        if line.trim().is_empty() {
            continue;
        }
        let item: Item =
            serde_json::from_str(line).map_err(|e| at(format!("not a manifest item: {e}")))?;
        check_item(&item).map_err(at)?;
        if !ids.insert(item.id.clone()) {
            return Err(at(format!("duplicate item id `{}`", item.id)));
        }
        items.push(item);
    }
    Ok(items)
}

/// Reads and checks a card.
pub fn read_card(path: &Path) -> Result<Card> {
    let text = std::fs::read_to_string(path).map_err(|e| DatasetError::io(path, e))?;
    let card: Card = serde_json::from_str(&text)
        .map_err(|e| DatasetError::invalid(path, format!("not a dataset card: {e}")))?;
    if card.classes != class_table() {
        return Err(DatasetError::invalid(
            path,
            "the card's class table is not 0 road, 1 lane_marking, 2 vehicle, 3 human, 4 other, 255 ignore",
        ));
    }
    if let Some(bad) = card
        .labelable
        .iter()
        .find(|&&id| Class::from_id(id).is_none())
    {
        return Err(DatasetError::invalid(
            path,
            format!("labelable lists {bad}, which is not a class id"),
        ));
    }
    Ok(card)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn items() -> Vec<Item> {
        vec![
            Item::new("b", "test", (4, 3), json!({"z": 1, "a": [1.5, 2]})),
            Item::new("a", "test", (4, 3), json!(null)),
        ]
    }

    #[test]
    fn writer_sorts_and_reader_round_trips() -> Result<()> {
        let dir = tempfile::tempdir().map_err(|e| DatasetError::io(Path::new("tmp"), e))?;
        let card = Card::new("t", &[Class::Other, Class::Road], json!({}), json!({}), 3);
        write_dataset_files(dir.path(), &card, &items())?;
        let text = std::fs::read_to_string(dir.path().join(MANIFEST_FILE))
            .map_err(|e| DatasetError::io(dir.path(), e))?;
        assert!(text.starts_with("{\"id\":\"a\""), "{text}");
        assert!(
            text.contains("\"params\":{\"a\":[1.5,2],\"z\":1}"),
            "{text}"
        );
        let ds = Dataset::open(dir.path())?;
        assert_eq!(ds.card, card);
        assert_eq!(ds.card.labelable, vec![0, 4]);
        assert_eq!(ds.items[1], items()[0]);
        // Same items in another order: same bytes.
        let mut reversed = items();
        reversed.reverse();
        assert_eq!(
            manifest_text(Path::new("m"), &reversed)?,
            manifest_text(Path::new("m"), &items())?
        );
        Ok(())
    }

    #[test]
    fn reader_errors_name_file_and_line() {
        let p = Path::new("d/manifest.jsonl");
        let good = serde_json::to_string(&items()[1]).unwrap_or_default();
        let cases = [
            format!("{good}\n{{\"id\": 3}}\n"),
            format!("{good}\n\n{good}\n"),
            good.replace("images/a.png", "../etc/passwd"),
        ];
        let expected = [
            "d/manifest.jsonl:2:",
            "d/manifest.jsonl:3:",
            "d/manifest.jsonl:1:",
        ];
        for (text, want) in cases.iter().zip(expected) {
            let err = parse_manifest(p, text).err().map(|e| e.to_string());
            assert!(
                err.as_deref().is_some_and(|e| e.starts_with(want)),
                "{err:?} should start with {want}"
            );
        }
        let dup = [items()[0].clone(), items()[0].clone()];
        assert!(manifest_text(p, &dup).is_err());
    }

    #[test]
    fn ids_must_name_files() {
        assert!(is_valid_id("0001TP_006690.aug3"));
        for bad in ["", ".hidden", "a/b", "a b", "ü"] {
            assert!(!is_valid_id(bad), "{bad}");
        }
    }
}
