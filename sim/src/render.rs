//! The synthetic bird's-eye representation: an ego-centred, ego-aligned grid of layers
//! drawn from a [`Scene`].
//!
//! Row 0 is the farthest ahead, column 0 the farthest to the left (x forward, y left, the
//! ego in the middle). Layers are `u8` (0 empty, 255 full), layer-major.
//!
//! Speed matters (a frame per 0.1 s step of every environment): the static layers
//! (navigable area, stop / yield lines) are rasterised once per map region at a fine
//! resolution ([`MapRaster`]) and each frame samples them through the ego transform (one
//! lookup per output pixel, nearest neighbour); the path and the vehicles are drawn
//! directly as convex polygons in the output grid.

use maps::geometry::Bounds;
use maps::raster::{Layers, RasterSpec, Rasterizer};
use maps::{Map, Point};
use serde::{Deserialize, Serialize};

use crate::scene::{Actor, Scene};

/// One layer of the representation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Layer {
    /// Where a car may drive (lanes, connections, junction areas).
    Navigable,
    /// The ego's route.
    Path,
    /// Every vehicle's footprint, the ego's included.
    Obstacles,
    /// Stop and yield lines.
    StopLines,
    /// Every vehicle's footprint, as bright as it is fast: 255 at
    /// [`BevConfig::full_speed_mps`] or faster, 0 standing. A car creeping round a ring
    /// moves under a pixel between two frames; here it differs from one stopped at its line
    /// in every single frame.
    ObstacleSpeed,
}

impl Layer {
    pub fn name(self) -> &'static str {
        match self {
            Layer::Navigable => "navigable",
            Layer::Path => "path",
            Layer::Obstacles => "obstacles",
            Layer::StopLines => "stop_lines",
            Layer::ObstacleSpeed => "obstacle_speed",
        }
    }
}

/// Size, extent and content of the representation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct BevConfig {
    /// Pixels across (left to right).
    pub width: usize,
    /// Pixels from front to back.
    pub height: usize,
    /// Metres covered ahead-to-behind and left-to-right; the ego sits in the middle.
    pub forward_m: f64,
    pub lateral_m: f64,
    pub layers: Vec<Layer>,
    /// Frames stacked into one observation (oldest first).
    pub stack: usize,
    /// Resolution of the precomputed map raster the static layers are sampled from, m.
    pub map_resolution_m: f64,
    /// Width of the drawn path, m.
    pub path_width_m: f64,
    /// Width of drawn stop lines, m (about one output pixel keeps them visible).
    pub line_width_m: f64,
    /// The speed drawn at full brightness in [`Layer::ObstacleSpeed`], m/s.
    pub full_speed_mps: f64,
    /// Draw each pixel as bright as the share of it covered, instead of all or nothing by
    /// whether its centre is. A car or a line moving by a fraction of a pixel then changes
    /// the frame by a fraction, where without it a whole row of pixels can appear or vanish
    /// (a 0.8 m stop line at 1.2 m a pixel falls between the row centres in a third of the
    /// frames). In [`Layer::ObstacleSpeed`] an edge pixel is the vehicle's brightness times
    /// that share; [`Layer::Obstacles`] holds the share itself. Where vehicles overlap, the
    /// brighter value wins.
    pub antialias: bool,
}

impl Default for BevConfig {
    fn default() -> Self {
        BevConfig {
            width: 84,
            height: 84,
            forward_m: 50.0,
            lateral_m: 50.0,
            layers: vec![
                Layer::Navigable,
                Layer::Path,
                Layer::Obstacles,
                Layer::StopLines,
            ],
            stack: 4,
            map_resolution_m: 0.2,
            path_width_m: 2.0,
            line_width_m: 0.8,
            full_speed_mps: 15.0,
            antialias: false,
        }
    }
}

impl BevConfig {
    pub fn frame_len(&self) -> usize {
        self.layers.len() * self.width * self.height
    }

    /// Channels of an observation: layers × stacked frames.
    pub fn channels(&self) -> usize {
        self.layers.len() * self.stack
    }

    /// The shape of a task's observations drawn with this view, beside `scalars` inputs.
    pub fn observation_spec(&self, scalars: usize) -> crate::ObservationSpec {
        crate::ObservationSpec {
            channels: self.channels(),
            height: self.height,
            width: self.width,
            scalars,
        }
    }

    /// Radius around the ego that a frame can show, m.
    pub fn view_radius_m(&self) -> f64 {
        self.forward_m.hypot(self.lateral_m) / 2.0
    }

    pub fn validate(&self) -> Result<(), crate::SimError> {
        let ok = self.width > 0
            && self.height > 0
            && self.width * self.height <= 1 << 22
            && self.stack > 0
            && !self.layers.is_empty()
            && [
                self.forward_m,
                self.lateral_m,
                self.map_resolution_m,
                self.full_speed_mps,
            ]
            .iter()
            .all(|v| v.is_finite() && *v > 0.0);
        if ok {
            Ok(())
        } else {
            Err(crate::SimError::Config(format!(
                "bird's-eye view {}×{} px over {}×{} m, {} layers, stack {}, map raster {} m, full speed {} m/s: sizes must be positive",
                self.width,
                self.height,
                self.forward_m,
                self.lateral_m,
                self.layers.len(),
                self.stack,
                self.map_resolution_m,
                self.full_speed_mps
            )))
        }
    }
}

