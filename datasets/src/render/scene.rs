//! The static world built once from a map and shared read-only by every view: ground
//! polygons (road surface, lane markings, kerbs, sidewalks) in painting order, procedural
//! buildings and trees beyond the sidewalks, and the places road users can stand, each
//! with a uniform grid so a view only looks at what is near it.
//!
//! Ground layers, painted in this order over grass: sidewalks, kerbs, road surfaces
//! (connections through junctions, junction areas, lanes), lane markings (the map's
//! dashed, centre and edge lines with the rasteriser's dash lengths), stop and give-way
//! lines. Centre lines exist in several painted styles (double yellow, single yellow,
//! dashed white); each view shows one of them.
//!
//! Scenery is procedural, drawn from the scenery seed: per road side a sidewalk (or none),
//! a grass verge, then buildings set back from the sidewalk and trees on the verge and in
//! front of buildings, each accepted only where a coarse occupancy grid says it keeps
//! clear of roads, sidewalks and other scenery.

use std::collections::BTreeMap;

use maps::geometry::{
    Bounds, Point, direction_at, offset_polyline, point_at, polyline_length, slice_polyline,
};
use maps::raster::{DASH_OFF_M, DASH_ON_M, MARKING_WIDTH_M};
use maps::{JunctionKind, LaneId, Map, MarkingKind, Road, StopKind};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::raster::fill_polygon;
use super::solids::{BoxExtent, Placement, Rgb, Solid, Tint, building, tree};
use crate::classes::Class;

/// What a piece of ground is made of: decides its class and its look.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Material {
    /// Grass and earth: the ground where nothing else is.
    Terrain = 0,
    Sidewalk = 1,
    Kerb = 2,
    Road = 3,
    WhitePaint = 4,
    YellowPaint = 5,
}

impl Material {
    pub const ALL: [Material; 6] = [
        Material::Terrain,
        Material::Sidewalk,
        Material::Kerb,
        Material::Road,
        Material::WhitePaint,
        Material::YellowPaint,
    ];

    /// The label class of this material.
    pub fn class(self) -> Class {
        match self {
            Material::Terrain | Material::Sidewalk | Material::Kerb => Class::Other,
            Material::Road => Class::Road,
            Material::WhitePaint | Material::YellowPaint => Class::LaneMarking,
        }
    }
}

/// How centre lines are painted in one view.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CentreLineStyle {
    DoubleYellow,
    SingleYellow,
    DashedWhite,
}

impl CentreLineStyle {
    pub const ALL: [CentreLineStyle; 3] = [
        CentreLineStyle::DoubleYellow,
        CentreLineStyle::SingleYellow,
        CentreLineStyle::DashedWhite,
    ];
    fn bit(self) -> u8 {
        match self {
            CentreLineStyle::DoubleYellow => 1,
            CentreLineStyle::SingleYellow => 2,
            CentreLineStyle::DashedWhite => 4,
        }
    }
}

/// One ground polygon: a range of [`MapScene::ground_points`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroundPolygon {
    pub material: Material,
    /// Centre-line styles it belongs to (bits of [`CentreLineStyle`]); 0 = every view.
    styles: u8,
    /// Painted markings can be worn away in a view.
    pub wearable: bool,
    start: u32,
    end: u32,
}

impl GroundPolygon {
    /// Whether a view painting centre lines in `style` shows it.
    pub fn shown_with(&self, style: CentreLineStyle) -> bool {
        self.styles == 0 || self.styles & style.bit() != 0
    }
}

/// Sizes of the procedural roadside, metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SceneryConfig {
    pub kerb_width_m: f64,
    /// Grass between kerb and sidewalk: uniform in this range per road side.
    pub verge_m: (f64, f64),
    pub sidewalk_m: (f64, f64),
    /// Share of road sides with a sidewalk (service roads: half as many).
    pub sidewalk_share: f64,
    /// Share of building plots along a road side that get a building (service roads: half).
    pub building_share: f64,
    pub building_setback_m: (f64, f64),
    pub building_height_m: (f64, f64),
    pub trees: bool,
    /// Street furniture at the roadside (lamp posts, sign posts with their signs, bollards),
    /// items per 100 m of road side; 0 draws none (and leaves the rest of the scenery as it
    /// is: furniture is placed last, from the same generator).
    pub furniture_per_100m: f64,
}

impl Default for SceneryConfig {
    fn default() -> Self {
        SceneryConfig {
            kerb_width_m: 0.2,
            verge_m: (0.0, 2.5),
            sidewalk_m: (1.5, 3.0),
            sidewalk_share: 0.85,
            building_share: 0.7,
            building_setback_m: (2.0, 10.0),
            building_height_m: (4.0, 22.0),
            trees: true,
            furniture_per_100m: 0.0,
        }
    }
}

