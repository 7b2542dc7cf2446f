//! Deterministic train / val / test splits.
//!
//! Items are grouped first (by default an augmented copy belongs to the group of its source
//! item, so copies of one picture never land in two splits), each group gets a rank from a
//! hash of (seed, group key), and groups are dealt out in rank order until each split holds
//! its share of the items. The same seed and items always give the same split, and adding
//! items does not move the others' ranks.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::manifest::Item;

/// How items are grouped so that a group stays in one split.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GroupBy {
    /// An augmented item goes with its source item (`params.source_id`); others alone.
    #[default]
    Source,
    /// The id up to its first `_` (CamVid's sequence, e.g. `0016E5`), after grouping by
    /// source: frames of one video stay together.
    Prefix,
    /// Every item alone.
    None,
}

/// Shares of the splits; they must add up to 1.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SplitRatios {
    pub train: f64,
    pub val: f64,
    pub test: f64,
}

impl Default for SplitRatios {
    /// 70 / 30, as the thesis.
    fn default() -> Self {
        SplitRatios {
            train: 0.7,
            val: 0.3,
            test: 0.0,
        }
    }
}

/// Split shares that cannot be used ([`SplitRatios::validate`]): train, val, test.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SplitSharesError {
    #[error("split shares must be within 0..1, not {0:?}")]
    OutsideUnit([f64; 3]),
    #[error("split shares must add up to 1 (train {} + val {} + test {})", .0[0], .0[1], .0[2])]
    Sum([f64; 3]),
}

impl SplitRatios {
    pub fn validate(&self) -> Result<(), SplitSharesError> {
        let all = [self.train, self.val, self.test];
        if all.iter().any(|r| !(0.0..=1.0).contains(r)) {
            return Err(SplitSharesError::OutsideUnit(all));
        }
        if ((self.train + self.val + self.test) - 1.0).abs() > 1e-9 {
            return Err(SplitSharesError::Sum(all));
        }
        Ok(())
    }
}

/// The group key of an item.
pub fn group_key(item: &Item, by: GroupBy) -> String {
    let source = item
        .params
        .get("source_id")
        .and_then(|v| v.as_str())
        .unwrap_or(&item.id);
    match by {
        GroupBy::None => item.id.clone(),
        GroupBy::Source => source.to_owned(),
        GroupBy::Prefix => source.split('_').next().unwrap_or(source).to_owned(),
    }
}

/// The items' indices by group key.
fn groups(items: &[Item], by: GroupBy) -> BTreeMap<String, Vec<usize>> {
    let mut groups: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    for (i, item) in items.iter().enumerate() {
        groups.entry(group_key(item, by)).or_default().push(i);
    }
    groups
}

/// FNV-1a of the seed and a key, finished with splitmix: a stable rank.
fn rank(seed: u64, key: &str) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in seed.to_le_bytes().iter().chain(key.as_bytes()) {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    sim::seed::derive_seed(h, 0, 0)
}

/// Counts per split after [`split_items`].
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SplitCounts {
    pub train: usize,
    pub val: usize,
    pub test: usize,
    pub groups: usize,
}

/// Sets every item's `split`. Groups are dealt in rank order: a group goes to the first
/// split (train, val, test) whose target count it does not overshoot by more than half.
pub fn split_items(
    items: &mut [Item],
    ratios: &SplitRatios,
    seed: u64,
    by: GroupBy,
) -> SplitCounts {
    let groups = groups(items, by);
    let mut ordered: Vec<(u64, &String, &Vec<usize>)> =
        groups.iter().map(|(k, v)| (rank(seed, k), k, v)).collect();
    ordered.sort();
    let n = items.len() as f64;
    let targets = [ratios.train * n, (ratios.train + ratios.val) * n, n];
    let names = ["train", "val", "test"];
    let mut counts = SplitCounts {
        groups: ordered.len(),
        ..SplitCounts::default()
    };
    let mut done = 0usize;
    for (_, _, members) in ordered {
        // The split whose cumulative target this group's middle falls under.
        let middle = done as f64 + members.len() as f64 / 2.0;
        let which = targets.iter().position(|&t| middle <= t).unwrap_or(2);
        for &i in members {
            items[i].split = Some(names[which].to_owned());
        }
        match which {
            0 => counts.train += members.len(),
            1 => counts.val += members.len(),
            _ => counts.test += members.len(),
        }
        done += members.len();
    }
    counts
}

