//! Property tests of the augmentation.
//!
//! Alignment: the image is a palette picture of rectangles, one colour per class, and the
//! label is derived from it by the rule "class = the class whose colour the pixel has".
//! After any chain of geometric ops:
//! - a pixel whose colour is exactly class c's colour is labelled c (never another class,
//!   never ignore): image and label moved together;
//! - a black pixel (pure padding) is labelled ignore;
//! - the only other pixels are interpolation blends at a region edge or at the padding's
//!   edge, and each lies within [`BLEND_RADIUS`] pixels of a label change;
//! - every label value is in {0, 1, 2, 3, 4, 255}.
//!
//! The palette colours are vertices of the RGB cube, none inside the convex hull of the
//! others and black, so no blend of other colours (or of black padding) can round to a
//! palette colour unless it is that colour's own pixel by more than 99.8 % weight.

use image::{GrayImage, RgbImage};
use proptest::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::{AugmentConfig, Chance, Op, Preset, apply};
use crate::classes::{IGNORE, is_valid_label};

const PALETTE: [[u8; 3]; 5] = [
    [255, 0, 0],
    [0, 255, 0],
    [0, 0, 255],
    [255, 255, 0],
    [0, 255, 255],
];

/// How far (Chebyshev, output pixels) a blend may lie from a label change after `ops`.
/// A blend's source point is within one input pixel of an edge, which is at most the
/// chain's magnification in output pixels: the product of each op's, with scale `f` giving
/// `max(1, f)` and a perspective whose corners move by at most 10 % of the side bounded
/// by 1.5 (crop, flip and rotation do not magnify). One pixel more for rounding.
fn blend_radius(ops: &[Op]) -> i64 {
    let magnification: f64 = ops
        .iter()
        .map(|op| match op {
            Op::Scale { factor } => factor.max(1.0),
            Op::Perspective { .. } => 1.5,
            _ => 1.0,
        })
        .product();
    magnification.ceil() as i64 + 1
}

fn class_of(colour: [u8; 3]) -> Option<u8> {
    PALETTE.iter().position(|p| *p == colour).map(|c| c as u8)
}

/// A palette image of `blocks` rectangles and its derived label.
/// A rectangle `(x, y, width, height, class)`.
type Block = (u32, u32, u32, u32, u8);

fn palette_scene(w: u32, h: u32, blocks: &[Block]) -> (RgbImage, GrayImage) {
    let mut image = RgbImage::from_pixel(w, h, image::Rgb(PALETTE[4]));
    for &(x, y, bw, bh, class) in blocks {
        for yy in y..(y + bh).min(h) {
            for xx in x..(x + bw).min(w) {
                image.put_pixel(xx, yy, image::Rgb(PALETTE[usize::from(class)]));
            }
        }
    }
    let label = GrayImage::from_fn(w, h, |x, y| {
        image::Luma([class_of(image.get_pixel(x, y).0).unwrap_or(IGNORE)])
    });
    (image, label)
}

/// Counts blends and checks the alignment rules; Err with the first violation.
fn check_alignment(image: &RgbImage, label: &GrayImage, radius: i64) -> Result<usize, String> {
    if image.dimensions() != label.dimensions() {
        return Err(format!(
            "sizes {:?} vs {:?}",
            image.dimensions(),
            label.dimensions()
        ));
    }
    let (w, h) = (i64::from(image.width()), i64::from(image.height()));
    let mut blends = 0;
    for y in 0..h {
        for x in 0..w {
            let l = label.get_pixel(x as u32, y as u32).0[0];
            if !is_valid_label(l) {
                return Err(format!("label value {l} at ({x}, {y})"));
            }
            let colour = image.get_pixel(x as u32, y as u32).0;
            match class_of(colour) {
                Some(c) if c == l => {}
                Some(c) => {
                    return Err(format!(
                        "pixel ({x}, {y}) has class {c}'s colour but label {l}"
                    ));
                }
                // Pure padding: black image, ignore label.
                None if colour == [0, 0, 0] => {
                    if l != IGNORE {
                        return Err(format!("padding pixel ({x}, {y}) is labelled {l}"));
                    }
                }
                None => {
                    blends += 1;
                    let near_change = (-radius..=radius).any(|dy| {
                        (-radius..=radius).any(|dx| {
                            let (nx, ny) = (x + dx, y + dy);
                            let outside = nx < 0 || ny < 0 || nx >= w || ny >= h;
                            outside || label.get_pixel(nx as u32, ny as u32).0[0] != l
                        })
                    });
                    if !near_change {
                        return Err(format!("blend at ({x}, {y}) far from any label change"));
                    }
                }
            }
        }
    }
    Ok(blends)
}