/// Stop lines are this wide; give-way lines are dashed and narrower.
const STOP_LINE_WIDTH_M: f64 = 0.45;
const GIVE_WAY_WIDTH_M: f64 = 0.3;
const GIVE_WAY_DASH_M: (f64, f64) = (0.6, 0.3);
/// Double centre lines: two lines of this width this far apart (centre to centre).
const DOUBLE_LINE_WIDTH_M: f64 = 0.1;
const DOUBLE_LINE_SPACING_M: f64 = 0.22;
/// Grid cell of the spatial indexes, metres.
const GRID_CELL_M: f64 = 24.0;
/// Occupancy grid used to keep scenery off roads: finest cell, and most cells.
const OCCUPANCY_CELL_M: f64 = 1.0;
const OCCUPANCY_MAX_CELLS: f64 = 6e7;

/// Ids of things whose bounding boxes meet each cell of a uniform grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    origin: Point,
    cell: f64,
    cols: usize,
    rows: usize,
    cells: Vec<Vec<u32>>,
}

impl Grid {
    fn new(bounds: Bounds, cell: f64) -> Self {
        let (origin, cols, rows) = if bounds.is_empty() {
            (Point::default(), 1, 1)
        } else {
            (
                bounds.min,
                ((bounds.width() / cell).ceil() as usize).max(1),
                ((bounds.height() / cell).ceil() as usize).max(1),
            )
        };
        Grid {
            origin,
            cell,
            cols,
            rows,
            cells: vec![Vec::new(); cols * rows],
        }
    }

    /// Cell ranges covering a box, clamped to the grid.
    fn range(&self, (lo, hi): (Point, Point)) -> Option<((usize, usize), (usize, usize))> {
        let f = |v: f64, o: f64, n: usize| {
            ((v - o) / self.cell).floor().clamp(0.0, (n - 1) as f64) as usize
        };
        if !(lo.is_finite() && hi.is_finite()) {
            return None;
        }
        Some((
            (
                f(lo.x, self.origin.x, self.cols),
                f(hi.x, self.origin.x, self.cols),
            ),
            (
                f(lo.y, self.origin.y, self.rows),
                f(hi.y, self.origin.y, self.rows),
            ),
        ))
    }

    fn insert(&mut self, bbox: (Point, Point), id: u32) {
        if let Some(((c0, c1), (r0, r1))) = self.range(bbox) {
            for r in r0..=r1 {
                for c in c0..=c1 {
                    self.cells[r * self.cols + c].push(id);
                }
            }
        }
    }

    /// Ids whose boxes may meet `bbox`, ascending, each once.
    pub fn query(&self, bbox: (Point, Point), out: &mut Vec<u32>) {
        out.clear();
        if let Some(((c0, c1), (r0, r1))) = self.range(bbox) {
            for r in r0..=r1 {
                for c in c0..=c1 {
                    out.extend_from_slice(&self.cells[r * self.cols + c]);
                }
            }
        }
        out.sort_unstable();
        out.dedup();
    }
}

/// Bounding box of some points.
pub fn bbox_of(pts: &[Point]) -> (Point, Point) {
    let mut b = Bounds::empty();
    for p in pts {
        b.extend(*p);
    }
    (b.min, b.max)
}

/// A building or tree with its bounding box.
#[derive(Debug, Clone, PartialEq)]
pub struct Prop {
    pub solid: Solid,
    pub bbox: (Point, Point),
}

/// A place on a lane end where people cross the road.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CrossingSpot {
    pub point: Point,
    /// Unit direction of the lane's travel there.
    pub along: Point,
    pub half_width_m: f64,
}

/// The static world of one map; see the module docs.
#[derive(Debug, Clone)]
pub struct MapScene {
    pub ground: Vec<GroundPolygon>,
    ground_points: Vec<Point>,
    ground_boxes: Vec<(Point, Point)>,
    ground_grid: Grid,
    pub props: Vec<Prop>,
    prop_grid: Grid,
    /// Centre lines of sidewalks, in the direction of their road edge.
    pub sidewalk_lines: Vec<Vec<Point>>,
    sidewalk_grid: Grid,
    /// Car lanes long enough to stand on, with their cumulative lengths for sampling.
    pub car_lanes: Vec<LaneId>,
    car_lane_cumulative_m: Vec<f64>,
    lane_grid: Grid,
    pub crossings: Vec<CrossingSpot>,
    crossing_grid: Grid,
}