const NAVIGABLE_BIT: u8 = 1;
const STOP_LINE_BIT: u8 = 2;

/// The static layers of one map region, rasterised once at a fine resolution: bit 0
/// navigable, bit 1 stop / yield line.
#[derive(Debug, Clone)]
pub struct MapRaster {
    spec: RasterSpec,
    bits: Vec<u8>,
    /// Summed-area tables of the bits, built on the first antialiased frame.
    area_sums: std::sync::OnceLock<AreaSums>,
}

/// Summed-area tables of a raster's navigable and stop line bits, interleaved: entry
/// (x, y) of a `(width + 1)` × `(height + 1)` table counts the cells left of x and above y,
/// so any box's count is four look-ups.
#[derive(Debug, Clone)]
struct AreaSums {
    width: usize,
    height: usize,
    /// [navigable, stop line] counts per entry.
    sums: Vec<[u32; 2]>,
}

impl AreaSums {
    fn new(spec: &RasterSpec, bits: &[u8]) -> Self {
        let (width, height) = (spec.width as usize, spec.height as usize);
        let stride = width + 1;
        let mut sums = vec![[0u32; 2]; stride * (height + 1)];
        for y in 0..height {
            let mut row = [0u32; 2];
            for x in 0..width {
                let b = bits[y * width + x];
                row[0] += u32::from(b & NAVIGABLE_BIT);
                row[1] += u32::from((b & STOP_LINE_BIT) >> 1);
                let above = sums[y * stride + x + 1];
                sums[(y + 1) * stride + x + 1] = [above[0] + row[0], above[1] + row[1]];
            }
        }
        AreaSums {
            width,
            height,
            sums,
        }
    }

    /// [navigable, stop line] cells in the box of `box_w` × `box_h` cells whose top-left
    /// corner is cell (`x0`, `y0`) (whole numbers); cells outside the raster count 0.
    fn count(&self, x0: f64, y0: f64, box_w: f64, box_h: f64) -> [u32; 2] {
        let clamp = |v: f64, max: usize| v.clamp(0.0, max as f64) as usize;
        let (xa, xb) = (clamp(x0, self.width), clamp(x0 + box_w, self.width));
        let (ya, yb) = (clamp(y0, self.height), clamp(y0 + box_h, self.height));
        let stride = self.width + 1;
        let (tl, tr) = (self.sums[ya * stride + xa], self.sums[ya * stride + xb]);
        let (bl, br) = (self.sums[yb * stride + xa], self.sums[yb * stride + xb]);
        [0, 1].map(|k| br[k] + tl[k] - tr[k] - bl[k])
    }
}

impl MapRaster {
    /// Rasterises `region` of `map` at `resolution_m`, stop lines `line_width_m` wide.
    pub fn new(map: &Map, region: Bounds, resolution_m: f64, line_width_m: f64) -> Self {
        let spec = RasterSpec::covering(region, resolution_m);
        let drivable = Rasterizer::new(map)
            .rasterize(&spec, Layers::DRIVABLE)
            .drivable
            .unwrap_or_else(|| vec![0; spec.len()]);
        let mut bits: Vec<u8> = drivable
            .iter()
            .map(|&d| if d != 0 { NAVIGABLE_BIT } else { 0 })
            .collect();
        let mut lines = vec![0u8; spec.len()];
        let to_pixel = |p: Point| map_pixel(&spec, p);
        for line in map.stop_lines.values() {
            let pts: Vec<(f64, f64)> = line.line.iter().map(|p| to_pixel(*p)).collect();
            stroke(
                &mut lines,
                spec.width as usize,
                spec.height as usize,
                &pts,
                line_width_m / spec.resolution_m,
                1,
            );
        }
        for (b, l) in bits.iter_mut().zip(&lines) {
            if *l != 0 {
                *b |= STOP_LINE_BIT;
            }
        }
        MapRaster {
            spec,
            bits,
            area_sums: Default::default(),
        }
    }

    fn area_sums(&self) -> &AreaSums {
        self.area_sums
            .get_or_init(|| AreaSums::new(&self.spec, &self.bits))
    }

    pub fn spec(&self) -> &RasterSpec {
        &self.spec
    }

    /// Marks a corridor `width_m` wide along each of `lines` navigable: routes rounded off
    /// where the mapped lanes kink may leave the mapped lane area by a little, and are
    /// driven there.
    pub fn mark_navigable<'a>(
        &mut self,
        lines: impl IntoIterator<Item = &'a [Point]>,
        width_m: f64,
    ) {
        let (w, h) = (self.spec.width as usize, self.spec.height as usize);
        let mut corridors = vec![0u8; self.bits.len()];
        for line in lines {
            let pts: Vec<(f64, f64)> = line.iter().map(|p| map_pixel(&self.spec, *p)).collect();
            stroke(
                &mut corridors,
                w,
                h,
                &pts,
                width_m / self.spec.resolution_m,
                1,
            );
        }
        for (b, c) in self.bits.iter_mut().zip(&corridors) {
            if *c != 0 {
                *b |= NAVIGABLE_BIT;
            }
        }
        self.area_sums = Default::default();
    }

    fn bits_at(&self, p: Point) -> u8 {
        let (x, y) = map_pixel(&self.spec, p);
        if x >= 0.0 && y >= 0.0 && x < f64::from(self.spec.width) && y < f64::from(self.spec.height)
        {
            self.bits[y as usize * self.spec.width as usize + x as usize]
        } else {
            0
        }
    }

    /// Whether a car may drive at `p` (false outside the region).
    pub fn navigable(&self, p: Point) -> bool {
        self.bits_at(p) & NAVIGABLE_BIT != 0
    }
}

