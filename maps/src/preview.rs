//! A PNG picture of a whole map, for a quick look at what an import produced.
//!
//! Drawn with the rasterizer's painter (so it is fast even for city-sized maps) in painter's
//! order: connections, junction areas, lanes (roundabout rings tinted), markings, stop lines.
//! Thin features are widened to at least a pixel so they stay visible when zoomed out;
//! markings are left out when lanes are too few pixels wide to show them.

use crate::error::MapError;
use crate::geometry::Bounds;
use crate::model::{Map, MarkingKind};
use crate::raster::{
    DASH_OFF_M, DASH_ON_M, MARKING_WIDTH_M, Painter, RasterSpec, connection_corridor,
    connection_width, dashes, paired_boundaries,
};

const BACKGROUND: [u8; 3] = [40, 40, 40];
/// Colour per class painted (index = class value).
const PALETTE: [[u8; 3]; 6] = [
    BACKGROUND,
    // 1: lanes and connections
    [105, 105, 105],
    // 2: junction areas
    [140, 130, 105],
    // 3: roundabout circulating lanes
    [85, 115, 170],
    // 4: markings
    [255, 255, 255],
    // 5: stop and give-way lines
    [220, 30, 30],
];
const LANE: u8 = 1;
const JUNCTION: u8 = 2;
const ROUNDABOUT: u8 = 3;
const MARKING: u8 = 4;
const STOP: u8 = 5;
/// Painted width of stop lines, metres (before widening to a pixel).
const STOP_LINE_WIDTH_M: f64 = 0.5;
/// Coarsest resolution at which markings are drawn, metres per pixel (a 3.5 m lane is then
/// seven pixels wide).
const MARKINGS_MAX_RESOLUTION_M: f64 = 0.5;
/// Border around the map, as a fraction of its longer side.
const MARGIN: f64 = 0.02;

/// The window and resolution of a preview: the map's bounds plus a small margin, at the
/// resolution that makes the longer side `max_size_px` pixels.
pub fn preview_spec(map: &Map, max_size_px: u32) -> Result<RasterSpec, MapError> {
    if max_size_px == 0 {
        return Err(MapError::Invalid {
            path: None,
            message: "preview size must be at least one pixel".into(),
        });
    }
    let b = map.bounds();
    if b.is_empty() || !b.min.is_finite() || !b.max.is_finite() {
        return Ok(RasterSpec {
            origin: Default::default(),
            resolution_m: 1.0,
            width: 1,
            height: 1,
        });
    }
    let side = b.width().max(b.height()).max(1.0) * (1.0 + 2.0 * MARGIN);
    let res = side / f64::from(max_size_px);
    let c = b.center();
    let half = |len: f64| (len / 2.0 + side * MARGIN).max(res / 2.0);
    let mut grown = Bounds::empty();
    grown.extend(crate::geometry::Point::new(
        c.x - half(b.width()),
        c.y - half(b.height()),
    ));
    grown.extend(crate::geometry::Point::new(
        c.x + half(b.width()),
        c.y + half(b.height()),
    ));
    let mut spec = RasterSpec::covering(grown, res);
    spec.width = spec.width.min(max_size_px);
    spec.height = spec.height.min(max_size_px);
    Ok(spec)
}

/// Renders the map as an RGB PNG whose longer side is at most `max_size_px` pixels.
pub fn render_preview_png(map: &Map, max_size_px: u32) -> Result<Vec<u8>, MapError> {
    let spec = preview_spec(map, max_size_px)?;
    let class = paint_classes(map, &spec);
    let mut rgb = Vec::with_capacity(class.len() * 3);
    for &c in &class {
        rgb.extend_from_slice(PALETTE.get(usize::from(c)).unwrap_or(&BACKGROUND));
    }
    let mut png = Vec::new();
    image::ImageEncoder::write_image(
        // Fast compression: the preview is mostly flat colour, so it still compresses well,
        // and the default level would cost more than the whole import.
        image::codecs::png::PngEncoder::new_with_quality(
            &mut png,
            image::codecs::png::CompressionType::Fast,
            image::codecs::png::FilterType::Sub,
        ),
        &rgb,
        spec.width,
        spec.height,
        image::ExtendedColorType::Rgb8,
    )
    .map_err(|e| MapError::Serialise(format!("preview PNG: {e}")))?;
    Ok(png)
}

/// One class value per pixel (see [`PALETTE`]), row-major from the top.
fn paint_classes(map: &Map, spec: &RasterSpec) -> Vec<u8> {
    let px = spec.resolution_m;
    let mut p = Painter::new(*spec);
    let ring: std::collections::BTreeSet<_> = map
        .roundabouts
        .values()
        .flat_map(|r| r.circulating_lanes.iter().copied())
        .collect();
    for c in map.connections.values() {
        let (l, r) = connection_corridor(&c.centre, connection_width(map, c).max(px));
        p.strip(&l, &r, Some(0), LANE, 0);
    }
    for j in map.junctions.values() {
        p.polygon(&j.polygon, Some(0), JUNCTION, 0);
    }
    for lane in map.lanes.values() {
        let class = if ring.contains(&lane.id) {
            ROUNDABOUT
        } else {
            LANE
        };
        if lane.width_m >= px {
            let (l, r) = paired_boundaries(&lane.left, &lane.right);
            p.strip(&l, &r, Some(0), class, 0);
        } else {
            p.stroke(&lane.centre, px, Some(0), class, 0);
        }
    }
    // Markings widened to a pixel would bury lanes only a few pixels wide: draw them only
    // when a lane spans enough pixels to show road between them.
    if px <= MARKINGS_MAX_RESOLUTION_M {
        let mark_w = MARKING_WIDTH_M.max(px);
        for m in &map.markings {
            if m.kind == MarkingKind::Dashed {
                for d in dashes(&m.line, DASH_ON_M, DASH_OFF_M) {
                    p.stroke(&d, mark_w, Some(0), MARKING, 0);
                }
            } else {
                p.stroke(&m.line, mark_w, Some(0), MARKING, 0);
            }
        }
    }
    for s in map.stop_lines.values() {
        p.stroke(&s.line, STOP_LINE_WIDTH_M.max(1.5 * px), Some(0), STOP, 0);
    }
    let (mut layers, _) = p.paint(1, false);
    layers.pop().unwrap_or_default()
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::graph::test_maps;

    #[test]
    fn preview_is_a_png_of_the_right_size() {
        let map = test_maps::square_loop();
        let png = render_preview_png(&map, 256).unwrap();
        let img = image::load_from_memory_with_format(&png, image::ImageFormat::Png)
            .unwrap()
            .to_rgb8();
        assert_eq!(img.width(), 256);
        assert!(img.height() <= 256 && img.height() > 40);
        let lane_px = img.pixels().filter(|p| p.0 == PALETTE[1]).count();
        assert!(lane_px > 500, "{lane_px}");
        assert_eq!(png, render_preview_png(&map, 256).unwrap());
        assert!(render_preview_png(&map, 0).is_err());
    }
}
