//! Rasters of a map window: drivable area, lane markings and lane ids.
//!
//! Later stages crop bird's-eye observations from these many times per second of simulated
//! driving, so the rasterizer is built for speed: the map is first cut into small simple
//! shapes (one quad per lane or connection segment, junction polygons, marking strokes),
//! each with a bounding box; shapes outside the window are dropped; the rest are binned into
//! bands of rows and every band is scanline-filled on its own (in parallel with rayon). Each
//! band paints its shapes in the same fixed order, so the output does not depend on the
//! number of threads.
//!
//! A pixel is set when its centre lies inside a shape (non-zero winding rule).

use std::borrow::Cow;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::geometry::{Bounds, Point, polyline_length};
use crate::model::{Map, MarkingKind};

/// Width of painted lane markings, metres.
pub const MARKING_WIDTH_M: f64 = 0.15;
/// Dashed markings: painted length, metres.
pub const DASH_ON_M: f64 = 3.0;
/// Dashed markings: gap length, metres.
pub const DASH_OFF_M: f64 = 6.0;
/// Rows per parallel work item: small enough to balance two to many cores, large enough
/// that binning shapes stays cheap.
const BAND_ROWS: usize = 32;
/// Windows smaller than this are painted on the calling thread.
const PARALLEL_MIN_PIXELS: usize = 1 << 18;

/// One band's share of the work: band index, its slice of each u8 layer and of the id
/// layer, and the shapes that reach it.
type BandWork<'a> = (
    usize,
    ((Vec<Option<&'a mut [u8]>>, Option<&'a mut [u32]>), Vec<u32>),
);

/// A raster window: `width` × `height` square pixels of `resolution_m`, lower-left corner
/// at `origin` (map metres). Row 0 is the top (largest y), column 0 the left (smallest x).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RasterSpec {
    pub origin: Point,
    pub resolution_m: f64,
    pub width: u32,
    pub height: u32,
}

impl RasterSpec {
    /// The smallest window at `resolution_m` that covers `bounds` (at least 1 × 1 pixel).
    pub fn covering(bounds: Bounds, resolution_m: f64) -> Self {
        let res = if resolution_m.is_finite() && resolution_m > 0.0 {
            resolution_m
        } else {
            1.0
        };
        if bounds.is_empty() || !bounds.min.is_finite() || !bounds.max.is_finite() {
            return RasterSpec {
                origin: Point::default(),
                resolution_m: res,
                width: 1,
                height: 1,
            };
        }
        let cells = |len: f64| ((len / res).ceil().max(1.0)).min(f64::from(u32::MAX)) as u32;
        RasterSpec {
            origin: bounds.min,
            resolution_m: res,
            width: cells(bounds.width()),
            height: cells(bounds.height()),
        }
    }

    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.width as usize * self.height as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Map metres of the top edge.
    fn top(&self) -> f64 {
        self.origin.y + f64::from(self.height) * self.resolution_m
    }

    /// Map point to continuous pixel coordinates (x to the right, y down from the top).
    fn pixel_of(&self, p: Point) -> Point {
        Point::new(
            (p.x - self.origin.x) / self.resolution_m,
            (self.top() - p.y) / self.resolution_m,
        )
    }

    /// Centre of pixel (`col`, `row`) in map metres.
    pub fn pixel_centre(&self, col: u32, row: u32) -> Point {
        Point::new(
            self.origin.x + (f64::from(col) + 0.5) * self.resolution_m,
            self.top() - (f64::from(row) + 0.5) * self.resolution_m,
        )
    }
}

/// Which layers to produce.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Layers {
    pub drivable: bool,
    pub markings: bool,
    pub lane_ids: bool,
}

impl Layers {
    pub const ALL: Layers = Layers {
        drivable: true,
        markings: true,
        lane_ids: true,
    };
    pub const DRIVABLE: Layers = Layers {
        drivable: true,
        markings: false,
        lane_ids: false,
    };
}

impl Default for Layers {
    fn default() -> Self {
        Layers::ALL
    }
}