/// Lanes shorter than this are not used for poses or vehicles.
const MIN_LANE_M: f64 = 4.0;

impl MapScene {
    /// Builds the ground, the scenery (from `scenery_seed`) and the indexes of `map`.
    pub fn build(map: &Map, config: &SceneryConfig, scenery_seed: u64) -> Self {
        let mut b = map.bounds();
        if !b.is_empty() {
            // Scenery reaches beyond the outermost lanes.
            let m = 80.0;
            b.extend(Point::new(b.min.x - m, b.min.y - m));
            b.extend(Point::new(b.max.x + m, b.max.y + m));
        }
        let mut rng = ChaCha8Rng::seed_from_u64(scenery_seed);
        let sides = road_sides(map, config, &mut rng);
        let mut ground = GroundBuilder::default();
        ground.roadside(&sides);
        ground.road_surfaces(map);
        ground.markings(map);
        let ground_grid = {
            let mut g = Grid::new(b, GRID_CELL_M);
            for (i, bb) in ground.boxes.iter().enumerate() {
                g.insert(*bb, i as u32);
            }
            g
        };
        let props = if b.is_empty() {
            Vec::new()
        } else {
            let mut occupancy = Occupancy::new(b);
            occupancy.paint_ground(&ground);
            place_scenery(&sides, config, &mut occupancy, &mut rng)
        };
        let mut prop_grid = Grid::new(b, GRID_CELL_M);
        for (i, p) in props.iter().enumerate() {
            prop_grid.insert(p.bbox, i as u32);
        }
        let sidewalk_lines: Vec<Vec<Point>> = sides
            .iter()
            .filter(|s| s.sidewalk_m > 0.0)
            .map(|s| offset_polyline(&s.edge, -(s.sidewalk_from_m() + s.sidewalk_m / 2.0)))
            .filter(|l| l.len() >= 2)
            .collect();
        let mut sidewalk_grid = Grid::new(b, GRID_CELL_M);
        for (i, l) in sidewalk_lines.iter().enumerate() {
            sidewalk_grid.insert(bbox_of(l), i as u32);
        }
        let car_lanes: Vec<LaneId> = map
            .car_lanes()
            .filter(|l| l.centre.len() >= 2 && polyline_length(&l.centre) >= MIN_LANE_M)
            .map(|l| l.id)
            .collect();
        let mut acc = 0.0;
        let mut car_lane_cumulative_m = Vec::with_capacity(car_lanes.len());
        let mut lane_grid = Grid::new(b, GRID_CELL_M);
        for (i, id) in car_lanes.iter().enumerate() {
            if let Some(l) = map.lanes.get(id) {
                acc += polyline_length(&l.centre);
                lane_grid.insert(bbox_of(&l.centre), i as u32);
            }
            car_lane_cumulative_m.push(acc);
        }
        let crossings = crossing_spots(map);
        let mut crossing_grid = Grid::new(b, GRID_CELL_M);
        for (i, c) in crossings.iter().enumerate() {
            crossing_grid.insert((c.point, c.point), i as u32);
        }
        MapScene {
            ground: ground.polygons,
            ground_points: ground.points,
            ground_boxes: ground.boxes,
            ground_grid,
            props,
            prop_grid,
            sidewalk_lines,
            sidewalk_grid,
            car_lanes,
            car_lane_cumulative_m,
            lane_grid,
            crossings,
            crossing_grid,
        }
    }

    /// The points of a ground polygon.
    pub fn ground_points(&self, g: &GroundPolygon) -> &[Point] {
        &self.ground_points[g.start as usize..g.end as usize]
    }

    /// Ground polygons whose boxes meet `bbox` and pass `keep` (a test on the box), in
    /// painting order.
    pub fn ground_near(
        &self,
        bbox: (Point, Point),
        keep: impl Fn((Point, Point)) -> bool,
        out: &mut Vec<u32>,
    ) {
        self.ground_grid.query(bbox, out);
        out.retain(|&i| keep(self.ground_boxes[i as usize]));
    }

    /// Props (buildings, trees) whose boxes meet `bbox`, in id order.
    pub fn props_near(&self, bbox: (Point, Point), out: &mut Vec<u32>) {
        self.prop_grid.query(bbox, out);
    }

    /// Indexes into [`Self::car_lanes`] of lanes whose centre line's box meets `bbox`.
    pub fn lanes_near(&self, bbox: (Point, Point), out: &mut Vec<u32>) {
        self.lane_grid.query(bbox, out);
    }

    /// Indexes into [`Self::sidewalk_lines`] near `bbox`.
    pub fn sidewalks_near(&self, bbox: (Point, Point), out: &mut Vec<u32>) {
        self.sidewalk_grid.query(bbox, out);
    }