fn geometric_op(w: u32, h: u32) -> impl Strategy<Value = Op> {
    prop_oneof![
        (0.3f64..1.0, 0.3f64..1.0, 0.0f64..1.0, 0.0f64..1.0).prop_map(move |(fw, fh, fx, fy)| {
            let cw = ((f64::from(w) * fw) as u32).max(1);
            let ch = ((f64::from(h) * fh) as u32).max(1);
            Op::Crop {
                x: ((f64::from(w - cw)) * fx) as u32,
                y: ((f64::from(h - ch)) * fy) as u32,
                width: cw,
                height: ch,
            }
        }),
        (0.6f64..2.0).prop_map(|factor| Op::Scale { factor }),
        (-45.0f64..45.0).prop_map(|degrees| Op::Rotate { degrees }),
        Just(Op::HorizontalFlip),
        proptest::array::uniform4((-0.1f64..0.1, -0.1f64..0.1)).prop_map(move |d| {
            let (fw, fh) = (f64::from(w), f64::from(h));
            let base = [[0.0, 0.0], [fw, 0.0], [fw, fh], [0.0, fh]];
            let mut corners = base;
            for (c, (dx, dy)) in corners.iter_mut().zip(d) {
                c[0] += dx * fw;
                c[1] += dy * fh;
            }
            Op::Perspective { corners }
        }),
    ]
}

/// Scene rectangles lie on a grid of this many pixels, so every region (the gaps between
/// rectangles included) is at least this wide.
///
/// Why: a region thinner than the output's pixel spacing can fall between nearest-neighbour
/// label samples while the bilinear image still shows a trace of it, a blend far from any
/// label change. That is aliasing of a sub-pixel feature, not misalignment, and the test
/// keeps it out: the strongest minification a chain here can apply (three scales of 0.6
/// and a perspective warp, about 0.8) leaves an 8-pixel region about 1.4 output pixels wide.
const GRID: u32 = 8;

fn scene() -> impl Strategy<Value = (u32, u32, Vec<Block>)> {
    (3u32..8, 3u32..8).prop_flat_map(|(cells_w, cells_h)| {
        let block = (0..cells_w, 0..cells_h, 1u32..3, 1u32..3, 0u8..4)
            .prop_map(|(x, y, bw, bh, class)| (x * GRID, y * GRID, bw * GRID, bh * GRID, class));
        (
            Just(cells_w * GRID),
            Just(cells_h * GRID),
            proptest::collection::vec(block, 1..6),
        )
    })
}