/// Row-major layers of one window; a layer not asked for is `None`.
#[derive(Debug, Clone, PartialEq)]
pub struct Rasters {
    pub spec: RasterSpec,
    /// 1 where a car may drive: lanes, connections through junctions, junction areas.
    pub drivable: Option<Vec<u8>>,
    /// 1 on painted lane markings.
    pub markings: Option<Vec<u8>>,
    /// Lane id + 1 on each lane's area, 0 elsewhere (junction areas and connections
    /// included). Where lanes overlap, the larger lane id wins.
    pub lane_ids: Option<Vec<u32>>,
}

/// One shape to paint: a polygon (a range of the painter's points, in pixel coordinates),
/// the u8 layer and value it writes, and the id it writes into the u32 layer (0: none).
#[derive(Debug, Clone)]
struct Shape {
    pts: (u32, u32),
    layer: u8,
    value: u8,
    id: u32,
    rows: (usize, usize),
}

/// Collects shapes for one window, dropping those that cannot touch it, then paints them.
#[derive(Debug, Clone)]
pub(crate) struct Painter {
    spec: RasterSpec,
    /// Points of every shape, back to back (one allocation instead of one per quad).
    pts: Vec<Point>,
    shapes: Vec<Shape>,
}

/// Bounding box of some points (empty: +inf / -inf).
pub(crate) fn bbox<'a>(pts: impl IntoIterator<Item = &'a Point>) -> (Point, Point) {
    let mut lo = Point::new(f64::INFINITY, f64::INFINITY);
    let mut hi = Point::new(f64::NEG_INFINITY, f64::NEG_INFINITY);
    for p in pts {
        lo = Point::new(lo.x.min(p.x), lo.y.min(p.y));
        hi = Point::new(hi.x.max(p.x), hi.y.max(p.y));
    }
    (lo, hi)
}

impl Painter {
    pub(crate) fn new(spec: RasterSpec) -> Self {
        Painter {
            spec,
            pts: Vec::new(),
            shapes: Vec::new(),
        }
    }

    /// Whether a box (map metres), grown by `margin`, meets the window: the cheap test that
    /// lets a small crop of a big map skip almost everything.
    pub(crate) fn touches(&self, (lo, hi): (Point, Point), margin: f64) -> bool {
        let s = &self.spec;
        let (x1, y1) = (
            s.origin.x + f64::from(s.width) * s.resolution_m,
            s.origin.y + f64::from(s.height) * s.resolution_m,
        );
        hi.x + margin >= s.origin.x
            && lo.x - margin <= x1
            && hi.y + margin >= s.origin.y
            && lo.y - margin <= y1
    }

    /// Adds a polygon (map metres, any orientation); `layer` None writes only the id.
    pub(crate) fn polygon(&mut self, pts: &[Point], layer: Option<u8>, value: u8, id: u32) {
        if pts.len() < 3 {
            return;
        }
        let (w, h) = (f64::from(self.spec.width), f64::from(self.spec.height));
        let first = self.pts.len();
        let mut lo = Point::new(f64::INFINITY, f64::INFINITY);
        let mut hi = Point::new(f64::NEG_INFINITY, f64::NEG_INFINITY);
        for p in pts {
            let q = self.spec.pixel_of(*p);
            lo = Point::new(lo.x.min(q.x), lo.y.min(q.y));
            hi = Point::new(hi.x.max(q.x), hi.y.max(q.y));
            self.pts.push(q);
        }
        // Rows whose centre (row + 0.5) lies within [lo.y, hi.y], clipped to the window;
        // NaN fails every comparison and is dropped here too.
        let overlaps = hi.x > 0.0 && lo.x < w && hi.y > 0.0 && lo.y < h;
        let r0 = (lo.y - 0.5).ceil().max(0.0);
        let r1 = (hi.y - 0.5).floor().min(h - 1.0);
        if !overlaps || r0 > r1 {
            self.pts.truncate(first);
            return;
        }
        self.shapes.push(Shape {
            pts: (first as u32, self.pts.len() as u32),
            layer: layer.unwrap_or(u8::MAX),
            value,
            id,
            rows: (r0 as usize, r1 as usize),
        });
    }