    /// Indexes into [`Self::crossings`] near `bbox`.
    pub fn crossings_near(&self, bbox: (Point, Point), out: &mut Vec<u32>) {
        self.crossing_grid.query(bbox, out);
    }

    /// The car lane (index into [`Self::car_lanes`]) and arc length at `t` ∈ [0, 1) of
    /// the total car lane length: a uniform draw of `t` is a uniform place on the lanes.
    pub fn lane_at_fraction(&self, t: f64) -> Option<(usize, f64)> {
        let total = *self.car_lane_cumulative_m.last()?;
        let target = t.clamp(0.0, 1.0) * total;
        let i = self
            .car_lane_cumulative_m
            .partition_point(|&c| c <= target)
            .min(self.car_lanes.len() - 1);
        let start = if i == 0 {
            0.0
        } else {
            self.car_lane_cumulative_m[i - 1]
        };
        Some((i, target - start))
    }
}

/// One side of a road: its outer edge (outwards = to the right of the polyline) and what
/// lies beyond it.
#[derive(Debug, Clone)]
struct RoadSide {
    edge: Vec<Point>,
    kerb_m: f64,
    verge_m: f64,
    /// 0: no sidewalk.
    sidewalk_m: f64,
    /// Whether to line it with buildings at all (service roads less often).
    building_share: f64,
}

impl RoadSide {
    fn sidewalk_from_m(&self) -> f64 {
        self.kerb_m + self.verge_m
    }
    /// Where the built-up land may start, from the edge.
    fn plots_from_m(&self) -> f64 {
        self.sidewalk_from_m() + self.sidewalk_m
    }
}

/// The two outer edges of a road's carriageway, each turned so that outwards is its right.
fn road_edges(map: &Map, road: &Road) -> Vec<Vec<Point>> {
    let lane = |id: Option<&LaneId>| id.and_then(|id| map.lanes.get(id));
    let mut edges = Vec::new();
    let (f, b) = (&road.lanes_forward, &road.lanes_backward);
    match (lane(f.last()), lane(b.last())) {
        (Some(fl), Some(bl)) => {
            edges.push(fl.right.clone());
            edges.push(bl.right.clone());
        }
        (Some(out), None) | (None, Some(out)) => {
            edges.push(out.right.clone());
            let inner = if f.is_empty() { b.first() } else { f.first() };
            if let Some(inner) = lane(inner) {
                edges.push(inner.left.iter().rev().copied().collect());
            }
        }
        (None, None) => {}
    }
    edges.retain(|e| e.len() >= 2);
    edges
}

/// Every road side with its drawn widths.
fn road_sides(map: &Map, config: &SceneryConfig, rng: &mut ChaCha8Rng) -> Vec<RoadSide> {
    let mut sides = Vec::new();
    for road in map.roads.values() {
        let minor = matches!(road.highway.as_str(), "service" | "track" | "living_street");
        let factor = if minor { 0.5 } else { 1.0 };
        for edge in road_edges(map, road) {
            let has_sidewalk = rng.random::<f64>() < config.sidewalk_share * factor;
            let sidewalk_m = if has_sidewalk {
                uniform(rng, config.sidewalk_m)
            } else {
                0.0
            };
            sides.push(RoadSide {
                edge,
                kerb_m: config.kerb_width_m,
                verge_m: uniform(rng, config.verge_m),
                sidewalk_m,
                building_share: config.building_share * factor,
            });
        }
    }
    sides
}

/// A uniform draw in `(lo, hi)` (just `lo` when the range is empty or reversed).
pub fn uniform(rng: &mut impl Rng, (lo, hi): (f64, f64)) -> f64 {
    if hi > lo {
        rng.random_range(lo..hi)
    } else {
        lo
    }
}

/// Collects ground polygons in painting order.
#[derive(Debug, Default)]
struct GroundBuilder {
    polygons: Vec<GroundPolygon>,
    points: Vec<Point>,
    boxes: Vec<(Point, Point)>,
}

impl GroundBuilder {
    fn polygon(&mut self, pts: &[Point], material: Material, styles: u8) {
        if pts.len() < 3 || pts.iter().any(|p| !p.is_finite()) {
            return;
        }
        let start = self.points.len() as u32;
        self.points.extend_from_slice(pts);
        self.boxes.push(bbox_of(pts));
        self.polygons.push(GroundPolygon {
            material,
            styles,
            wearable: matches!(material, Material::WhitePaint | Material::YellowPaint),
            start,
            end: self.points.len() as u32,
        });
    }

