//! The top-down label view of the same scene: class ids seen from straight above, centred
//! on the ego camera and turned with it (row 0 is farthest ahead, column 0 on the left),
//! like the bird's-eye observations of `sim`.
//!
//! Painted with the same polygon filler as the camera view: ground polygons in layer order
//! (the same centre-line style and worn paint as the camera view), then the footprints of
//! buildings and trees (other), vehicles and people.

use maps::geometry::Point;
use serde::{Deserialize, Serialize};

use super::look::Look;
use super::raster::fill_polygon;
use super::scene::MapScene;
use super::solids::Solid;
use super::view::ground_shown;
use crate::classes::Class;

/// Size and scale of the top-down view.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TopdownConfig {
    /// Width and height, pixels.
    pub size_px: u32,
    /// Metres per pixel.
    pub resolution_m: f64,
}

impl Default for TopdownConfig {
    /// 256 pixels of 0.25 m: 64 m square around the ego.
    fn default() -> Self {
        TopdownConfig {
            size_px: 256,
            resolution_m: 0.25,
        }
    }
}

/// Renders the top-down label view around `centre` facing `heading_rad`.
pub fn render_topdown(
    scene: &MapScene,
    look: &Look,
    wear_seed: u64,
    (centre, heading_rad): (Point, f64),
    actors: &[Solid],
    config: &TopdownConfig,
) -> Vec<u8> {
    let n = config.size_px as usize;
    let mut out = vec![Class::Other as u8; n * n];
    if n == 0 || config.resolution_m.is_nan() || config.resolution_m <= 0.0 {
        return out;
    }
    let fwd = Point::new(heading_rad.cos(), heading_rad.sin());
    let left = fwd.perp();
    let half = n as f64 / 2.0;
    let res = config.resolution_m;
    let to_px = |p: &Point| {
        let d = p.sub(centre);
        (half - d.dot(left) / res, half - d.dot(fwd) / res)
    };
    let reach = half * res * std::f64::consts::SQRT_2;
    let window = (
        Point::new(centre.x - reach, centre.y - reach),
        Point::new(centre.x + reach, centre.y + reach),
    );
    let mut crossings = Vec::new();
    let mut pts = Vec::new();
    let mut paint = |poly: &mut dyn Iterator<Item = (f64, f64)>, class: u8, out: &mut [u8]| {
        pts.clear();
        pts.extend(poly);
        fill_polygon(&pts, n, n, &mut crossings, |row, c0, c1| {
            out[row * n + c0..row * n + c1].fill(class);
        });
    };
    let mut ids = Vec::new();
    scene.ground_near(window, |_| true, &mut ids);
    for &i in &ids {
        let g = &scene.ground[i as usize];
        if ground_shown(look, wear_seed, i, g) {
            let class = g.material.class() as u8;
            paint(
                &mut scene.ground_points(g).iter().map(to_px),
                class,
                &mut out,
            );
        }
    }
    scene.props_near(window, &mut ids);
    let props = ids.iter().map(|&i| &scene.props[i as usize].solid);
    // People last: on a crossing they stand on the road, and nothing hides them from above.
    let mut solids: Vec<&Solid> = props.chain(actors.iter()).collect();
    solids.sort_by_key(|s| match s.class {
        Class::Human => 2,
        Class::Vehicle => 1,
        _ => 0,
    });
    for s in solids {
        paint(
            &mut s.footprint().iter().map(to_px),
            s.class as u8,
            &mut out,
        );
    }
    out
}
