//! A tiny labelled dataset of simple synthetic scenes, for tests and smoke runs of the
//! segmenter: sky ("other") above a horizon, road below with a lane marking, a vehicle and a
//! person, at positions that vary per image, each class in its own colour with noise. All
//! regions are at least 4 px wide, so a network of output stride 4-8 can learn them exactly.

use std::path::Path;

use datasets::classes::Class;
use datasets::image_io::{encode_label_png, encode_rgb_png, write_bytes};
use datasets::manifest::write_dataset_files;
use datasets::{Card, Item};
use image::{GrayImage, Luma, Rgb, RgbImage};
use rand::Rng;
use sim::seed::item_rng;

use super::error::Result;

/// Seed stage of the scenes' noise.
const STAGE_SCENE: u64 = 0x5e6_0010;

/// Scene `index` at `side`×`side` pixels (side ≥ 32; positions scale with it).
pub fn scene(index: u64, side: u32, seed: u64) -> (RgbImage, GrayImage) {
    let mut rng = item_rng(seed, STAGE_SCENE, index);
    let u = (side / 8).max(1);
    let i = index as u32;
    let horizon = 3 * u + u * (i % 2);
    let lane_x = 2 * u + u * (i % 4);
    let car_x = 5 * u - u * (i % 3);
    let person_x = if i.is_multiple_of(2) { 0 } else { 7 * u };
    let class_at = |x: u32, y: u32| -> Class {
        if (car_x..car_x + 2 * u).contains(&x) && (horizon..horizon + 2 * u).contains(&y) {
            Class::Vehicle
        } else if (person_x..person_x + u).contains(&x)
            && (horizon - u..horizon + 2 * u).contains(&y)
        {
            Class::Human
        } else if y < horizon {
            Class::Other
        } else if (lane_x..lane_x + u).contains(&x) && y >= horizon + 2 * u {
            Class::LaneMarking
        } else {
            Class::Road
        }
    };
    let mut image = RgbImage::new(side, side);
    let mut label = GrayImage::new(side, side);
    for y in 0..side {
        for x in 0..side {
            let class = class_at(x, y);
            let base = match class {
                Class::Road => [70, 70, 75],
                Class::LaneMarking => [230, 220, 120],
                Class::Vehicle => [30, 60, 200],
                Class::Human => [200, 40, 60],
                Class::Other => [140, 170, 210],
            };
            let pixel = base.map(|v: i32| (v + rng.random_range(-12..=12)).clamp(0, 255) as u8);
            image.put_pixel(x, y, Rgb(pixel));
            label.put_pixel(x, y, Luma([class.id()]));
        }
    }
    (image, label)
}

/// Writes `count` scenes as a dataset folder (manifest, card, images, labels). With `split`,
/// every item gets that split; the card says the source labels every class.
pub fn write_synthetic_dataset(
    dir: &Path,
    count: usize,
    side: u32,
    seed: u64,
    split: Option<&str>,
) -> Result<()> {
    let mut items = Vec::with_capacity(count);
    for index in 0..count {
        let (image, label) = scene(index as u64, side, seed);
        let mut item = Item::new(
            format!("scene{index:04}"),
            "synthetic",
            (side, side),
            serde_json::json!({ "seed": seed }),
        );
        item.split = split.map(str::to_owned);
        write_bytes(&dir.join(&item.image), &encode_rgb_png(&image))?;
        write_bytes(&dir.join(&item.label), &encode_label_png(&label))?;
        items.push(item);
    }
    let card = Card::new(
        "synthetic",
        &Class::ALL,
        serde_json::json!({ "tool": "models::segmenter::synthetic" }),
        serde_json::json!({ "count": count, "side": side }),
        seed,
    );
    write_dataset_files(dir, &card, &items)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_class_appears_and_scenes_differ() {
        let (a_image, a) = scene(0, 32, 1);
        let (_, b) = scene(1, 32, 1);
        for class in Class::ALL {
            assert!(
                a.as_raw().contains(&class.id()) || b.as_raw().contains(&class.id()),
                "{class:?}"
            );
        }
        assert_ne!(a, b);
        assert_eq!(scene(0, 32, 1).0, a_image);
    }
}
