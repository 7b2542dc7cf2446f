//! Merging datasets with sampling weights.
//!
//! The merged set holds `total` items (default: all items of all inputs). Input `i` gets
//! `total · wᵢ / Σw` of them (largest-remainder rounding). Within an input, items are taken
//! in a seeded random order; when an input must give more items than it has, it gives all
//! of them as often as needed (repeats get `.r<k>` ids), so a small set can be up-weighted.
//!
//! Ids become `<input name>.<id>`. Each item's `params` records its dataset, source id and
//! the classes its source can label; the card's `labelable` is the classes *every* input
//! labels, so a loss masked by the card is right for every item, and a loss masked per item
//! can use `params.labelable`.

use std::path::Path;

use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::classes::Class;
use crate::error::{DatasetError, Result};
use crate::manifest::{Card, Dataset, Item, write_dataset_files};

/// Seed-derivation stage of merging.
const STAGE: u64 = u64::from_le_bytes(*b"merge\0\0\0");

/// How many items each input gives.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct MergePlan {
    pub counts: Vec<usize>,
}

/// Weights that give no merge plan ([`plan`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MergePlanError {
    #[error("nothing to merge")]
    Nothing,
    #[error("weights must be finite and not negative: {0:?}")]
    Weights(Vec<f64>),
    #[error("at least one weight must be positive")]
    NoPositiveWeight,
}

/// Shares of `total` by weight, largest remainders first (ties to the earlier input).
pub fn plan(weights: &[f64], total: usize) -> std::result::Result<MergePlan, MergePlanError> {
    if weights.is_empty() {
        return Err(MergePlanError::Nothing);
    }
    if weights.iter().any(|w| !w.is_finite() || *w < 0.0) {
        return Err(MergePlanError::Weights(weights.to_vec()));
    }
    let sum: f64 = weights.iter().sum();
    if sum <= 0.0 {
        return Err(MergePlanError::NoPositiveWeight);
    }
    let exact: Vec<f64> = weights.iter().map(|w| total as f64 * w / sum).collect();
    let mut counts: Vec<usize> = exact.iter().map(|e| e.floor() as usize).collect();
    let mut order: Vec<usize> = (0..weights.len()).collect();
    order.sort_by(|&a, &b| {
        let (ra, rb) = (exact[a] - exact[a].floor(), exact[b] - exact[b].floor());
        rb.total_cmp(&ra).then(a.cmp(&b))
    });
    let missing = total - counts.iter().sum::<usize>();
    for &i in order.iter().take(missing) {
        counts[i] += 1;
    }
    Ok(MergePlan { counts })
}

/// A name usable as an id prefix.
fn prefix(name: &str, index: usize, all: &[&Dataset]) -> String {
    let clean = crate::import::layout::sanitize_id(name);
    let clash = all
        .iter()
        .filter(|d| crate::import::layout::sanitize_id(&d.card.name) == clean)
        .count()
        > 1;
    if clean.is_empty() || clash {
        format!("d{index}")
    } else {
        clean
    }
}

/// Links (or copies) a file into the output.
fn place(from: &Path, to: &Path) -> Result<()> {
    if let Some(parent) = to.parent() {
        std::fs::create_dir_all(parent).map_err(|e| DatasetError::io(parent, e))?;
    }
    if std::fs::hard_link(from, to).is_ok() {
        return Ok(());
    }
    std::fs::copy(from, to)
        .map(|_| ())
        .map_err(|e| DatasetError::io(from, e))
}

/// Merges `inputs` with `weights` into `out_dir` (which must exist).
pub fn merge(
    name: &str,
    inputs: &[&Dataset],
    weights: &[f64],
    total: Option<usize>,
    seed: u64,
    out_dir: &Path,
) -> Result<(Vec<Item>, Card)> {
    if weights.len() != inputs.len() {
        return Err(DatasetError::Config(format!(
            "{} weights for {} datasets",
            weights.len(),
            inputs.len()
        )));
    }
    let total = total.unwrap_or_else(|| inputs.iter().map(|d| d.items.len()).sum());
    let plan = plan(weights, total).map_err(|e| DatasetError::Config(e.to_string()))?;
    let mut items = Vec::with_capacity(total);
    for (index, (dataset, &count)) in inputs.iter().zip(&plan.counts).enumerate() {
        if count > 0 && dataset.items.is_empty() {
            return Err(DatasetError::invalid(
                &dataset.root,
                "has no items to merge",
            ));
        }
        let pre = prefix(&dataset.card.name, index, inputs);
        let mut order: Vec<usize> = (0..dataset.items.len()).collect();
        order.shuffle(&mut ChaCha8Rng::seed_from_u64(sim::seed::derive_seed(
            seed,
            STAGE,
            index as u64,
        )));
        for k in 0..count {
            let source = &dataset.items[order[k % order.len()]];
            let round = k / order.len();
            let id = if round == 0 {
                format!("{pre}.{}", source.id)
            } else {
                format!("{pre}.{}.r{round}", source.id)
            };
            let ext = |p: &str| {
                Path::new(p)
                    .extension()
                    .map(|e| e.to_string_lossy().into_owned())
                    .unwrap_or_else(|| "png".into())
            };
            let mut item = Item::new(
                id,
                source.source.clone(),
                (source.width, source.height),
                serde_json::json!({
                    "dataset": dataset.card.name,
                    "source_id": source.id,
                    "labelable": dataset.card.labelable,
                    "source_params": source.params,
                }),
            );
            item.image = format!(
                "{}/{}.{}",
                crate::manifest::IMAGES_DIR,
                item.id,
                ext(&source.image)
            );
            item.split.clone_from(&source.split);
            place(&dataset.image_path(source), &out_dir.join(&item.image))?;
            place(&dataset.label_path(source), &out_dir.join(&item.label))?;
            items.push(item);
        }
    }
    let labelable: Vec<Class> = Class::ALL
        .into_iter()
        .filter(|c| inputs.iter().all(|d| d.card.labels(*c)))
        .collect();
    let card = Card::new(
        name,
        &labelable,
        serde_json::json!({
            "tool": "pipeline dataset merge",
            "version": env!("CARGO_PKG_VERSION"),
            "inputs": inputs.iter().map(|d| serde_json::json!({
                "name": d.card.name,
                "path": d.root.display().to_string(),
                "items": d.items.len(),
                "labelable": d.card.labelable,
            })).collect::<Vec<_>>(),
        }),
        serde_json::json!({ "weights": weights, "total": total, "counts": plan.counts }),
        seed,
    );
    write_dataset_files(out_dir, &card, &items)?;
    Ok((items, card))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_follows_the_weights() -> std::result::Result<(), MergePlanError> {
        assert_eq!(plan(&[1.0, 1.0], 10)?.counts, vec![5, 5]);
        assert_eq!(plan(&[2.0, 1.0], 10)?.counts, vec![7, 3]);
        assert_eq!(plan(&[1.0, 1.0, 1.0], 10)?.counts, vec![4, 3, 3]);
        assert_eq!(plan(&[0.0, 3.0], 4)?.counts, vec![0, 4]);
        assert!(plan(&[-1.0], 3).is_err());
        assert!(plan(&[0.0], 3).is_err());
        Ok(())
    }
}
