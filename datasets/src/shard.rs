//! Sharding a data-parallel stage across machines: shard `i` of `n` makes the items of
//! index `[i·N/n, (i+1)·N/n)` of an `N`-item run (every item is seeded by its own index, so
//! it is the same item whichever shard makes it) and records that in its card; merging the
//! `n` shards puts their items back in index order and drops the shard record, so the
//! merged folder is byte for byte the folder an unsharded run writes.

use std::ops::Range;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{DatasetError, Result};
use crate::manifest::{CARD_FILE, Card, Dataset, Item, PREVIEWS_DIR, write_dataset_files};

/// Key of the shard record in a card's `config`.
pub const SHARD_KEY: &str = "shard";

/// Shard `index` of `count`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    pub index: u64,
    pub count: u64,
}

/// Text that is not a shard `i/n` ([`Shard::parse`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("expected i/n with 0 <= i < n (e.g. 0/4), not `{0}`")]
pub struct ShardParseError(pub String);

impl Shard {
    /// Parses `i/n` (0 ≤ i < n).
    pub fn parse(s: &str) -> std::result::Result<Shard, ShardParseError> {
        let bad = || ShardParseError(s.to_owned());
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let index: u64 = i.trim().parse().map_err(|_| bad())?;
        let count: u64 = n.trim().parse().map_err(|_| bad())?;
        if count == 0 || index >= count {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }

    /// The item indices of this shard in a run of `total` items.
    pub fn range(&self, total: u64) -> Range<u64> {
        let bound = |i: u64| (u128::from(total) * u128::from(i) / u128::from(self.count)) as u64;
        bound(self.index)..bound(self.index + 1)
    }
}

/// The shard record of a card's `config` (or of any JSON object), if it has one.
pub fn shard_record(config: &serde_json::Value) -> Option<Shard> {
    config
        .get(SHARD_KEY)
        .cloned()
        .and_then(|v| serde_json::from_value::<Shard>(v).ok())
}

/// `value` (a JSON object) without its shard record.
pub fn without_shard(value: &serde_json::Value) -> serde_json::Value {
    let mut value = value.clone();
    if let Some(object) = value.as_object_mut() {
        object.remove(SHARD_KEY);
    }
    value
}

/// The shards of one run in index order: each of `0..n` must be there exactly once, all
/// of the same `n`, any order in.
pub fn in_order<T>(shards: Vec<(Shard, T)>) -> Result<Vec<(Shard, T)>> {
    let mut ordered = shards;
    ordered.sort_by_key(|(s, _)| s.index);
    let count = ordered.first().map_or(0, |(s, _)| s.count);
    let indices: Vec<u64> = ordered.iter().map(|(s, _)| s.index).collect();
    if ordered.is_empty()
        || ordered.iter().any(|(s, _)| s.count != count)
        || indices != (0..count).collect::<Vec<_>>()
    {
        return Err(DatasetError::Config(format!(
            "the shards given are {:?}; merging needs each of 0..{count} of one run exactly once",
            ordered
                .iter()
                .map(|(s, _)| format!("{}/{}", s.index, s.count))
                .collect::<Vec<_>>()
        )));
    }
    Ok(ordered)
}

/// Key of the card's `provenance` list that each shard makes on its own (the items an
/// `--on-error skip` run left out): merging puts the shards' lists one after the other.
pub const PER_SHARD_LIST: &str = "skipped";

/// Merges the shards of one run (any order given) into `out_dir` under the card name
/// `name`: the shards must all be there once, from the same run (card equal but for the
/// shard record and the `provenance.skipped` list). Copies each item's files (image,
/// label, and the `params.topdown` and `previews/<id>.png` files when present) and writes
/// the manifest and card. Used for `dataset generate` and `dataset augment` shards.
pub fn merge_shards(name: &str, shards: &[&Dataset], out_dir: &Path) -> Result<(Vec<Item>, Card)> {
    let mut found: Vec<(Shard, &Dataset)> = Vec::new();
    for d in shards {
        let shard = shard_record(&d.card.config).ok_or_else(|| {
            DatasetError::invalid(
                &d.root.join(CARD_FILE),
                "is not a shard (no `shard` in its config; made without --shard?)",
            )
        })?;
        found.push((shard, d));
    }
    let ordered = in_order(found)?;
    // The card of the unsharded run, the name and the per-shard list aside.
    let unsharded = |card: &Card| {
        let mut card = card.clone();
        card.config = without_shard(&card.config);
        if let Some(provenance) = card.provenance.as_object_mut() {
            provenance.remove(PER_SHARD_LIST);
        }
        card.name.clear();
        card
    };
    let first = unsharded(&ordered[0].1.card);
    for (shard, d) in &ordered[1..] {
        if unsharded(&d.card) != first {
            return Err(DatasetError::invalid(
                &d.root.join(CARD_FILE),
                format!(
                    "shard {}/{} was made with other settings than shard 0 (its card differs)",
                    shard.index, shard.count
                ),
            ));
        }
    }

    let mut items = Vec::new();
    let mut listed: Option<Vec<serde_json::Value>> = None;
    for (_, d) in &ordered {
        if let Some(list) = d
            .card
            .provenance
            .get(PER_SHARD_LIST)
            .and_then(|v| v.as_array())
        {
            listed
                .get_or_insert_with(Vec::new)
                .extend(list.iter().cloned());
        }
        for item in &d.items {
            let mut files = vec![item.image.clone(), item.label.clone()];
            if let Some(top) = item.params.get("topdown").and_then(|v| v.as_str()) {
                files.push(top.to_owned());
            }
            let preview = format!("{PREVIEWS_DIR}/{}.png", item.id);
            if d.root.join(&preview).is_file() {
                files.push(preview);
            }
            for rel in files {
                let to = out_dir.join(&rel);
                if let Some(parent) = to.parent() {
                    std::fs::create_dir_all(parent).map_err(|e| DatasetError::io(parent, e))?;
                }
                std::fs::copy(d.root.join(&rel), &to)
                    .map_err(|e| DatasetError::io(&d.root.join(&rel), e))?;
            }
            items.push(item.clone());
        }
    }
    let mut card = first;
    card.name = name.to_owned();
    if let (Some(list), Some(provenance)) = (listed, card.provenance.as_object_mut()) {
        provenance.insert(PER_SHARD_LIST.to_owned(), serde_json::Value::Array(list));
    }
    write_dataset_files(out_dir, &card, &items)?;
    Ok((items, card))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_parse_and_cover_every_index_once() {
        assert_eq!(Shard::parse("1/4"), Ok(Shard { index: 1, count: 4 }));
        for bad in ["4/4", "1/0", "a/2", "1", "-1/2"] {
            assert!(Shard::parse(bad).is_err(), "{bad}");
        }
        for (total, count) in [(0u64, 3u64), (7, 3), (100, 7), (5, 8)] {
            let mut next = 0;
            for index in 0..count {
                let r = Shard { index, count }.range(total);
                assert_eq!(r.start, next);
                next = r.end;
            }
            assert_eq!(next, total);
        }
    }

    #[test]
    fn shards_are_put_in_order_and_must_all_be_there_once() {
        let s = |index, count| Shard { index, count };
        let ordered = in_order(vec![(s(2, 3), 'c'), (s(0, 3), 'a'), (s(1, 3), 'b')]);
        assert_eq!(
            ordered
                .ok()
                .map(|v| v.into_iter().map(|(_, c)| c).collect::<String>()),
            Some("abc".to_owned())
        );
        for bad in [
            vec![(s(0, 3), 'a'), (s(1, 3), 'b')],
            vec![(s(0, 2), 'a'), (s(0, 2), 'b')],
            vec![(s(0, 2), 'a'), (s(1, 3), 'b')],
            vec![],
        ] {
            assert!(
                in_order(bad.clone()).is_err_and(|e| e.to_string().contains("exactly once")),
                "{bad:?}"
            );
        }
        let record = serde_json::json!({"count": 9, "shard": {"index": 1, "count": 2}});
        assert_eq!(shard_record(&record), Some(s(1, 2)));
        assert_eq!(without_shard(&record), serde_json::json!({"count": 9}));
        assert_eq!(shard_record(&without_shard(&record)), None);
    }
}