/// Continuous pixel coordinates (x right, y down) of a map point in a raster.
fn map_pixel(spec: &RasterSpec, p: Point) -> (f64, f64) {
    let top = spec.origin.y + f64::from(spec.height) * spec.resolution_m;
    (
        (p.x - spec.origin.x) / spec.resolution_m,
        (top - p.y) / spec.resolution_m,
    )
}

/// Draws scenes of one map region.
#[derive(Debug, Clone)]
pub struct BevRenderer {
    config: BevConfig,
    raster: std::sync::Arc<MapRaster>,
}

/// The ego transform of one frame: map point -> continuous output pixel.
#[derive(Debug, Clone, Copy)]
struct EgoFrame {
    origin: Point,
    forward: Point,
    left: Point,
    /// Pixels per metre along the rows and the columns.
    px_fwd: f64,
    px_lat: f64,
    half_w: f64,
    half_h: f64,
}

impl EgoFrame {
    fn new(config: &BevConfig, ego: &Actor) -> Self {
        let (sin, cos) = ego.heading_rad.sin_cos();
        EgoFrame {
            origin: ego.position,
            forward: Point::new(cos, sin),
            left: Point::new(-sin, cos),
            px_fwd: config.height as f64 / config.forward_m,
            px_lat: config.width as f64 / config.lateral_m,
            half_w: config.width as f64 / 2.0,
            half_h: config.height as f64 / 2.0,
        }
    }

    /// (column, row) in continuous pixel units: row 0 ahead, column 0 left.
    fn pixel(&self, p: Point) -> (f64, f64) {
        let d = p.sub(self.origin);
        (
            self.half_w - d.dot(self.left) * self.px_lat,
            self.half_h - d.dot(self.forward) * self.px_fwd,
        )
    }

    /// Map point at the centre of output pixel (`col`, `row`).
    fn map_point(&self, col: f64, row: f64) -> Point {
        let fwd = (self.half_h - row - 0.5) / self.px_fwd;
        let lat = (self.half_w - col - 0.5) / self.px_lat;
        self.origin
            .add(self.forward.scale(fwd))
            .add(self.left.scale(lat))
    }
}

impl BevRenderer {
    /// A renderer for scenes whose ego stays inside `region` of `map`: the static layers
    /// are rasterised here, over the region grown by the view radius.
    pub fn new(map: &Map, region: Bounds, config: BevConfig) -> Result<Self, crate::SimError> {
        config.validate()?;
        let mut grown = region;
        if !grown.is_empty() {
            let r = config.view_radius_m() + 1.0;
            grown.extend(Point::new(region.min.x - r, region.min.y - r));
            grown.extend(Point::new(region.max.x + r, region.max.y + r));
        }
        let raster = MapRaster::new(map, grown, config.map_resolution_m, config.line_width_m);
        Ok(BevRenderer {
            config,
            raster: std::sync::Arc::new(raster),
        })
    }