    /// Adds a quad strip between two polylines of equal length (one quad per segment).
    pub(crate) fn strip(
        &mut self,
        left: &[Point],
        right: &[Point],
        layer: Option<u8>,
        value: u8,
        id: u32,
    ) {
        for i in 0..left.len().min(right.len()).saturating_sub(1) {
            self.polygon(
                &[left[i], left[i + 1], right[i + 1], right[i]],
                layer,
                value,
                id,
            );
        }
    }

    /// Adds a polyline stroked `width` metres wide: one rectangle per segment, plus a small
    /// square at each inner vertex so bends do not show notches.
    pub(crate) fn stroke(
        &mut self,
        line: &[Point],
        width: f64,
        layer: Option<u8>,
        value: u8,
        id: u32,
    ) {
        let h = width / 2.0;
        for w in line.windows(2) {
            let d = w[1].sub(w[0]);
            let len = d.norm();
            if len.is_nan() || len <= 0.0 {
                continue;
            }
            let n = d.normalized().perp().scale(h);
            self.polygon(
                &[w[0].add(n), w[1].add(n), w[1].sub(n), w[0].sub(n)],
                layer,
                value,
                id,
            );
        }
        for p in line.iter().skip(1).take(line.len().saturating_sub(2)) {
            let sq = [
                Point::new(p.x - h, p.y - h),
                Point::new(p.x + h, p.y - h),
                Point::new(p.x + h, p.y + h),
                Point::new(p.x - h, p.y + h),
            ];
            self.polygon(&sq, layer, value, id);
        }
    }

    /// Paints every shape into `n_layers` fresh u8 layers (and a u32 id layer when `ids`).
    pub(crate) fn paint(&self, n_layers: usize, ids: bool) -> (Vec<Vec<u8>>, Option<Vec<u32>>) {
        let mut layers: Vec<Vec<u8>> = vec![Vec::new(); n_layers];
        let mut id_layer = ids.then(Vec::new);
        let mut refs: Vec<Option<&mut Vec<u8>>> = layers.iter_mut().map(Some).collect();
        self.paint_into(&mut refs, id_layer.as_mut());
        (layers, id_layer)
    }