/// Re-aims crops and perspective corners drawn for a 40x40 frame at the size the image has
/// when each op is reached (crops and scales change it along the chain).
fn aimed_at(ops: Vec<Op>, (mut w, mut h): (u32, u32)) -> Vec<Op> {
    ops.into_iter()
        .map(|op| match op {
            Op::Crop {
                x,
                y,
                width,
                height,
            } => {
                let (x, y) = (x * w / 40, y * h / 40);
                (w, h) = ((width * w / 40).max(1), (height * h / 40).max(1));
                Op::Crop {
                    x,
                    y,
                    width: w,
                    height: h,
                }
            }
            Op::Scale { factor } => {
                w = (f64::from(w) * factor).round().max(1.0) as u32;
                h = (f64::from(h) * factor).round().max(1.0) as u32;
                op
            }
            Op::Perspective { corners } => {
                let (sx, sy) = (f64::from(w) / 40.0, f64::from(h) / 40.0);
                Op::Perspective {
                    corners: corners.map(|[x, y]| [x * sx, y * sy]),
                }
            }
            other => other,
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    /// Every geometric op alone and in chains keeps image and label aligned.
    #[test]
    fn geometric_ops_keep_image_and_label_aligned(
        (w, h, blocks) in scene(),
        ops in proptest::collection::vec(geometric_op(40, 40), 1..4),
    ) {
        let (image, label) = palette_scene(w, h, &blocks);
        let ops = aimed_at(ops, (w, h));
        let (out_image, out_label) = apply(&ops, &image, &label).map_err(|e| TestCaseError::fail(e.to_string()))?;
        check_alignment(&out_image, &out_label, blend_radius(&ops)).map_err(|e| TestCaseError::fail(format!("{e} after {ops:?}")))?;
    }

    /// No op chain ever writes a label value outside the class table, whatever the label
    /// holds, and the label always has the image's size.
    #[test]
    fn labels_stay_in_the_class_table(
        seed in any::<u64>(),
        w in 8u32..48,
        h in 8u32..48,
        values in proptest::collection::vec(prop_oneof![0u8..5, Just(IGNORE)], 64),
    ) {
        let image = RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 5) as u8, (y * 7) as u8, 90]));
        let label = GrayImage::from_fn(w, h, |x, y| image::Luma([values[((x + y * 3) % 64) as usize]]));
        let mut config = AugmentConfig::preset(Preset::Full);
        // Every transform, every time.
        for c in [&mut config.crop, &mut config.scale, &mut config.rotate, &mut config.hflip,
                  &mut config.perspective, &mut config.brightness, &mut config.contrast,
                  &mut config.gamma, &mut config.hue, &mut config.saturation, &mut config.fog,
                  &mut config.shadow, &mut config.gaussian_blur, &mut config.motion_blur,
                  &mut config.gaussian_noise, &mut config.jpeg].into_iter().flatten() {
            *c = Chance { p: 1.0, ..*c };
        }
        let ops = config.sample(&mut ChaCha8Rng::seed_from_u64(seed), w, h);
        prop_assert_eq!(ops.len(), 16);
        let (out_image, out_label) = apply(&ops, &image, &label).map_err(|e| TestCaseError::fail(e.to_string()))?;
        prop_assert_eq!(out_image.dimensions(), out_label.dimensions());
        prop_assert!(out_label.iter().all(|&v| is_valid_label(v)));
    }
}

/// The exact copies (crop, flip) leave no blend at all; and the share of blend pixels
/// under the thesis chain on a scene of large regions stays small (the figure is printed).
#[test]
fn blends_only_where_resampling_happens() -> Result<(), String> {
    let blocks = [(0, 0, 40, 30, 0), (40, 0, 40, 30, 2), (0, 30, 80, 30, 3)];
    let (image, label) = palette_scene(80, 60, &blocks);
    let exact = [
        Op::Crop {
            x: 3,
            y: 5,
            width: 50,
            height: 40,
        },
        Op::HorizontalFlip,
    ];
    let (i, l) = apply(&exact, &image, &label).map_err(|e| e.to_string())?;
    assert_eq!(check_alignment(&i, &l, blend_radius(&exact))?, 0);

    let config = AugmentConfig::preset(Preset::Thesis);
    let (mut blends, mut pixels) = (0usize, 0usize);
    for seed in 0..50 {
        let ops: Vec<Op> = config
            .sample(&mut ChaCha8Rng::seed_from_u64(seed), 80, 60)
            .into_iter()
            .filter(Op::is_geometric)
            .collect();
        let (i, l) = apply(&ops, &image, &label).map_err(|e| e.to_string())?;
        blends += check_alignment(&i, &l, blend_radius(&ops))?;
        pixels += (i.width() * i.height()) as usize;
    }
    let share = 100.0 * blends as f64 / pixels as f64;
    #[allow(clippy::print_stdout)]
    {
        println!(
            "thesis geometric chain, 50 draws: {blends} of {pixels} pixels are edge blends ({share:.2} %)"
        );
    }
    assert!(share < 10.0, "{share}");
    Ok(())
}
