//! `dataset check`: finds what would make a dataset silently wrong.
//!
//! - unreadable or missing images and labels, labels that are not single-channel;
//! - sizes that disagree (label vs image vs manifest);
//! - label values outside the class table (unknown ids), with their pixel counts;
//! - empty labels (no pixel of any class: all ignore);
//! - classes present that the item's source cannot label (the card's `labelable`, or a
//!   merged item's own, from its input);
//! - duplicates: items whose image pixels are identical (SHA-256 of the decoded RGB);
//! - split leakage: one picture (by content) or one source group in two splits.

use std::collections::BTreeMap;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::classes::{Class, IGNORE, is_valid_label};
use crate::error::DatasetError;
use crate::image_io::{read_label, read_rgb};
use crate::manifest::{Dataset, Item};
use crate::split::{GroupBy, group_key};
use crate::stats::LabelHistogram;

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ProblemKind {
    Unreadable,
    SizeMismatch,
    UnknownIds,
    EmptyLabel,
    UnlabelableClass,
    Duplicate,
    SplitLeak,
}

#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Problem {
    pub kind: ProblemKind,
    pub id: String,
    pub message: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CheckReport {
    pub items: usize,
    pub problems: Vec<Problem>,
    /// Problems per kind.
    pub counts: BTreeMap<String, usize>,
}

impl CheckReport {
    pub fn is_clean(&self) -> bool {
        self.problems.is_empty()
    }
}

/// What one item's files say.
struct ItemFacts {
    problems: Vec<Problem>,
    image_hash: Option<[u8; 32]>,
}

fn problem(kind: ProblemKind, item: &Item, message: impl Into<String>) -> Problem {
    Problem {
        kind,
        id: item.id.clone(),
        message: message.into(),
    }
}

fn inspect(dataset: &Dataset, item: &Item) -> ItemFacts {
    let mut problems = Vec::new();
    let image_path = dataset.image_path(item);
    let label_path = dataset.label_path(item);
    let image = match read_rgb(&image_path) {
        Ok(i) => Some(i),
        Err(e) => {
            problems.push(problem(ProblemKind::Unreadable, item, e.to_string()));
            None
        }
    };
    let label = match read_label(&label_path) {
        Ok(l) => Some(l),
        Err(e) => {
            problems.push(problem(ProblemKind::Unreadable, item, e.to_string()));
            None
        }
    };
    if let Some(img) = &image
        && img.dimensions() != (item.width, item.height)
    {
        let e = DatasetError::invalid(
            &image_path,
            format!(
                "image is {}x{}, the manifest says {}x{}",
                img.width(),
                img.height(),
                item.width,
                item.height
            ),
        );
        problems.push(problem(ProblemKind::SizeMismatch, item, e.to_string()));
    }
    if let Some(lab) = &label {
        if lab.dimensions() != (item.width, item.height) {
            let e = DatasetError::invalid(
                &label_path,
                format!(
                    "label is {}x{}, the manifest says {}x{}",
                    lab.width(),
                    lab.height(),
                    item.width,
                    item.height
                ),
            );
            problems.push(problem(ProblemKind::SizeMismatch, item, e.to_string()));
        }
        let hist = LabelHistogram::of(lab);
        let unknown: Vec<String> = (0..=255u8)
            .filter(|&v| !is_valid_label(v) && hist.count(v) > 0)
            .map(|v| format!("{v} ({} px)", hist.count(v)))
            .collect();
        if !unknown.is_empty() {
            let e = DatasetError::invalid(
                &label_path,
                format!("values outside the class table: {}", unknown.join(", ")),
            );
            problems.push(problem(ProblemKind::UnknownIds, item, e.to_string()));
        }
        if hist.count(IGNORE) == hist.total() {
            let e = DatasetError::invalid(&label_path, "label is empty (every pixel is ignore)");
            problems.push(problem(ProblemKind::EmptyLabel, item, e.to_string()));
        }
        let labelable = item_labelable(dataset, item);
        let unlabelable: Vec<&str> = Class::ALL
            .iter()
            .filter(|c| hist.count(c.id()) > 0 && !labelable.contains(&c.id()))
            .map(|c| c.name())
            .collect();
        if !unlabelable.is_empty() {
            let e = DatasetError::invalid(
                &label_path,
                format!(
                    "has {} pixels, which the card says this source cannot label",
                    unlabelable.join(", ")
                ),
            );
            problems.push(problem(ProblemKind::UnlabelableClass, item, e.to_string()));
        }
    }
    let image_hash = image.map(|img| {
        let mut h = Sha256::new();
        h.update(img.width().to_le_bytes());
        h.update(img.height().to_le_bytes());
        h.update(img.as_raw());
        h.finalize().into()
    });
    ItemFacts {
        problems,
        image_hash,
    }
}