    /// Paints every shape, in the order added (later shapes overwrite earlier ones), into
    /// the given buffers: u8 layer `k` is `layers[k]` (None: not drawn). A buffer that
    /// already has the window's size is reused (cleared band by band, in parallel, which
    /// spares the page faults of a fresh allocation); any other is replaced.
    pub(crate) fn paint_into(
        &self,
        layers: &mut [Option<&mut Vec<u8>>],
        ids: Option<&mut Vec<u32>>,
    ) {
        let (w, h) = (self.spec.width as usize, self.spec.height as usize);
        let n = w * h;
        let mut clear_u8 = Vec::with_capacity(layers.len());
        for buf in layers.iter_mut() {
            clear_u8.push(match buf {
                Some(b) if b.len() == n => true,
                Some(b) => {
                    **b = vec![0; n];
                    false
                }
                None => false,
            });
        }
        let mut ids = ids;
        let clear_ids = match ids.as_mut() {
            Some(b) if b.len() == n => true,
            Some(b) => {
                **b = vec![0; n];
                false
            }
            None => false,
        };
        if n == 0 {
            return;
        }
        let n_bands = h.div_ceil(BAND_ROWS);
        // Shapes per band, in insertion order.
        let mut bins: Vec<Vec<u32>> = vec![Vec::new(); n_bands];
        for (i, s) in self.shapes.iter().enumerate() {
            for band in bins
                .iter_mut()
                .take(s.rows.1 / BAND_ROWS + 1)
                .skip(s.rows.0 / BAND_ROWS)
            {
                band.push(i as u32);
            }
        }
        // Split every output buffer into bands of rows, and hand each band its slices.
        let band_len = BAND_ROWS * w;
        let mut u8_bands: Vec<Vec<Option<&mut [u8]>>> = (0..n_bands)
            .map(|_| Vec::with_capacity(layers.len()))
            .collect();
        for layer in layers.iter_mut() {
            match layer {
                Some(buf) => {
                    for (b, chunk) in buf.chunks_mut(band_len).enumerate() {
                        u8_bands[b].push(Some(chunk));
                    }
                }
                None => u8_bands.iter_mut().for_each(|b| b.push(None)),
            }
        }
        let mut id_bands: Vec<Option<&mut [u32]>> = (0..n_bands).map(|_| None).collect();
        if let Some(idl) = ids {
            for (b, chunk) in idl.chunks_mut(band_len).enumerate() {
                id_bands[b] = Some(chunk);
            }
        }
        let work: Vec<_> = u8_bands
            .into_iter()
            .zip(id_bands)
            .zip(bins)
            .enumerate()
            .collect();
        let paint = |(b, ((mut u8s, mut idb), bin)): BandWork<'_>| {
            self.paint_band(b, &mut u8s, idb.as_deref_mut(), &bin, &clear_u8, clear_ids);
        };
        // Small windows (ego crops) are quicker on one thread than handed around.
        if n < PARALLEL_MIN_PIXELS {
            work.into_iter().for_each(paint);
        } else {
            work.into_par_iter().for_each(paint);
        }
    }

    /// Clears (when asked) and paints one band of rows.
    fn paint_band(
        &self,
        b: usize,
        u8s: &mut [Option<&mut [u8]>],
        mut idb: Option<&mut [u32]>,
        bin: &[u32],
        clear_u8: &[bool],
        clear_ids: bool,
    ) {
        let (w, h) = (self.spec.width as usize, self.spec.height as usize);
        for (buf, &clear) in u8s.iter_mut().zip(clear_u8) {
            if let Some(buf) = buf.as_mut().filter(|_| clear) {
                buf.fill(0);
            }
        }
        if let Some(buf) = idb.as_mut().filter(|_| clear_ids) {
            buf.fill(0);
        }
        let row0 = b * BAND_ROWS;
        let rows = (row0, (row0 + BAND_ROWS).min(h) - 1);
        let mut xs: Vec<(f64, i32)> = Vec::with_capacity(8);
        for &si in bin {
            let s = &self.shapes[si as usize];
            let pts = &self.pts[s.pts.0 as usize..s.pts.1 as usize];
            for row in s.rows.0.max(rows.0)..=s.rows.1.min(rows.1) {
                crossings(pts, row as f64 + 0.5, &mut xs);
                let off = (row - row0) * w;
                let mut winding = 0;
                for k in 0..xs.len() {
                    let was = winding;
                    winding += xs[k].1;
                    if was != 0 || winding == 0 {
                        continue;
                    }
                    // Entering: fill up to where the winding number drops back to zero.
                    let x0 = xs[k].0;
                    let mut wn = winding;
                    let mut x1 = x0;
                    for &(x, d) in &xs[k + 1..] {
                        wn += d;
                        if wn == 0 {
                            x1 = x;
                            break;
                        }
                    }
                    let c0 = (x0 - 0.5).ceil().max(0.0);
                    let c1 = (x1 - 0.5).ceil().min(w as f64);
                    if c0 >= c1 {
                        continue;
                    }
                    let (c0, c1) = (off + c0 as usize, off + c1 as usize);
                    if let Some(Some(buf)) = u8s.get_mut(usize::from(s.layer)) {
                        buf[c0..c1].fill(s.value);
                    }
                    if s.id != 0
                        && let Some(idb) = idb.as_mut()
                    {
                        idb[c0..c1].fill(s.id);
                    }
                }
            }
        }
    }
}

/// Where the edges of a closed polygon cross the horizontal line `y`, sorted by x, with
/// the edge's direction (+1 downwards, -1 upwards) for the winding rule.
fn crossings(pts: &[Point], y: f64, out: &mut Vec<(f64, i32)>) {
    out.clear();
    let n = pts.len();
    for i in 0..n {
        let (a, b) = (pts[i], pts[(i + 1) % n]);
        if (a.y <= y) != (b.y <= y) {
            let x = a.x + (y - a.y) * (b.x - a.x) / (b.y - a.y);
            out.push((x, if b.y > a.y { 1 } else { -1 }));
        }
    }
    if out.len() > 2 {
        out.sort_by(|p, q| p.0.total_cmp(&q.0));
    } else if out.len() == 2 && out[1].0 < out[0].0 {
        out.swap(0, 1);
    }
}