    /// One quad per segment between two polylines of equal length (else one ribbon).
    fn strip(&mut self, left: &[Point], right: &[Point], material: Material, styles: u8) {
        if left.len() == right.len() {
            for i in 0..left.len().saturating_sub(1) {
                self.polygon(
                    &[left[i], left[i + 1], right[i + 1], right[i]],
                    material,
                    styles,
                );
            }
        } else {
            let ring: Vec<Point> = left.iter().chain(right.iter().rev()).copied().collect();
            self.polygon(&ring, material, styles);
        }
    }

    /// A band between lateral offsets `from` and `to` (left positive) of a polyline.
    fn band(&mut self, line: &[Point], (from, to): (f64, f64), material: Material, styles: u8) {
        let (a, b) = (offset_polyline(line, to), offset_polyline(line, from));
        self.strip(&a, &b, material, styles);
    }

    /// A painted line `width` wide centred `shift` to the left of `line`, solid or dashed.
    fn paint(
        &mut self,
        line: &[Point],
        width: f64,
        shift: f64,
        dashes: Option<(f64, f64)>,
        material: Material,
        styles: u8,
    ) {
        let band = (shift - width / 2.0, shift + width / 2.0);
        match dashes {
            None => self.band(line, band, material, styles),
            Some((on, off)) => {
                let total = polyline_length(line);
                let mut s = 0.0;
                while s < total {
                    let dash = slice_polyline(line, s, (s + on).min(total));
                    self.band(&dash, band, material, styles);
                    s += on + off;
                }
            }
        }
    }

    fn roadside(&mut self, sides: &[RoadSide]) {
        for s in sides.iter().filter(|s| s.sidewalk_m > 0.0) {
            let from = s.sidewalk_from_m();
            self.band(
                &s.edge,
                (-(from + s.sidewalk_m), -from),
                Material::Sidewalk,
                0,
            );
        }
        for s in sides {
            self.band(&s.edge, (-s.kerb_m, 0.0), Material::Kerb, 0);
        }
    }

    fn road_surfaces(&mut self, map: &Map) {
        for c in map.connections.values() {
            let width = [c.from, c.to]
                .iter()
                .filter_map(|l| map.lanes.get(l))
                .map(|l| l.width_m)
                .filter(|w| w.is_finite() && *w > 0.0)
                .fold((0.0, 0), |(s, n), w| (s + w, n + 1));
            let width = if width.1 > 0 {
                width.0 / f64::from(width.1)
            } else {
                3.0
            };
            self.band(&c.centre, (-width / 2.0, width / 2.0), Material::Road, 0);
        }
        for j in map.junctions.values() {
            self.polygon(&j.polygon, Material::Road, 0);
        }
        for lane in map.lanes.values() {
            self.strip(&lane.left, &lane.right, Material::Road, 0);
        }
    }

    fn markings(&mut self, map: &Map) {
        let dashed = Some((DASH_ON_M, DASH_OFF_M));
        let double = CentreLineStyle::DoubleYellow.bit();
        let single = CentreLineStyle::SingleYellow.bit();
        let white = CentreLineStyle::DashedWhite.bit();
        for m in map.markings.iter().filter(|m| m.line.len() >= 2) {
            match m.kind {
                MarkingKind::Dashed => {
                    self.paint(
                        &m.line,
                        MARKING_WIDTH_M,
                        0.0,
                        dashed,
                        Material::WhitePaint,
                        0,
                    );
                }
                MarkingKind::SolidEdge => {
                    self.paint(&m.line, MARKING_WIDTH_M, 0.0, None, Material::WhitePaint, 0);
                }
                MarkingKind::CentreLine => {
                    let half = DOUBLE_LINE_SPACING_M / 2.0;
                    for shift in [-half, half] {
                        self.paint(
                            &m.line,
                            DOUBLE_LINE_WIDTH_M,
                            shift,
                            None,
                            Material::YellowPaint,
                            double,
                        );
                    }
                    self.paint(
                        &m.line,
                        MARKING_WIDTH_M,
                        0.0,
                        None,
                        Material::YellowPaint,
                        single,
                    );
                    self.paint(
                        &m.line,
                        MARKING_WIDTH_M,
                        0.0,
                        dashed,
                        Material::WhitePaint,
                        white,
                    );
                }
            }
        }
        for s in map.stop_lines.values().filter(|s| s.line.len() >= 2) {
            match s.kind {
                StopKind::Stop => {
                    self.paint(
                        &s.line,
                        STOP_LINE_WIDTH_M,
                        0.0,
                        None,
                        Material::WhitePaint,
                        0,
                    );
                }
                StopKind::GiveWay => self.paint(
                    &s.line,
                    GIVE_WAY_WIDTH_M,
                    0.0,
                    Some(GIVE_WAY_DASH_M),
                    Material::WhitePaint,
                    0,
                ),
            }
        }
    }
}