    /// This renderer with a navigable corridor `width_m` wide along each of `lines` (see
    /// [`MapRaster::mark_navigable`]).
    pub fn with_navigable_corridors<'a>(
        mut self,
        lines: impl IntoIterator<Item = &'a [Point]>,
        width_m: f64,
    ) -> Self {
        std::sync::Arc::make_mut(&mut self.raster).mark_navigable(lines, width_m);
        self
    }

    /// A renderer sharing another's map raster, with a different layer choice or stack
    /// (same size, extent and raster resolution).
    pub fn with_raster(
        raster: std::sync::Arc<MapRaster>,
        config: BevConfig,
    ) -> Result<Self, crate::SimError> {
        config.validate()?;
        Ok(BevRenderer { config, raster })
    }

    pub fn config(&self) -> &BevConfig {
        &self.config
    }

    pub fn raster(&self) -> &std::sync::Arc<MapRaster> {
        &self.raster
    }

    /// Draws one frame of `scene` into `out` (`config.frame_len()` bytes, layer-major,
    /// `[layer, row, column]`). Does nothing when the scene has no ego.
    pub fn render(&self, scene: &Scene<'_>, out: &mut Vec<u8>) {
        let cfg = &self.config;
        let (w, h) = (cfg.width, cfg.height);
        let plane = w * h;
        out.clear();
        out.resize(cfg.frame_len(), 0);
        let Some(ego) = scene.ego_actor() else { return };
        let frame = EgoFrame::new(cfg, ego);
        let slot = |layer: Layer| cfg.layers.iter().position(|l| *l == layer);
        let (nav, lines) = (slot(Layer::Navigable), slot(Layer::StopLines));
        if nav.is_some() || lines.is_some() {
            if cfg.antialias {
                self.average_static(&frame, out, nav, lines);
            } else {
                self.sample_static(&frame, out, nav, lines);
            }
        }
        if let Some(k) = slot(Layer::Path) {
            let pts: Vec<(f64, f64)> = scene.ego_path.iter().map(|p| frame.pixel(*p)).collect();
            let width_px = cfg.path_width_m * frame.px_lat;
            let buf = &mut out[k * plane..(k + 1) * plane];
            for_each_stroke_quad(&pts, width_px, w, h, |quad| {
                self.fill(buf, quad, 255);
            });
        }
        let obstacles = slot(Layer::Obstacles);
        let speeds = slot(Layer::ObstacleSpeed);
        if obstacles.is_some() || speeds.is_some() {
            for actor in &scene.actors {
                let corners = actor.footprint().corners().map(|p| frame.pixel(p));
                if let Some(k) = obstacles {
                    self.fill(&mut out[k * plane..(k + 1) * plane], &corners, 255);
                }
                if let Some(k) = speeds {
                    let value = speed_brightness(actor.speed_mps, cfg.full_speed_mps);
                    self.fill(&mut out[k * plane..(k + 1) * plane], &corners, value);
                }
            }
        }
    }

    /// Fills a convex polygon (output pixels) into one layer: the pixels whose centre it
    /// covers, or with `antialias` every pixel by the share of it covered.
    fn fill(&self, buf: &mut [u8], pts: &[(f64, f64)], value: u8) {
        let (w, h) = (self.config.width, self.config.height);
        if self.config.antialias {
            fill_convex_coverage(buf, w, h, pts, value);
        } else {
            fill_convex(buf, w, h, pts, value);
        }
    }

    /// Nearest-neighbour samples of the map raster for the navigable and stop line layers.
    fn sample_static(
        &self,
        frame: &EgoFrame,
        out: &mut [u8],
        nav: Option<usize>,
        lines: Option<usize>,
    ) {
        let (w, h) = (self.config.width, self.config.height);
        let plane = w * h;
        let spec = self.raster.spec;
        let (rw, rh) = (spec.width as f64, spec.height as f64);
        let to_raster = |p: Point| map_pixel(&spec, p);
        // Raster coordinates are affine in (column, row): walk them by increments.
        let p00 = to_raster(frame.map_point(0.0, 0.0));
        let p01 = to_raster(frame.map_point(1.0, 0.0));
        let p10 = to_raster(frame.map_point(0.0, 1.0));
        let d_col = (p01.0 - p00.0, p01.1 - p00.1);
        let d_row = (p10.0 - p00.0, p10.1 - p00.1);
        let stride = spec.width as usize;
        let bits = &self.raster.bits;
        for row in 0..h {
            let (mut x, mut y) = (p00.0 + d_row.0 * row as f64, p00.1 + d_row.1 * row as f64);
            for col in 0..w {
                let b = if x >= 0.0 && y >= 0.0 && x < rw && y < rh {
                    bits[y as usize * stride + x as usize]
                } else {
                    0
                };
                let i = row * w + col;
                if let Some(k) = nav {
                    out[k * plane + i] = if b & NAVIGABLE_BIT != 0 { 255 } else { 0 };
                }
                if let Some(k) = lines {
                    out[k * plane + i] = if b & STOP_LINE_BIT != 0 { 255 } else { 0 };
                }
                x += d_col.0;
                y += d_col.1;
            }
        }
    }

    /// The navigable and stop line layers with `antialias`: each output pixel the mean of
    /// the map raster over a box of the pixel's size around its centre (in the raster's
    /// axes, so for a turned ego a box about the pixel's size rather than the pixel itself).
    fn average_static(
        &self,
        frame: &EgoFrame,
        out: &mut [u8],
        nav: Option<usize>,
        lines: Option<usize>,
    ) {
        let (w, h) = (self.config.width, self.config.height);
        let plane = w * h;
        let spec = self.raster.spec;
        let sums = self.raster.area_sums();
        // The box: one output pixel's extent in raster cells, at least one.
        let cells = |px_per_m: f64| (1.0 / px_per_m / spec.resolution_m).round().max(1.0);
        let (box_w, box_h) = (cells(frame.px_lat), cells(frame.px_fwd));
        let area = box_w * box_h;
        let scale = |count: u32| (255.0 * f64::from(count) / area).round() as u8;
        // Raster coordinates of the boxes' corners are affine in (column, row): walk them.
        let corner = |col: f64, row: f64| {
            let (x, y) = map_pixel(&spec, frame.map_point(col, row));
            (x - box_w / 2.0, y - box_h / 2.0)
        };
        let p00 = corner(0.0, 0.0);
        let p01 = corner(1.0, 0.0);
        let p10 = corner(0.0, 1.0);
        let d_col = (p01.0 - p00.0, p01.1 - p00.1);
        let d_row = (p10.0 - p00.0, p10.1 - p00.1);
        for row in 0..h {
            let (mut x, mut y) = (p00.0 + d_row.0 * row as f64, p00.1 + d_row.1 * row as f64);
            for col in 0..w {
                let [nav_count, line_count] = sums.count(x.round(), y.round(), box_w, box_h);
                let i = row * w + col;
                if let Some(k) = nav {
                    out[k * plane + i] = scale(nav_count);
                }
                if let Some(k) = lines {
                    out[k * plane + i] = scale(line_count);
                }
                x += d_col.0;
                y += d_col.1;
            }
        }
    }
}

/// The brightness of a vehicle moving at `speed_mps` in [`Layer::ObstacleSpeed`]: linear
/// from 0 standing (or reversing) to 255 at `full_speed_mps` and above. A NaN speed draws
/// 0: the float-to-integer cast maps NaN to 0.
fn speed_brightness(speed_mps: f64, full_speed_mps: f64) -> u8 {
    ((speed_mps / full_speed_mps).clamp(0.0, 1.0) * 255.0).round() as u8
}