/// The pieces of a polyline that a dashed marking paints: `on` metres painted, `off` gap.
pub(crate) fn dashes(line: &[Point], on: f64, off: f64) -> Vec<Vec<Point>> {
    let total = polyline_length(line);
    let mut out = Vec::new();
    let mut s = 0.0;
    while s < total {
        out.push(crate::geometry::slice_polyline(
            line,
            s,
            (s + on).min(total),
        ));
        s += on + off;
    }
    out
}

/// Left and right boundaries with the same number of points, so they pair up into quads.
/// Boundaries of Lanelet2 lanes come from separate ways with their own vertices; those are
/// resampled at equal fractions of their lengths.
pub(crate) fn paired_boundaries<'a>(
    left: &'a [Point],
    right: &'a [Point],
) -> (Cow<'a, [Point]>, Cow<'a, [Point]>) {
    if left.len() == right.len() {
        return (Cow::Borrowed(left), Cow::Borrowed(right));
    }
    let n = left.len().max(right.len()).max(2);
    let at = |pts: &[Point]| {
        let total = polyline_length(pts);
        let mut out = Vec::with_capacity(n);
        let mut seg = 0;
        let mut acc = 0.0;
        for i in 0..n {
            let s = total * i as f64 / (n - 1) as f64;
            while seg + 2 < pts.len() && acc + pts[seg].distance(pts[seg + 1]) < s {
                acc += pts[seg].distance(pts[seg + 1]);
                seg += 1;
            }
            let (a, b) = (pts[seg], pts.get(seg + 1).copied().unwrap_or(pts[seg]));
            let len = a.distance(b);
            out.push(if len > 0.0 {
                a.lerp(b, ((s - acc) / len).clamp(0.0, 1.0))
            } else {
                a
            });
        }
        out
    };
    if left.is_empty() || right.is_empty() {
        return (Cow::Borrowed(&[]), Cow::Borrowed(&[]));
    }
    (Cow::Owned(at(left)), Cow::Owned(at(right)))
}

/// Corridor of a connection: its centre line offset half a lane width each way.
pub(crate) fn connection_corridor(centre: &[Point], width: f64) -> (Vec<Point>, Vec<Point>) {
    (
        crate::geometry::offset_polyline(centre, width / 2.0),
        crate::geometry::offset_polyline(centre, -width / 2.0),
    )
}

/// Width of the corridor drawn for a connection: the mean of its two lanes' widths.
pub(crate) fn connection_width(map: &Map, c: &crate::model::Connection) -> f64 {
    let w = |l| {
        map.lanes
            .get(l)
            .map(|l: &crate::model::Lane| l.width_m)
            .filter(|w| w.is_finite() && *w > 0.0)
    };
    match (w(&c.from), w(&c.to)) {
        (Some(a), Some(b)) => (a + b) / 2.0,
        (Some(a), None) | (None, Some(a)) => a,
        (None, None) => 3.0,
    }
}

const DRIVABLE: u8 = 0;
const MARKINGS: u8 = 1;

/// Rasterizes a map window. See [`Rasters`] for the meaning of each layer.
pub fn rasterize(map: &Map, spec: &RasterSpec, layers: Layers) -> Rasters {
    Rasterizer::new(map).rasterize(spec, layers)
}

/// Rasterizes the window `out.spec` into `out`, reusing its buffers when they already have
/// the window's size (see [`Rasterizer::rasterize_into`]).
pub fn rasterize_into(map: &Map, layers: Layers, out: &mut Rasters) {
    Rasterizer::new(map).rasterize_into(layers, out);
}