/// What a cell of the occupancy grid holds.
const FREE: u8 = 0;
const ROAD: u8 = 1;
const WALK: u8 = 2;
const TAKEN: u8 = 3;

/// A coarse raster of what the ground is used for, to keep scenery off it.
#[derive(Debug)]
struct Occupancy {
    origin: Point,
    cell: f64,
    cols: usize,
    rows: usize,
    cells: Vec<u8>,
}

impl Occupancy {
    fn new(b: Bounds) -> Self {
        let area = b.width() * b.height();
        let cell = OCCUPANCY_CELL_M.max((area / OCCUPANCY_MAX_CELLS).sqrt());
        let cols = ((b.width() / cell).ceil() as usize).max(1);
        let rows = ((b.height() / cell).ceil() as usize).max(1);
        Occupancy {
            origin: b.min,
            cell,
            cols,
            rows,
            cells: vec![FREE; cols * rows],
        }
    }

    fn to_grid(&self, p: Point) -> (f64, f64) {
        (
            (p.x - self.origin.x) / self.cell,
            (p.y - self.origin.y) / self.cell,
        )
    }

    /// What the cell at `p` holds; `None` outside the grid.
    fn at(&self, p: Point) -> Option<u8> {
        let (x, y) = self.to_grid(p);
        if x < 0.0 || y < 0.0 || x >= self.cols as f64 || y >= self.rows as f64 {
            return None;
        }
        Some(self.cells[y as usize * self.cols + x as usize])
    }

    /// Every cell a polygon touches (its centre inside, or the polygon grown by one cell).
    fn cells_of(&self, pts: &[Point], grow_m: f64, mut f: impl FnMut(usize)) {
        let centre = pts
            .iter()
            .fold(Point::default(), |a, p| a.add(*p))
            .scale(1.0 / pts.len().max(1) as f64);
        let grown: Vec<(f64, f64)> = pts
            .iter()
            .map(|p| {
                let d = p.sub(centre);
                let n = d.norm();
                let q = if n > 0.0 {
                    p.add(d.scale(grow_m / n))
                } else {
                    *p
                };
                self.to_grid(q)
            })
            .collect();
        let cols = self.cols;
        fill_polygon(
            &grown,
            self.cols,
            self.rows,
            &mut Vec::new(),
            |row, c0, c1| {
                for c in c0..c1 {
                    f(row * cols + c);
                }
            },
        );
    }

    fn paint_ground(&mut self, ground: &GroundBuilder) {
        let half_cell = self.cell * 0.75;
        for g in &ground.polygons {
            let value = match g.material {
                Material::Sidewalk => WALK,
                Material::Terrain => continue,
                _ => ROAD,
            };
            let pts = &ground.points[g.start as usize..g.end as usize];
            let mut hits = Vec::new();
            self.cells_of(pts, half_cell, |i| hits.push(i));
            for i in hits {
                if self.cells[i] != ROAD {
                    self.cells[i] = value;
                }
            }
        }
    }

    /// Claims the cells under `pts` (grown by `clearance_m`) if none holds any of
    /// `blocked`; returns whether it did.
    fn claim(&mut self, pts: &[Point], clearance_m: f64, blocked: &[u8]) -> bool {
        let mut cells = Vec::new();
        self.cells_of(pts, clearance_m, |i| cells.push(i));
        if cells.is_empty() || cells.iter().any(|&i| blocked.contains(&self.cells[i])) {
            return false;
        }
        for i in cells {
            self.cells[i] = TAKEN;
        }
        true
    }
}

/// Wall colours: brick, sandstone, render, concrete, glass-grey.
const WALLS: [Rgb; 7] = [
    [0.55, 0.27, 0.2],
    [0.72, 0.62, 0.45],
    [0.82, 0.8, 0.74],
    [0.6, 0.6, 0.58],
    [0.45, 0.5, 0.55],
    [0.68, 0.45, 0.32],
    [0.9, 0.88, 0.82],
];
const ROOFS: [Rgb; 3] = [[0.3, 0.3, 0.32], [0.42, 0.36, 0.33], [0.5, 0.5, 0.5]];
const LEAVES: [Rgb; 4] = [
    [0.2, 0.38, 0.14],
    [0.28, 0.42, 0.16],
    [0.16, 0.3, 0.12],
    [0.35, 0.45, 0.2],
];
const TRUNK: Rgb = [0.3, 0.22, 0.15];