/// The extent `[top, bottom, left, right]` of a polygon (continuous pixel coordinates) that
/// overlaps a `w` × `h` buffer; None for fewer than 3 points, a non-finite one, or no overlap.
fn visible_extent(pts: &[(f64, f64)], w: usize, h: usize) -> Option<[f64; 4]> {
    if pts.len() < 3 || !pts.iter().all(|p| p.0.is_finite() && p.1.is_finite()) {
        return None;
    }
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let (mut left, mut right) = (f64::INFINITY, f64::NEG_INFINITY);
    for p in pts {
        lo = lo.min(p.1);
        hi = hi.max(p.1);
        left = left.min(p.0);
        right = right.max(p.0);
    }
    let outside = hi <= 0.0 || lo >= h as f64 || right <= 0.0 || left >= w as f64;
    (!outside).then_some([lo, hi, left, right])
}

/// Fills a convex polygon (continuous pixel coordinates, x right, y down) into a
/// `w` × `h` buffer: every pixel whose centre lies inside gets `value`.
pub fn fill_convex(buf: &mut [u8], w: usize, h: usize, pts: &[(f64, f64)], value: u8) {
    let Some([lo, hi, _, _]) = visible_extent(pts, w, h) else {
        return;
    };
    let r0 = (lo - 0.5).ceil().max(0.0) as usize;
    let r1 = ((hi - 0.5).floor().min(h as f64 - 1.0)).max(-1.0);
    if r1 < 0.0 {
        return;
    }
    for row in r0..=r1 as usize {
        let Some((x0, x1)) = convex_span(pts, row as f64 + 0.5) else {
            continue;
        };
        let c0 = (x0 - 0.5).ceil().max(0.0);
        let c1 = (x1 - 0.5).floor().min(w as f64 - 1.0);
        if c0 > c1 {
            continue;
        }
        let off = row * w;
        buf[off + c0 as usize..=off + c1 as usize].fill(value);
    }
}

/// Horizontal strips a pixel row is cut into by [`fill_convex_coverage`].
const COVERAGE_STRIPS: usize = 8;

/// Fills a convex polygon (continuous pixel coordinates, x right, y down) into a
/// `w` × `h` buffer by coverage: each pixel it touches gets `value` scaled by the share of
/// the pixel inside it (exact across a row, in eighth-of-a-pixel strips down a column), unless
/// the pixel is already brighter.
pub fn fill_convex_coverage(buf: &mut [u8], w: usize, h: usize, pts: &[(f64, f64)], value: u8) {
    let Some([lo, hi, left, right]) = visible_extent(pts, w, h) else {
        return;
    };
    let (r0, r1) = (lo.floor().max(0.0) as usize, (hi.ceil() as usize).min(h));
    let (c0, c1) = (
        left.floor().max(0.0) as usize,
        (right.ceil() as usize).min(w),
    );
    let strip_share = 1.0 / COVERAGE_STRIPS as f64;
    let mut cover = vec![0.0_f64; c1 - c0];
    for row in r0..r1 {
        cover.fill(0.0);
        for strip in 0..COVERAGE_STRIPS {
            let y = row as f64 + (strip as f64 + 0.5) * strip_share;
            let Some((x0, x1)) = convex_span(pts, y) else {
                continue;
            };
            let (x0, x1) = (x0.max(c0 as f64), x1.min(c1 as f64));
            if x0 >= x1 {
                continue;
            }
            for col in x0.floor() as usize..x1.ceil() as usize {
                let inside = x1.min(col as f64 + 1.0) - x0.max(col as f64);
                cover[col - c0] += inside * strip_share;
            }
        }
        for (col, share) in (c0..c1).zip(&cover) {
            let v = (f64::from(value) * share.min(1.0)).round() as u8;
            let px = &mut buf[row * w + col];
            *px = (*px).max(v);
        }
    }
}

/// Where the horizontal line at `y` crosses a convex polygon: (leftmost, rightmost) x.
fn convex_span(pts: &[(f64, f64)], y: f64) -> Option<(f64, f64)> {
    let n = pts.len();
    let (mut x0, mut x1) = (f64::INFINITY, f64::NEG_INFINITY);
    for i in 0..n {
        let (a, b) = (pts[i], pts[(i + 1) % n]);
        if (a.1 <= y) != (b.1 <= y) {
            let x = a.0 + (y - a.1) * (b.0 - a.0) / (b.1 - a.1);
            x0 = x0.min(x);
            x1 = x1.max(x);
        }
    }
    (x0 <= x1).then_some((x0, x1))
}

/// Draws a polyline `width` pixels wide: a rectangle per segment and a square at each
/// inner vertex (so bends have no notches).
pub fn stroke(buf: &mut [u8], w: usize, h: usize, pts: &[(f64, f64)], width: f64, value: u8) {
    for_each_stroke_quad(pts, width, w, h, |quad| fill_convex(buf, w, h, quad, value));
}