/// A map prepared for many rasters: the bounding box of every element is computed once,
/// so each window only looks at the elements that reach it. Worth it for crops: a 256 ×
/// 256 pixel crop then costs a scan of a few thousand boxes plus the painting.
#[derive(Debug, Clone)]
pub struct Rasterizer<'a> {
    map: &'a Map,
    junctions: Vec<(Point, Point)>,
    /// Boxes of connection corridors, grown to cover their offset mitres.
    connections: Vec<(Point, Point)>,
    lanes: Vec<(Point, Point)>,
    markings: Vec<(Point, Point)>,
}

/// A box grown by `m` on every side.
fn grow((lo, hi): (Point, Point), m: f64) -> (Point, Point) {
    (
        Point::new(lo.x - m, lo.y - m),
        Point::new(hi.x + m, hi.y + m),
    )
}

impl<'a> Rasterizer<'a> {
    pub fn new(map: &'a Map) -> Self {
        Rasterizer {
            map,
            junctions: map.junctions.values().map(|j| bbox(&j.polygon)).collect(),
            // Offset mitres reach at most four half-widths from the centre line.
            connections: map
                .connections
                .values()
                .map(|c| grow(bbox(&c.centre), 2.0 * connection_width(map, c)))
                .collect(),
            lanes: map
                .lanes
                .values()
                .map(|l| bbox(l.left.iter().chain(&l.right)))
                .collect(),
            markings: map
                .markings
                .iter()
                .map(|m| grow(bbox(&m.line), MARKING_WIDTH_M))
                .collect(),
        }
    }

