//! Importing CamVid val through the shipped class map keeps the
//! original pixel shares in the mapped classes.
//!
//! The reference is `class_shares.json` beside the data (numpy bincount over every label
//! pixel): every target class must get exactly the pixels of the source classes mapped to
//! it, and the quoted shares (Road 28.95 %, Car 1.75 %, Pedestrian 0.65 %) must come out.
//!
//! Skips with a printed notice when `../shared/data` is absent.

#![allow(clippy::print_stdout, clippy::unwrap_used)]

mod common;

use std::collections::BTreeMap;
use std::path::PathBuf;

use datasets::error::OnError;
use datasets::import::{ClassMap, ImportOptions, LayoutOptions, SourceFormat, import};

fn camvid_dir() -> Option<PathBuf> {
    common::shared_data("segmentation/camvid")
}

#[test]
fn camvid_val_keeps_its_pixel_shares_in_our_classes() {
    let Some(root) = camvid_dir() else { return };
    let reference: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(root.join("class_shares.json")).unwrap())
            .unwrap();
    let val = &reference["splits"]["val"];
    let source_counts: BTreeMap<String, u64> = val["pixel_counts"]
        .as_object()
        .unwrap()
        .iter()
        .map(|(name, n)| (name.clone(), n.as_u64().unwrap()))
        .collect();

    let class_map = ClassMap::load("camvid").unwrap();
    let options = ImportOptions {
        name: "camvid".into(),
        format: SourceFormat::Camvid,
        layout: LayoutOptions {
            root: root.clone(),
            splits: vec!["val".into()],
            images: None,
            labels: None,
            variant: None,
        },
        class_map: class_map.clone(),
        source_config: None,
        lane_masks: None,
        on_error: OnError::Fail,
    };
    let out = tempfile::tempdir().unwrap();
    let outcome = import(&options, out.path()).unwrap();
    let report = &outcome.report;
    assert_eq!(report.items, 101);
    assert!(report.skipped.is_empty());
    assert_eq!(report.pixels, val["pixels"].as_u64().unwrap());

    // Each source class keeps its exact pixel count.
    for class in &report.source_classes {
        assert_eq!(
            Some(&class.pixels),
            source_counts.get(&class.name),
            "source class {}",
            class.name
        );
    }
    // Each target class gets exactly the pixels of the source classes mapped to it.
    let mut expected: BTreeMap<String, u64> = BTreeMap::new();
    for class in &class_map.classes {
        *expected.entry(class.target.clone()).or_default() += source_counts[&class.name];
    }
    for target in &report.target_classes {
        let want = expected.get(&target.name).copied().unwrap_or(0);
        println!(
            "{:>12}: {:>9} pixels, {:6.2} %",
            target.name, target.pixels, target.percent_of_all
        );
        assert_eq!(target.pixels, want, "target class {}", target.name);
    }
    // The shares quoted in the issue.
    let percent = |name: &str| {
        report
            .target_classes
            .iter()
            .find(|t| t.name == name)
            .map(|t| t.percent_of_all)
            .unwrap()
    };
    let source_percent = |name: &str| {
        report
            .source_classes
            .iter()
            .find(|c| c.name == name)
            .map(|c| c.percent_of_all)
            .unwrap()
    };
    assert_eq!(format!("{:.2}", percent("road")), "28.95");
    assert_eq!(format!("{:.2}", percent("vehicle")), "1.75");
    assert_eq!(format!("{:.2}", percent("human")), "0.65");
    assert_eq!(percent("human"), source_percent("Pedestrian"));
    // Bicyclist (rider and bicycle in one region) is ignored and reported as unmapped.
    assert!(
        report
            .unmapped_source_classes
            .iter()
            .any(|c| c.name == "Bicyclist")
    );
    // CamVid cannot label lane markings: none written, and the card says so.
    assert_eq!(percent("lane_marking"), 0.0);
    assert!(!report.labelable.iter().any(|c| c == "lane_marking"));
}

/// The sequence-disjoint protocol: CamVid's frames grouped by sequence (the id up to its
/// first `_`), one sequence each for validation and test, the README's frame counts.
#[test]
fn camvid_sequences_split_apart() {
    let Some(root) = camvid_dir() else { return };
    let options = ImportOptions {
        name: "camvid".into(),
        format: SourceFormat::Camvid,
        layout: LayoutOptions {
            root,
            splits: vec!["train".into(), "val".into()],
            images: None,
            labels: None,
            variant: None,
        },
        class_map: ClassMap::load("camvid").unwrap(),
        source_config: None,
        lane_masks: None,
        on_error: OnError::Fail,
    };
    let out = tempfile::tempdir().unwrap();
    import(&options, out.path()).unwrap();
    let mut items = datasets::manifest::Dataset::open(out.path()).unwrap().items;
    let counts = datasets::split::assign_groups(
        &mut items,
        datasets::split::GroupBy::Prefix,
        &["0001TP".into()],
        &["0006R0".into()],
    )
    .unwrap();
    // README: 0001TP x62, 0006R0 x101, 0016E5 x204 + x101.
    assert_eq!(
        (counts.train, counts.val, counts.test, counts.groups),
        (305, 62, 101, 3)
    );
    for item in &items {
        let sequence = item.id.split('_').next().unwrap();
        let expected = match sequence {
            "0001TP" => "val",
            "0006R0" => "test",
            _ => "train",
        };
        assert_eq!(item.split.as_deref(), Some(expected), "{}", item.id);
    }
}