/// A colour from `palette`, lighter or darker by up to `amount`.
fn pick_colour(rng: &mut ChaCha8Rng, palette: &[Rgb], amount: f32) -> Rgb {
    let c = palette[rng.random_range(0..palette.len())];
    let k = 1.0 + amount * (rng.random::<f32>() * 2.0 - 1.0);
    [
        (c[0] * k).clamp(0.0, 1.0),
        (c[1] * k).clamp(0.0, 1.0),
        (c[2] * k).clamp(0.0, 1.0),
    ]
}

/// Buildings and trees along every road side.
fn place_scenery(
    sides: &[RoadSide],
    config: &SceneryConfig,
    occupancy: &mut Occupancy,
    rng: &mut ChaCha8Rng,
) -> Vec<Prop> {
    let mut props = Vec::new();
    let mut push = |solid: Solid| {
        let bbox = bbox_of(&solid.footprint());
        props.push(Prop { solid, bbox });
    };
    for side in sides {
        let len = polyline_length(&side.edge);
        // Buildings: plots one after another, each a building or left open.
        let mut s = uniform(rng, (0.0, 6.0));
        while s < len {
            let along = uniform(rng, (8.0, 28.0));
            let depth = uniform(rng, (8.0, 22.0));
            let setback = uniform(rng, config.building_setback_m);
            let u: f64 = rng.random();
            let (h0, h1) = config.building_height_m;
            let height = h0 + (h1 - h0) * u * u;
            let wall = pick_colour(rng, &WALLS, 0.12);
            let roof = pick_colour(rng, &ROOFS, 0.1);
            let build = rng.random::<f64>() < side.building_share;
            let mid = s + along / 2.0;
            if build && mid < len {
                let p = point_at(&side.edge, mid);
                let dir = direction_at(&side.edge, mid);
                let out = dir.perp().scale(-1.0);
                let centre = p.add(out.scale(side.plots_from_m() + setback + depth / 2.0));
                let frame = Placement::new(centre, dir.y.atan2(dir.x));
                let rect =
                    frame.rectangle((-along / 2.0, along / 2.0), (-depth / 2.0, depth / 2.0));
                if occupancy.claim(&rect, 1.0, &[ROAD, WALK, TAKEN]) {
                    push(building(&frame, (along, depth), height, wall, roof));
                }
            }
            s += along + uniform(rng, (2.0, 8.0));
        }
        if !config.trees {
            continue;
        }
        // Trees: on a wide enough verge, and between the sidewalk and the plots.
        let verge_tree = side.verge_m >= 1.2;
        let mut s = uniform(rng, (0.0, 10.0));
        while s < len {
            let height = uniform(rng, (4.5, 11.0));
            let radius = uniform(rng, (1.2, 3.0));
            let leaves = pick_colour(rng, &LEAVES, 0.15);
            let on_verge = verge_tree && rng.random::<f64>() < 0.5;
            let offset = if on_verge {
                side.kerb_m + side.verge_m / 2.0
            } else {
                side.plots_from_m() + uniform(rng, (1.0, 4.0))
            };
            let plant = rng.random::<f64>() < 0.6;
            if plant {
                let p = point_at(&side.edge, s);
                let out = direction_at(&side.edge, s).perp().scale(-1.0);
                let centre = p.add(out.scale(offset));
                // The trunk's cell must be free; the crown may overhang sidewalks but not
                // roads.
                let trunk_ring = square(centre, 0.4);
                let crown_ring = square(centre, radius * 0.8);
                if crown_fits(occupancy, &crown_ring)
                    && occupancy.claim(&trunk_ring, 0.3, &[ROAD, WALK, TAKEN])
                {
                    push(tree(centre, height, radius, TRUNK, leaves));
                }
            }
            s += uniform(rng, (7.0, 16.0));
        }
    }
    if config.furniture_per_100m > 0.0 {
        for side in sides {
            place_furniture(side, config.furniture_per_100m, occupancy, rng, &mut push);
        }
    }
    props
}

/// Paint of posts and signs: galvanised grey, dark green, black; sign faces.
const POSTS: [Rgb; 4] = [
    [0.55, 0.56, 0.56],
    [0.2, 0.25, 0.22],
    [0.12, 0.12, 0.13],
    [0.7, 0.7, 0.68],
];
const SIGNS: [Rgb; 6] = [
    [0.85, 0.85, 0.85],
    [0.1, 0.25, 0.6],
    [0.75, 0.12, 0.1],
    [0.9, 0.75, 0.15],
    [0.15, 0.45, 0.2],
    [0.95, 0.95, 0.95],
];