    pub fn map(&self) -> &'a Map {
        self.map
    }

    /// Rasterizes a window into fresh buffers.
    pub fn rasterize(&self, spec: &RasterSpec, layers: Layers) -> Rasters {
        let mut out = Rasters {
            spec: *spec,
            drivable: None,
            markings: None,
            lane_ids: None,
        };
        self.rasterize_into(layers, &mut out);
        out
    }

    /// Rasterizes the window `out.spec` into `out`, reusing its buffers when they already
    /// have the window's size: the form for many crops in a row (no allocation, no page
    /// faults). Layers not asked for are set to `None`.
    pub fn rasterize_into(&self, layers: Layers, out: &mut Rasters) {
        let map = self.map;
        let mut p = Painter::new(out.spec);
        let drivable = layers.drivable.then_some(DRIVABLE);
        if layers.drivable {
            for (j, b) in map.junctions.values().zip(&self.junctions) {
                if p.touches(*b, 0.0) {
                    p.polygon(&j.polygon, drivable, 1, 0);
                }
            }
            for (c, b) in map.connections.values().zip(&self.connections) {
                if p.touches(*b, 0.0) {
                    let (l, r) = connection_corridor(&c.centre, connection_width(map, c));
                    p.strip(&l, &r, drivable, 1, 0);
                }
            }
        }
        if layers.drivable || layers.lane_ids {
            for (lane, b) in map.lanes.values().zip(&self.lanes) {
                if !p.touches(*b, 0.0) {
                    continue;
                }
                let (l, r) = paired_boundaries(&lane.left, &lane.right);
                let id = if layers.lane_ids {
                    lane.id.0.saturating_add(1)
                } else {
                    0
                };
                p.strip(&l, &r, drivable, 1, id);
            }
        }
        if layers.markings {
            let width = MARKING_WIDTH_M;
            for (m, b) in map.markings.iter().zip(&self.markings) {
                if !p.touches(*b, 0.0) {
                    continue;
                }
                if m.kind == MarkingKind::Dashed {
                    for d in dashes(&m.line, DASH_ON_M, DASH_OFF_M) {
                        p.stroke(&d, width, Some(MARKINGS), 1, 0);
                    }
                } else {
                    p.stroke(&m.line, width, Some(MARKINGS), 1, 0);
                }
            }
        }
        let take = |buf: Option<Vec<u8>>, want: bool| {
            if want {
                Some(buf.unwrap_or_default())
            } else {
                None
            }
        };
        let mut d = take(out.drivable.take(), layers.drivable);
        let mut m = take(out.markings.take(), layers.markings);
        let mut ids = if layers.lane_ids {
            Some(out.lane_ids.take().unwrap_or_default())
        } else {
            None
        };
        p.paint_into(&mut [d.as_mut(), m.as_mut()], ids.as_mut());
        out.drivable = d;
        out.markings = m;
        out.lane_ids = ids;
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::graph::test_maps;
    use crate::model::{Marking, RoadId};

    fn one_lane() -> Map {
        test_maps::straight_lanes(&[(Point::new(1.0, 5.0), Point::new(11.0, 5.0))], &[])
    }

    #[test]
    fn straight_lane_pixel_count() {
        let map = one_lane();
        let spec = RasterSpec {
            origin: Point::new(0.0, 0.0),
            resolution_m: 0.1,
            width: 120,
            height: 100,
        };
        let r = rasterize(&map, &spec, Layers::ALL);
        let n = r
            .drivable
            .as_ref()
            .unwrap()
            .iter()
            .filter(|&&v| v == 1)
            .count();
        // 10 m × 3.5 m at 0.1 m = 3500 pixels.
        assert!((n as f64 - 3500.0).abs() <= 35.0, "{n}");
        let ids = r.lane_ids.as_ref().unwrap();
        assert_eq!(ids.iter().filter(|&&v| v == 1).count(), n);
        // Row 0 is the top: the lane spans y 3.25..6.75, rows 32..67 from the top of y = 10.
        let row = |y: f64| ((10.0 - y) / 0.1) as usize;
        assert_eq!(ids[row(5.0) * 120 + 50], 1);
        assert_eq!(ids[row(8.0) * 120 + 50], 0);
        assert!(r.markings.as_ref().unwrap().iter().all(|&v| v == 0));
    }

    #[test]
    fn rotated_lane_and_clipping() {
        let map =
            test_maps::straight_lanes(&[(Point::new(-20.0, -20.0), Point::new(20.0, 20.0))], &[]);
        let spec = RasterSpec {
            origin: Point::new(-10.0, -10.0),
            resolution_m: 0.05,
            width: 400,
            height: 400,
        };
        let r = rasterize(&map, &spec, Layers::DRIVABLE);
        let n = r
            .drivable
            .as_ref()
            .unwrap()
            .iter()
            .filter(|&&v| v == 1)
            .count() as f64;
        // The band |y − x| ≤ d with d = 1.75·√2 inside the 20 m square: the square less two
        // corner triangles with legs 20 − d, so 20² − (20 − d)² m².
        let d = 1.75 * std::f64::consts::SQRT_2;
        let expect = (400.0 - (20.0 - d).powi(2)) / 0.0025;
        assert!((n - expect).abs() / expect < 0.01, "{n} vs {expect}");
        assert!(r.markings.is_none() && r.lane_ids.is_none());
    }

    #[test]
    fn markings_dashed_and_solid() {
        let mut map = one_lane();
        let line = vec![Point::new(0.0, 2.01), Point::new(9.0, 2.01)];
        map.markings.push(Marking {
            road: RoadId(0),
            kind: MarkingKind::Dashed,
            line: line.clone(),
        });
        let spec = RasterSpec {
            origin: Point::new(0.0, 0.0),
            resolution_m: 0.05,
            width: 400,
            height: 200,
        };
        let r = rasterize(&map, &spec, Layers::ALL);
        let dashed = r
            .markings
            .as_ref()
            .unwrap()
            .iter()
            .filter(|&&v| v == 1)
            .count() as f64;
        // One dash of 3 m (the next would start at 9 m, the end), 0.15 m wide: 3 × 0.15 / 0.0025.
        assert!((dashed - 180.0).abs() <= 10.0, "{dashed}");
        map.markings[0].kind = MarkingKind::SolidEdge;
        let r = rasterize(&map, &spec, Layers::ALL);
        let solid = r
            .markings
            .as_ref()
            .unwrap()
            .iter()
            .filter(|&&v| v == 1)
            .count() as f64;
        assert!((solid - 540.0).abs() <= 15.0, "{solid}");
    }

    #[test]
    fn same_output_with_one_or_two_threads() {
        let map = test_maps::square_loop();
        let spec = RasterSpec::covering(map.bounds(), 0.1);
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| rasterize(&map, &spec, Layers::ALL));
        let two = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap()
            .install(|| rasterize(&map, &spec, Layers::ALL));
        assert_eq!(one, two);
        // The loop's four lanes and the spur; overlapping corners go to the larger id.
        let ids = one.lane_ids.unwrap();
        for id in [0u32, 1, 2, 3, 4, 5] {
            assert!(ids.contains(&(id + 1)), "lane {id} missing");
        }
    }

    #[test]
    fn reused_buffers_give_the_same_rasters() {
        let map = test_maps::square_loop();
        let spec = RasterSpec::covering(map.bounds(), 0.2);
        let fresh = rasterize(&map, &spec, Layers::ALL);
        let mut out = rasterize(&map, &spec, Layers::ALL);
        // Dirty the buffers, then draw a shifted window and the first one again into them.
        out.drivable.as_mut().unwrap().fill(7);
        out.spec.origin.x += 3.0;
        rasterize_into(&map, Layers::ALL, &mut out);
        assert_ne!(out, fresh);
        out.spec = spec;
        rasterize_into(&map, Layers::ALL, &mut out);
        assert_eq!(out, fresh);
        rasterize_into(&map, Layers::DRIVABLE, &mut out);
        assert!(out.markings.is_none() && out.lane_ids.is_none());
        assert_eq!(out.drivable, fresh.drivable);
    }

    #[test]
    #[allow(clippy::print_stderr)]
    fn northwestern_same_output_with_one_or_two_threads() {
        let Some(map) = crate::graph::test_maps::shared_osm_map("northwestern_nu.osm.pbf") else {
            return;
        };
        let spec = RasterSpec::covering(map.bounds(), 1.0);
        assert!(spec.len() >= PARALLEL_MIN_PIXELS);
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| rasterize(&map, &spec, Layers::ALL))
        };
        let one = run(1);
        assert_eq!(one, run(2));
        let drivable = one
            .drivable
            .as_ref()
            .unwrap()
            .iter()
            .filter(|&&v| v == 1)
            .count();
        let ids = one
            .lane_ids
            .as_ref()
            .unwrap()
            .iter()
            .filter(|&&v| v != 0)
            .count();
        // Every lane longer than two pixels shows up in the id layer (shorter ones may fall
        // between pixel centres).
        let seen: std::collections::BTreeSet<u32> =
            one.lane_ids.as_ref().unwrap().iter().copied().collect();
        let missing: Vec<_> = map
            .lanes
            .values()
            .filter(|l| l.length_m > 2.0 && !seen.contains(&(l.id.0 + 1)))
            .map(|l| (l.id, l.length_m, l.width_m))
            .collect();
        assert!(missing.is_empty(), "{missing:?}");
        // Lanes cover most of the drivable area; junctions and connections the rest.
        assert!(ids > drivable / 2 && ids <= drivable, "{ids} {drivable}");
    }

    #[test]
    fn covering_and_pixel_centres() {
        let mut b = Bounds::empty();
        b.extend(Point::new(-1.0, 2.0));
        b.extend(Point::new(3.05, 4.0));
        let s = RasterSpec::covering(b, 0.5);
        assert_eq!((s.width, s.height), (9, 4));
        assert_eq!(s.pixel_centre(0, 0), Point::new(-0.75, 3.75));
        let empty = RasterSpec::covering(Bounds::empty(), 0.5);
        assert_eq!(empty.len(), 1);
    }

    #[test]
    fn unequal_boundaries_pair_up() {
        let left = vec![
            Point::new(0.0, 1.0),
            Point::new(5.0, 1.0),
            Point::new(10.0, 1.0),
        ];
        let right = vec![Point::new(0.0, -1.0), Point::new(10.0, -1.0)];
        let (l, r) = paired_boundaries(&left, &right);
        assert_eq!(l.len(), r.len());
        assert_eq!(r[1], Point::new(5.0, -1.0));
    }
}