/// The quadrilaterals that draw a polyline `width` pixels wide in a `w` × `h` buffer (see
/// [`stroke`]), those wholly outside it left out.
fn for_each_stroke_quad(
    pts: &[(f64, f64)],
    width: f64,
    w: usize,
    h: usize,
    mut draw: impl FnMut(&[(f64, f64); 4]),
) {
    let half = width / 2.0;
    let (fw, fh) = (w as f64, h as f64);
    let outside = |a: (f64, f64), b: (f64, f64)| {
        (a.0.max(b.0) + half < 0.0)
            || (a.0.min(b.0) - half > fw)
            || (a.1.max(b.1) + half < 0.0)
            || (a.1.min(b.1) - half > fh)
    };
    for seg in pts.windows(2) {
        let (a, b) = (seg[0], seg[1]);
        if outside(a, b) {
            continue;
        }
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let len = dx.hypot(dy);
        if len.is_nan() || len <= 0.0 {
            continue;
        }
        let (nx, ny) = (-dy / len * half, dx / len * half);
        draw(&[
            (a.0 + nx, a.1 + ny),
            (b.0 + nx, b.1 + ny),
            (b.0 - nx, b.1 - ny),
            (a.0 - nx, a.1 - ny),
        ]);
    }
    for p in pts.iter().skip(1).take(pts.len().saturating_sub(2)) {
        if outside(*p, *p) {
            continue;
        }
        draw(&[
            (p.0 - half, p.1 - half),
            (p.0 + half, p.1 - half),
            (p.0 + half, p.1 + half),
            (p.0 - half, p.1 + half),
        ]);
    }
}

/// The last `stack` frames of an episode, oldest first, `spacing` pushes apart (1: the
/// last `stack` pushes). A wider spacing lets a policy decide at every push while its
/// frames stay as far apart in time as when it was trained deciding every `spacing` pushes.
#[derive(Debug, Clone)]
pub struct FrameStack {
    frame_len: usize,
    stack: usize,
    spacing: usize,
    /// Ring buffer of the last `(stack − 1) · spacing + 1` frames; `head` is the oldest.
    frames: Vec<u8>,
    head: usize,
}

impl FrameStack {
    pub fn new(frame_len: usize, stack: usize) -> Self {
        Self::spaced(frame_len, stack, 1)
    }

    /// A stack whose frames are `spacing` pushes apart (at least 1).
    pub fn spaced(frame_len: usize, stack: usize, spacing: usize) -> Self {
        let mut frame_stack = FrameStack {
            frame_len,
            stack: stack.max(1),
            spacing: spacing.max(1),
            frames: Vec::new(),
            head: 0,
        };
        frame_stack.frames = vec![0; frame_len * frame_stack.slots()];
        frame_stack
    }

    /// Frames kept: enough to reach back `(stack − 1) · spacing` pushes.
    fn slots(&self) -> usize {
        (self.stack - 1) * self.spacing + 1
    }

    /// Starts an episode: every slot holds `frame`.
    pub fn reset(&mut self, frame: &[u8]) {
        for chunk in self.frames.chunks_mut(self.frame_len) {
            chunk.copy_from_slice(frame);
        }
        self.head = 0;
    }

    /// Adds the newest frame, dropping the oldest.
    pub fn push(&mut self, frame: &[u8]) {
        let at = self.head * self.frame_len;
        self.frames[at..at + self.frame_len].copy_from_slice(frame);
        self.head = (self.head + 1) % self.slots();
    }

    /// The stack, oldest frame first, into `out` (`stack × frame_len` bytes).
    pub fn write(&self, out: &mut Vec<u8>) {
        out.clear();
        out.reserve(self.stack * self.frame_len);
        let slots = self.slots();
        for k in 0..self.stack {
            // The oldest slot is `head`; the stacked frames are every `spacing`-th from it.
            let i = (self.head + k * self.spacing) % slots;
            out.extend_from_slice(&self.frames[i * self.frame_len..(i + 1) * self.frame_len]);
        }
    }