/// Groups named wrongly ([`assign_groups`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum GroupsError {
    #[error("group `{0}` is named for both val and test")]
    Both(String),
    #[error("no item is in group `{group}` (groups: {}{})", known.join(", "), if *more { ", ..." } else { "" })]
    Missing {
        group: String,
        /// The first groups the items have.
        known: Vec<String>,
        /// There are more groups than `known` lists.
        more: bool,
    },
}

/// Sets every item's `split` by naming groups: the groups in `val` go to validation, those
/// in `test` to test, every other group to training (CamVid's sequences, for a protocol
/// that never scores on a sequence seen in training). Errors name a group that no item
/// has, or one named twice.
pub fn assign_groups(
    items: &mut [Item],
    by: GroupBy,
    val: &[String],
    test: &[String],
) -> Result<SplitCounts, GroupsError> {
    if let Some(both) = val.iter().find(|g| test.contains(g)) {
        return Err(GroupsError::Both(both.clone()));
    }
    let groups = groups(items, by);
    if let Some(missing) = val.iter().chain(test).find(|g| !groups.contains_key(*g)) {
        return Err(GroupsError::Missing {
            group: missing.clone(),
            known: groups.keys().take(12).cloned().collect(),
            more: groups.len() > 12,
        });
    }
    let mut counts = SplitCounts {
        groups: groups.len(),
        ..SplitCounts::default()
    };
    for (key, members) in &groups {
        let name = if val.contains(key) {
            counts.val += members.len();
            "val"
        } else if test.contains(key) {
            counts.test += members.len();
            "test"
        } else {
            counts.train += members.len();
            "train"
        };
        for &i in members {
            items[i].split = Some(name.to_owned());
        }
    }
    Ok(counts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn items(n: usize) -> Vec<Item> {
        (0..n)
            .map(|i| Item::new(format!("seq{}_{i:04}", i % 3), "t", (2, 2), json!(null)))
            .collect()
    }

    #[test]
    fn seventy_thirty_and_deterministic() {
        let mut a = items(1000);
        let counts = split_items(&mut a, &SplitRatios::default(), 1, GroupBy::Source);
        assert_eq!((counts.train, counts.val, counts.test), (700, 300, 0));
        let mut b = items(1000);
        split_items(&mut b, &SplitRatios::default(), 1, GroupBy::Source);
        assert_eq!(a, b);
        let mut c = items(1000);
        split_items(&mut c, &SplitRatios::default(), 2, GroupBy::Source);
        assert_ne!(a, c);
    }

    #[test]
    fn groups_stay_together() {
        let mut v = items(30);
        for (i, item) in v.iter_mut().enumerate() {
            item.params = json!({ "source_id": format!("src{}", i / 5) });
        }
        split_items(&mut v, &SplitRatios::default(), 0, GroupBy::Source);
        for chunk in v.chunks(5) {
            assert!(chunk.iter().all(|i| i.split == chunk[0].split));
        }
        let mut p = items(30);
        let counts = split_items(&mut p, &SplitRatios::default(), 0, GroupBy::Prefix);
        assert_eq!(counts.groups, 3);
    }

    #[test]
    fn named_groups_go_where_they_are_named() {
        let mut v = items(30);
        let counts = assign_groups(&mut v, GroupBy::Prefix, &["seq1".into()], &["seq2".into()])
            .expect("both groups exist");
        assert_eq!((counts.train, counts.val, counts.test), (10, 10, 10));
        for item in &v {
            let expected = if item.id.starts_with("seq1_") {
                "val"
            } else if item.id.starts_with("seq2_") {
                "test"
            } else {
                "train"
            };
            assert_eq!(item.split.as_deref(), Some(expected), "{}", item.id);
        }
        let err = assign_groups(&mut v, GroupBy::Prefix, &["seq9".into()], &[])
            .expect_err("no item is in seq9");
        let err = err.to_string();
        assert!(err.contains("seq9") && err.contains("seq0"), "{err}");
        assert!(
            assign_groups(&mut v, GroupBy::Prefix, &["seq1".into()], &["seq1".into()]).is_err()
        );
    }

    #[test]
    fn ratios_are_checked() {
        assert!(
            SplitRatios {
                train: 0.5,
                val: 0.3,
                test: 0.1
            }
            .validate()
            .is_err()
        );
        assert!(
            SplitRatios {
                train: 0.8,
                val: 0.1,
                test: 0.1
            }
            .validate()
            .is_ok()
        );
    }
}
