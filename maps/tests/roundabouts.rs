//! Every roundabout of the real extracts in `../shared/data/osm/roundabouts/` (Andorra,
//! Campo Grande, Krems) against `reference/roundabouts_from_tags.json`, the rings and
//! mini-roundabout nodes counted from the tags by a separate script. Skips with a notice
//! when the folder is absent.
#![allow(clippy::unwrap_used, clippy::print_stderr)]

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use maps::summary::summarize;
use maps::{ImportOptions, RoundaboutKind, RoundaboutSource, import_file};

fn roundabouts_dir() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/osm/roundabouts");
    if p.join("reference/roundabouts_from_tags.json").exists() {
        Some(p)
    } else {
        eprintln!(
            "skipped: {}: {} not found",
            std::thread::current().name().unwrap_or("-"),
            p.display()
        );
        None
    }
}

fn ids(v: &serde_json::Value) -> Vec<i64> {
    let mut out: Vec<i64> = v
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|x| {
                    x.as_i64()
                        .or_else(|| x.as_str().and_then(|s| s.parse().ok()))
                })
                .collect()
        })
        .unwrap_or_default();
    out.sort_unstable();
    out
}

/// Per file: closed and complete tagged rings are found with the reference's ways, entries
/// and exits; the other tagged rings are listed with a reason; mini-roundabouts are found
/// node for node; guessed rings are flagged and share no way with a tagged one.
#[test]
fn every_tagged_ring_and_mini_roundabout_of_the_real_extracts() {
    let Some(dir) = roundabouts_dir() else { return };
    let reference: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("reference/roundabouts_from_tags.json")).unwrap(),
    )
    .unwrap();
    let files = reference["files"].as_object().unwrap();
    assert_eq!(files.len(), 3);
    for (file, entry) in files {
        let map = import_file(&dir.join(file), &ImportOptions::default())
            .unwrap_or_else(|e| panic!("{file}: {e}"));
        let summary = summarize(&map);
        let dropped: BTreeSet<i64> = map.report.ways_missing_nodes.iter().copied().collect();
        let rings = entry["rings"].as_array().unwrap();
        let (mut found, mut listed, mut imported_broken) = (0, 0, 0);
        for ring in rings {
            let ways = ids(&ring["osm_way_ids"]);
            let complete =
                ring["closed"].as_bool() == Some(true) && ways.iter().all(|w| !dropped.contains(w));
            let ours = map
                .roundabouts
                .values()
                .find(|r| r.source == RoundaboutSource::Tagged && r.osm_way_ids == ways);
            if !complete {
                // Listed with a reason; imported only as far as its lanes still make a ring
                // (a way ending inside another, say), and then listed as imported.
                let problem = map
                    .report
                    .ring_problems
                    .iter()
                    .find(|p| p.osm_way_ids == ways)
                    .unwrap_or_else(|| panic!("{file}: broken ring {ways:?} not listed"));
                assert!(!problem.reason.is_empty());
                assert_eq!(problem.imported, ours.is_some(), "{file}: {problem:?}");
                eprintln!("{file}: ring {ways:?} listed: {}", problem.reason);
                listed += 1;
                imported_broken += usize::from(ours.is_some());
                continue;
            }
            let ours = ours.unwrap_or_else(|| panic!("{file}: ring {ways:?} not found"));
            // The reference counts an arm on every highway way touching the ring, from its
            // ring node alone. The importer leaves out whole ways with nodes missing from
            // the extract (they are in `ways_missing_nodes`), so such arms cannot be found:
            // they are taken off the reference's counts. Otherwise arms are counted alike:
            // one per road and direction of travel at a ring node, a way through a ring node
            // giving two roads there.
            let (mut entries, mut exits) = (0, 0);
            for arm in ring["arms"].as_array().unwrap() {
                let way = arm["way_id"].as_i64().unwrap();
                if arm["car"].as_bool() != Some(true) || dropped.contains(&way) {
                    continue;
                }
                entries += usize::from(arm["entry"].as_bool() == Some(true));
                exits += usize::from(arm["exit"].as_bool() == Some(true));
            }
            assert_eq!(
                (ours.entries.len(), ours.exits.len()),
                (entries, exits),
                "{file}: ring {ways:?} entries / exits"
            );
            let kind = if ring["junction"].as_str() == Some("circular") {
                RoundaboutKind::Circular
            } else {
                RoundaboutKind::Roundabout
            };
            assert_eq!(ours.kind, kind, "{file}: ring {ways:?} kind");
            assert!(ours.lanes_across >= 1);
            found += 1;
        }
        // No tagged roundabout beyond the reference's rings.
        let tagged = map
            .roundabouts
            .values()
            .filter(|r| {
                r.source == RoundaboutSource::Tagged && r.kind != RoundaboutKind::MiniRoundabout
            })
            .count();
        assert_eq!(
            tagged,
            found + imported_broken,
            "{file}: tagged roundabouts"
        );
        // Guessed rings are flagged and made of untagged ways only.
        let tagged_ways: BTreeSet<i64> =
            rings.iter().flat_map(|r| ids(&r["osm_way_ids"])).collect();
        let mut guessed = 0;
        for r in &summary.roundabouts {
            if r.source == RoundaboutSource::Guessed {
                assert!(r.guessed && r.kind == RoundaboutKind::Roundabout, "{file}");
                assert!(
                    r.osm_way_ids.iter().all(|w| !tagged_ways.contains(w)),
                    "{file}: guessed ring {:?} uses a tagged way",
                    r.osm_way_ids
                );
                guessed += 1;
            } else {
                assert!(!r.guessed, "{file}");
            }
        }
        // Mini-roundabouts node for node.
        let minis: Vec<i64> = summary
            .roundabouts
            .iter()
            .filter(|r| r.kind == RoundaboutKind::MiniRoundabout)
            .filter_map(|r| r.osm_node_id)
            .collect();
        let listed_minis: Vec<i64> = map
            .report
            .ring_problems
            .iter()
            .filter_map(|p| p.osm_node_id)
            .collect();
        let mut all_minis: Vec<i64> = minis.iter().chain(&listed_minis).copied().collect();
        all_minis.sort_unstable();
        assert_eq!(
            all_minis,
            ids(&entry["mini_roundabout_node_ids"]),
            "{file}: mini-roundabout nodes"
        );
        for r in summary
            .roundabouts
            .iter()
            .filter(|r| r.kind == RoundaboutKind::MiniRoundabout)
        {
            assert!(
                r.entries > 0 && r.exits > 0,
                "{file}: mini-roundabout {r:?}"
            );
        }
        eprintln!(
            "{file}: tagged rings {} in the reference, {found} closed and complete found, {listed} others listed with a reason ({imported_broken} of them still imported); {guessed} guessed; mini-roundabouts {} found, {} listed, {} in the reference",
            rings.len(),
            minis.len(),
            listed_minis.len(),
            ids(&entry["mini_roundabout_node_ids"]).len()
        );
        assert_eq!(found + listed, rings.len(), "{file}");
    }
}

/// The two-lane rings of Andorra (primary roads without a `lanes` tag) are roundabouts whose
/// ring lanes are strongly connected, entered and left lane-level.
#[test]
fn two_lane_rings_are_roundabouts() {
    let Some(dir) = roundabouts_dir() else { return };
    let map = import_file(&dir.join("andorra.osm.pbf"), &ImportOptions::default()).unwrap();
    let two_lane: Vec<_> = map
        .roundabouts
        .values()
        .filter(|r| r.source == RoundaboutSource::Tagged && r.lanes_across == 2)
        .collect();
    assert!(two_lane.len() >= 15, "{} two-lane rings", two_lane.len());
    for r in two_lane {
        assert_eq!(r.ring_lanes.len(), 2 * r.roads.len());
        assert_eq!(r.yield_lines.len(), r.entries.len());
    }
}