/// The class ids an item's source can label: the item's own `params.labelable` when it has
/// one (a merge keeps each input's there, while the card lists only the classes every input
/// labels), else the card's.
pub fn item_labelable(dataset: &Dataset, item: &Item) -> Vec<u8> {
    item.params
        .get("labelable")
        .and_then(serde_json::Value::as_array)
        .map(|ids| {
            ids.iter()
                .filter_map(|v| v.as_u64().and_then(|id| u8::try_from(id).ok()))
                .collect()
        })
        .unwrap_or_else(|| dataset.card.labelable.clone())
}

/// Checks every item (in parallel) and the dataset as a whole.
pub fn check_dataset(dataset: &Dataset) -> CheckReport {
    check_dataset_with_progress(dataset, &|| {})
}

/// [`check_dataset`], calling `item_done` after each item (from the worker threads).
pub fn check_dataset_with_progress(
    dataset: &Dataset,
    item_done: &(dyn Fn() + Sync),
) -> CheckReport {
    let facts: Vec<ItemFacts> = dataset
        .items
        .par_iter()
        .map(|item| {
            let facts = inspect(dataset, item);
            item_done();
            facts
        })
        .collect();
    let mut problems: Vec<Problem> = facts.iter().flat_map(|f| f.problems.clone()).collect();

    // Duplicates and content leaking across splits.
    let mut by_hash: BTreeMap<[u8; 32], Vec<&Item>> = BTreeMap::new();
    for (item, f) in dataset.items.iter().zip(&facts) {
        if let Some(h) = f.image_hash {
            by_hash.entry(h).or_default().push(item);
        }
    }
    for same in by_hash.values().filter(|v| v.len() > 1) {
        let ids: Vec<&str> = same.iter().map(|i| i.id.as_str()).collect();
        for item in &same[1..] {
            problems.push(problem(
                ProblemKind::Duplicate,
                item,
                format!("same image pixels as {}", ids[0]),
            ));
        }
        let splits: std::collections::BTreeSet<&str> =
            same.iter().filter_map(|i| i.split.as_deref()).collect();
        if splits.len() > 1 {
            problems.push(problem(
                ProblemKind::SplitLeak,
                same[0],
                format!(
                    "the same image is in splits {} ({})",
                    splits.into_iter().collect::<Vec<_>>().join(" and "),
                    ids.join(", ")
                ),
            ));
        }
    }
    // Source groups (an item and its augmented copies) across splits.
    let mut groups: BTreeMap<String, Vec<&Item>> = BTreeMap::new();
    for item in &dataset.items {
        groups
            .entry(group_key(item, GroupBy::Source))
            .or_default()
            .push(item);
    }
    for (key, members) in &groups {
        let splits: std::collections::BTreeSet<&str> =
            members.iter().filter_map(|i| i.split.as_deref()).collect();
        if splits.len() > 1 {
            problems.push(problem(
                ProblemKind::SplitLeak,
                members[0],
                format!(
                    "copies of source item {key} are in splits {}",
                    splits.into_iter().collect::<Vec<_>>().join(" and ")
                ),
            ));
        }
    }
    problems.sort_by(|a, b| (a.kind, &a.id, &a.message).cmp(&(b.kind, &b.id, &b.message)));
    let mut counts = BTreeMap::new();
    for p in &problems {
        let name = serde_json::to_value(p.kind)
            .ok()
            .and_then(|v| v.as_str().map(str::to_owned))
            .unwrap_or_default();
        *counts.entry(name).or_insert(0) += 1;
    }
    CheckReport {
        items: dataset.items.len(),
        problems,
        counts,
    }
}