/// Lamp posts, sign posts and bollards along one road side, at the kerb edge of its
/// sidewalk (or of the verge when it has none), `per_100m` on average.
fn place_furniture(
    side: &RoadSide,
    per_100m: f64,
    occupancy: &mut Occupancy,
    rng: &mut ChaCha8Rng,
    push: &mut impl FnMut(Solid),
) {
    let len = polyline_length(&side.edge);
    let mean_gap = 100.0 / per_100m;
    let mut s = uniform(rng, (0.0, mean_gap));
    while s < len {
        let kind = rng.random_range(0..10);
        let colour = pick_colour(rng, &POSTS, 0.15);
        let offset = side.kerb_m + uniform(rng, (0.25, 0.6));
        let p = point_at(&side.edge, s);
        let dir = direction_at(&side.edge, s);
        let out = dir.perp().scale(-1.0);
        let centre = p.add(out.scale(offset));
        let frame = Placement::new(centre, dir.y.atan2(dir.x));
        let mut solid = Solid::new(Class::Other);
        match kind {
            // A lamp post: a tall pole with an arm over the road.
            0..=3 => {
                let height = uniform(rng, (5.0, 9.0));
                let r = uniform(rng, (0.07, 0.14));
                solid.add_cylinder(centre, (r, r * 0.7), (0.0, height), 6, colour, Tint::None);
                let reach = uniform(rng, (0.8, 2.2));
                solid.add_box(
                    &frame,
                    BoxExtent {
                        x: (-0.06, 0.06),
                        y: (0.0, reach),
                        z: (height - 0.12, height),
                    },
                    colour,
                    Tint::None,
                );
            }
            // A sign post with one or two plates facing the traffic.
            4..=7 => {
                let height = uniform(rng, (2.2, 3.4));
                let r = uniform(rng, (0.035, 0.06));
                solid.add_cylinder(centre, (r, r), (0.0, height), 6, colour, Tint::None);
                let plates = rng.random_range(1..=2);
                let mut top = height;
                for _ in 0..plates {
                    let size = uniform(rng, (0.45, 0.9));
                    let face = pick_colour(rng, &SIGNS, 0.1);
                    solid.add_box(
                        &frame,
                        BoxExtent {
                            x: (-0.03, 0.03),
                            y: (-size / 2.0, size / 2.0),
                            z: (top - size, top),
                        },
                        face,
                        Tint::None,
                    );
                    top -= size + 0.05;
                }
            }
            // A bollard or a bin.
            _ => {
                let height = uniform(rng, (0.6, 1.1));
                let r = uniform(rng, (0.08, 0.3));
                solid.add_cylinder(centre, (r, r), (0.0, height), 8, colour, Tint::None);
            }
        }
        // The pole stands within the road's grown cells; a metre further out must be off
        // every road (not inside a junction or another road), and no scenery there.
        let beyond = p.add(out.scale(offset + 1.0));
        if occupancy
            .at(beyond)
            .is_some_and(|c| c != ROAD && c != TAKEN)
            && occupancy.at(centre).is_some_and(|c| c != TAKEN)
        {
            occupancy.claim(&square(centre, 0.15), 0.0, &[]);
            push(solid);
        }
        s += uniform(rng, (0.3 * mean_gap, 1.7 * mean_gap));
    }
}

/// Whether a tree crown over `ring` stays off roads and other scenery.
fn crown_fits(occupancy: &Occupancy, ring: &[Point]) -> bool {
    let mut ok = true;
    occupancy.cells_of(ring, 0.0, |i| {
        ok &= !matches!(occupancy.cells[i], ROAD | TAKEN);
    });
    ok
}

/// An axis-aligned square of half-side `half` around `c`.
fn square(c: Point, half: f64) -> [Point; 4] {
    [
        Point::new(c.x - half, c.y - half),
        Point::new(c.x + half, c.y - half),
        Point::new(c.x + half, c.y + half),
        Point::new(c.x - half, c.y + half),
    ]
}

/// Lane ends that run into an intersection: where people cross.
fn crossing_spots(map: &Map) -> Vec<CrossingSpot> {
    let intersections: BTreeMap<_, _> = map
        .junctions
        .values()
        .filter(|j| j.kind == JunctionKind::Intersection)
        .map(|j| (j.id, ()))
        .collect();
    map.car_lanes()
        .filter(|l| intersections.contains_key(&l.to_junction) && l.centre.len() >= 2)
        .map(|l| {
            let len = polyline_length(&l.centre);
            let s = (len - 2.0).max(0.0);
            CrossingSpot {
                point: point_at(&l.centre, s),
                along: direction_at(&l.centre, s),
                half_width_m: l.width_m / 2.0,
            }
        })
        .collect()
}