    /// The newest frame.
    pub fn newest(&self) -> &[u8] {
        let slots = self.slots();
        let i = (self.head + slots - 1) % slots;
        &self.frames[i * self.frame_len..(i + 1) * self.frame_len]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::ActorKind;

    #[test]
    fn convex_fill_counts_pixel_centres() {
        let mut buf = vec![0u8; 100];
        // A 4 × 3 pixel rectangle from (2, 1) to (6, 4).
        fill_convex(
            &mut buf,
            10,
            10,
            &[(2.0, 1.0), (6.0, 1.0), (6.0, 4.0), (2.0, 4.0)],
            7,
        );
        assert_eq!(buf.iter().filter(|&&v| v == 7).count(), 12);
        assert_eq!(buf[10 + 2], 7);
        assert_eq!(buf[10 + 6], 0);
        // Clipped at the border, no panic.
        fill_convex(
            &mut buf,
            10,
            10,
            &[(-5.0, -5.0), (20.0, -5.0), (20.0, 0.4)],
            9,
        );
        fill_convex(
            &mut buf,
            10,
            10,
            &[(-5.0, 8.0), (20.0, 8.0), (20.0, 30.0), (-5.0, 30.0)],
            9,
        );
        assert_eq!(buf[95], 9);
    }

    #[test]
    fn frame_stack_keeps_order() {
        let mut s = FrameStack::new(2, 3);
        s.reset(&[1, 1]);
        s.push(&[2, 2]);
        s.push(&[3, 3]);
        let mut out = Vec::new();
        s.write(&mut out);
        assert_eq!(out, vec![1, 1, 2, 2, 3, 3]);
        s.push(&[4, 4]);
        s.write(&mut out);
        assert_eq!(out, vec![2, 2, 3, 3, 4, 4]);
        assert_eq!(s.newest(), &[4, 4]);
    }

    /// Frames two pushes apart: the stack is what a stack of one push per two steps would
    /// hold at every other push, and in between it moves on by one step.
    #[test]
    fn spaced_frame_stack_picks_every_spacing_th_frame() {
        let mut s = FrameStack::spaced(1, 3, 2);
        let mut out = Vec::new();
        s.reset(&[0]);
        s.write(&mut out);
        assert_eq!(out, vec![0, 0, 0]);
        for f in 1..=5u8 {
            s.push(&[f]);
        }
        s.write(&mut out);
        assert_eq!(out, vec![1, 3, 5]);
        assert_eq!(s.newest(), &[5]);
        s.push(&[6]);
        s.write(&mut out);
        assert_eq!(out, vec![2, 4, 6]);
        // Spacing 1 is the plain stack.
        let (mut plain, mut spaced) = (FrameStack::new(1, 3), FrameStack::spaced(1, 3, 1));
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for f in 0..7u8 {
            plain.push(&[f]);
            spaced.push(&[f]);
            plain.write(&mut a);
            spaced.write(&mut b);
            assert_eq!(a, b);
        }
    }

    /// A straight road along the x axis and the region around the origin the renderers cover.
    fn straight_road_with_region() -> (Map, Bounds) {
        let map = crate::test_maps::straight_road(Point::new(-100.0, 0.0), Point::new(100.0, 0.0));
        let mut region = Bounds::empty();
        region.extend(Point::new(-30.0, -30.0));
        region.extend(Point::new(30.0, 30.0));
        (map, region)
    }

    /// A 4 × 2 m car.
    fn car(id: u32, position: Point, heading_rad: f64, speed_mps: f64) -> Actor {
        Actor {
            id,
            kind: ActorKind::Car,
            position,
            heading_rad,
            speed_mps,
            length_m: 4.0,
            width_m: 2.0,
            lane: None,
            aggressiveness: None,
        }
    }

    /// The speed layer draws the same footprints as the obstacle layer, each as bright as
    /// its vehicle is fast, so a stopped car is in one layer and not the other.
    #[test]
    fn speed_layer_shades_each_footprint_by_its_speed() {
        let (map, region) = straight_road_with_region();
        let config = BevConfig {
            layers: vec![Layer::Obstacles, Layer::ObstacleSpeed],
            ..BevConfig::default()
        };
        let renderer = BevRenderer::new(&map, region, config).expect("renderer");
        let car = |id: u32, x: f64, speed_mps: f64| car(id, Point::new(x, 0.0), 0.0, speed_mps);
        let path = [Point::new(0.0, 0.0), Point::new(20.0, 0.0)];
        // The ego standing, a car 10 m ahead at half the full speed, one 20 m ahead at twice it.
        let scene = Scene {
            map: &map,
            time_s: 0.0,
            actors: vec![car(0, 0.0, 0.0), car(1, 10.0, 7.5), car(2, 20.0, 30.0)],
            ego: 0,
            ego_path: &path,
        };
        let mut out = Vec::new();
        renderer.render(&scene, &mut out);
        let plane = 84 * 84;
        let at = |layer: usize, metres_ahead: f64| {
            let row = (42.0 - metres_ahead * 84.0 / 50.0).floor() as usize;
            out[layer * plane + row * 84 + 42]
        };
        assert_eq!((at(0, 0.0), at(1, 0.0)), (255, 0));
        assert_eq!((at(0, 10.0), at(1, 10.0)), (255, 128));
        assert_eq!((at(0, 20.0), at(1, 20.0)), (255, 255));
        // Between the cars both layers are empty.
        assert_eq!((at(0, 15.0), at(1, 15.0)), (0, 0));
        assert_eq!(speed_brightness(-2.0, 15.0), 0);
        assert_eq!(speed_brightness(f64::NAN, 15.0), 0);
    }

    /// The straight road with a give-way line across it at x = 10 m.
    fn straight_road_with_line() -> (Map, Bounds) {
        use maps::model::{StopKind, StopLine, StopLineId, StopLineSource};
        let (mut map, region) = straight_road_with_region();
        let id = StopLineId(0);
        map.stop_lines.insert(
            id,
            StopLine {
                id,
                kind: StopKind::GiveWay,
                source: StopLineSource::OsmNode { id: 1 },
                lanes: Vec::new(),
                line: vec![Point::new(10.0, -3.0), Point::new(10.0, 3.0)],
                s_on_lane_m: 110.0,
            },
        );
        (map, region)
    }

    /// The sum and brightness-weighted mean row of `rows` of one layer of a `size` ×
    /// `size` frame.
    fn layer_mass(
        out: &[u8],
        layer: usize,
        size: usize,
        rows: std::ops::Range<usize>,
    ) -> (f64, f64) {
        let plane = &out[layer * size * size..(layer + 1) * size * size];
        let (mut sum, mut weighted) = (0.0, 0.0);
        for row in rows {
            for v in &plane[row * size..(row + 1) * size] {
                sum += f64::from(*v);
                weighted += f64::from(*v) * (row as f64 + 0.5);
            }
        }
        (sum, weighted / sum)
    }

    /// At 1.2 m a pixel a 0.8 m line falls between row centres in some frames. Antialiased
    /// it shows in every frame, about as bright in each, and a car ahead keeps its
    /// brightness while its centre of brightness follows it by fractions of a pixel.
    #[test]
    fn antialiasing_keeps_thin_lines_and_moves_cars_smoothly() {
        let (map, region) = straight_road_with_line();
        let view = |antialias: bool| BevConfig {
            width: 42,
            height: 42,
            layers: vec![Layer::StopLines, Layer::Obstacles],
            antialias,
            ..BevConfig::default()
        };
        let path = [Point::new(-20.0, 0.0), Point::new(20.0, 0.0)];
        let px_per_m = 42.0 / 50.0;
        let (mut line_missed, mut line_sums, mut car_sums) = (0, Vec::new(), Vec::new());
        let mut last_car_row = f64::NEG_INFINITY;
        for antialias in [false, true] {
            let renderer = BevRenderer::new(&map, region, view(antialias)).expect("renderer");
            let mut out = Vec::new();
            // The ego drives through 2.5 m in 0.1 m steps; a car stands at x = 12 m.
            for step in 0..25 {
                let x = -2.0 + 0.1 * f64::from(step);
                let scene = Scene {
                    map: &map,
                    time_s: 0.0,
                    actors: vec![
                        car(0, Point::new(x, 0.0), 0.0, 0.0),
                        car(1, Point::new(12.0, 0.0), 0.0, 0.0),
                    ],
                    ego: 0,
                    ego_path: &path,
                };
                renderer.render(&scene, &mut out);
                let (line_sum, _) = layer_mass(&out, 0, 42, 0..42);
                if !antialias {
                    line_missed += usize::from(line_sum == 0.0);
                    continue;
                }
                line_sums.push(line_sum);
                car_sums.push(layer_mass(&out, 1, 42, 0..42).0);
                // The car alone: the rows above the ego's footprint.
                let (_, car_row) = layer_mass(&out, 1, 42, 0..15);
                let expected = 21.0 - (12.0 - x) * px_per_m;
                assert!(
                    (car_row - expected).abs() < 0.1,
                    "car at row {car_row}, expected {expected}"
                );
                assert!(
                    car_row >= last_car_row,
                    "the car went back to row {car_row}"
                );
                last_car_row = car_row;
            }
        }
        assert!(
            line_missed > 0,
            "without antialiasing the line showed in every frame"
        );
        let spread = |v: &[f64]| {
            v.iter().fold((f64::INFINITY, 0.0_f64), |(lo, hi), s| {
                (lo.min(*s), hi.max(*s))
            })
        };
        let (lo, hi) = spread(&line_sums);
        assert!(lo > 0.0 && hi / lo < 1.25, "line brightness {lo} to {hi}");
        let (lo, hi) = spread(&car_sums);
        assert!(hi / lo < 1.05, "car brightness {lo} to {hi}");
        // Two 4 × 2 m cars cover 2 × 8 m² = 2 × 8 × 0.84² px².
        let area = 2.0 * 8.0 * px_per_m * px_per_m * 255.0;
        assert!((lo / area - 1.0).abs() < 0.05, "{lo} against {area}");
    }

    /// A straight east-going lane: ahead of a north-facing ego it shows on the right.
    #[test]
    fn ego_aligned_orientation() {
        let (map, region) = straight_road_with_region();
        let config = BevConfig::default();
        let renderer = BevRenderer::new(&map, region, config.clone()).expect("renderer");
        let actor = |x: f64, y: f64, heading: f64| car(0, Point::new(x, y), heading, 0.0);
        let path = [Point::new(0.0, 0.0), Point::new(20.0, 0.0)];
        // Ego facing east at the origin; another car 10 m ahead of it.
        let scene = Scene {
            map: &map,
            time_s: 0.0,
            actors: vec![actor(0.0, 0.0, 0.0), actor(10.0, 0.0, 0.0)],
            ego: 0,
            ego_path: &path,
        };
        let mut out = Vec::new();
        renderer.render(&scene, &mut out);
        let plane = 84 * 84;
        let at =
            |out: &[u8], layer: usize, row: usize, col: usize| out[layer * plane + row * 84 + col];
        // The road runs along the middle column band, forward = up.
        assert_eq!(at(&out, 0, 10, 42), 255);
        assert_eq!(at(&out, 0, 10, 10), 0);
        // Path ahead (rows above the middle), not behind.
        assert_eq!(at(&out, 1, 30, 42), 255);
        assert_eq!(at(&out, 1, 60, 42), 0);
        // The car 10 m ahead: 10 m × 1.68 px/m = 16.8 rows above the centre.
        assert_eq!(at(&out, 2, 42 - 17, 42), 255);
        assert_eq!(at(&out, 2, 42 + 17, 42), 0);
        // Ego facing north at (0, -10): the road is 10 m ahead, across the view.
        let scene = Scene {
            actors: vec![actor(0.0, -10.0, std::f64::consts::FRAC_PI_2)],
            ..scene
        };
        renderer.render(&scene, &mut out);
        assert_eq!(at(&out, 0, 42 - 17, 5), 255);
        assert_eq!(at(&out, 0, 42 - 17, 80), 255);
        assert_eq!(at(&out, 0, 42, 42), 0);
        // The path points east, which for a north-facing ego is to the right.
        assert_eq!(at(&out, 1, 42 - 17, 60), 255);
        assert_eq!(at(&out, 1, 42 - 17, 20), 0);
    }
}
