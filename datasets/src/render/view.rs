//! One camera view: what each pixel sees ([`render_view`]), its label ([`label_image`])
//! and its colour ([`colour_image`]).
//!
//! Steps: the ground polygons in the camera's wedge are painted in layer order; cast
//! shadows of buildings, trees and road users are marked on the ground; then every face
//! near enough is drawn with the depth test. Each pixel ends up with one surface id, so the
//! label is the class of that surface and the colour is that surface lit and textured —
//! the two can never disagree about which object a pixel shows.

use maps::geometry::Point;

use super::camera::{Camera, Vec3};
use super::look::Look;
use super::placement::Wedge;
use super::raster::{Frame, Rasteriser, Scratch, SurfaceId};
use super::scene::{GroundPolygon, MapScene, Material};
use super::solids::{Rgb, Solid, Tint};
use crate::classes::Class;

/// What a surface id stands for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SurfaceKind {
    Sky,
    Ground(Material),
    /// A face of a solid, with its lit colour.
    Face(Rgb),
    /// A building wall with its lit colour and its horizontal direction, for windows.
    Facade {
        lit: Rgb,
        along: Point,
    },
}

/// The surface id of a ground material.
pub fn ground_surface(m: Material) -> SurfaceId {
    1 + m as SurfaceId
}

/// Buffers of one view, reused from view to view by a worker.
#[derive(Debug, Default)]
pub struct ViewBuffers {
    pub frame: Frame,
    raster: Scratch,
    ids: Vec<u32>,
    pub surfaces: Vec<SurfaceKind>,
    pub classes: Vec<u8>,
}

/// Cheap per-element randomness from a seed (per marking piece, per pixel).
pub fn hash64(seed: u64, i: u64) -> u64 {
    sim::seed::derive_seed(seed, 0, i)
}

/// A uniform number in [0, 1) from a hash.
fn unit(h: u64) -> f64 {
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Whether a view with `look` shows ground polygon `i`: centre lines in its style only,
/// and worn-away marking pieces not at all (the same test for the camera and the top-down
/// view, so both agree).
pub fn ground_shown(look: &Look, wear_seed: u64, i: u32, g: &GroundPolygon) -> bool {
    g.shown_with(look.centre_lines)
        && !(g.wearable && unit(hash64(wear_seed, u64::from(i))) < look.paint_missing)
}

/// The horizontal half-angle of the camera's view on the ground, with a small margin:
/// the widest of its four corner rays.
pub fn ground_half_angle(camera: &Camera) -> f64 {
    let fwd = Point::new(camera.forward.x, camera.forward.y).normalized();
    let (w, h) = (f64::from(camera.width), f64::from(camera.height));
    let mut widest: f64 = 0.0;
    for (u, v) in [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)] {
        let r = camera.ray(u, v);
        let d = Point::new(r.x, r.y);
        if fwd.dot(d) <= 1e-9 {
            return std::f64::consts::PI;
        }
        widest = widest.max(fwd.cross(d).atan2(fwd.dot(d)).abs());
    }
    (widest + 3f64.to_radians()).min(std::f64::consts::PI)
}

/// The camera's wedge on the ground out to `range_m`.
pub fn view_wedge(camera: &Camera, range_m: f64) -> Wedge {
    Wedge {
        apex: Point::new(camera.position.x, camera.position.y),
        heading_rad: camera.forward.y.atan2(camera.forward.x),
        half_angle_rad: ground_half_angle(camera),
        range_m,
    }
}

/// Whether a box may show inside the wedge: not entirely beyond its range, behind either
/// of its side edges.
pub fn box_in_wedge(w: &Wedge, (lo, hi): (Point, Point)) -> bool {
    let dx = (lo.x - w.apex.x).max(0.0).max(w.apex.x - hi.x);
    let dy = (lo.y - w.apex.y).max(0.0).max(w.apex.y - hi.y);
    if dx.hypot(dy) > w.range_m {
        return false;
    }
    if w.half_angle_rad >= 80f64.to_radians() {
        return true;
    }
    let corners = [lo, Point::new(hi.x, lo.y), hi, Point::new(lo.x, hi.y)];
    let edge = |a: f64| Point::new(a.cos(), a.sin());
    let left = edge(w.heading_rad + w.half_angle_rad);
    let right = edge(w.heading_rad - w.half_angle_rad);
    let all_left = corners.iter().all(|c| left.cross(c.sub(w.apex)) > 0.0);
    let all_right = corners.iter().all(|c| right.cross(c.sub(w.apex)) < 0.0);
    !(all_left || all_right)
}

/// The bounding box of a wedge.
pub fn wedge_bbox(w: &Wedge) -> (Point, Point) {
    let mut pts = vec![w.apex];
    let n = 16;
    for k in 0..=n {
        let a = w.heading_rad - w.half_angle_rad + 2.0 * w.half_angle_rad * k as f64 / n as f64;
        pts.push(w.apex.add(Point::new(a.cos(), a.sin()).scale(w.range_m)));
    }
    let (lo, hi) = super::scene::bbox_of(&pts);
    // The arc bulges a little beyond its chords.
    let m = 0.05 * w.range_m;
    (
        Point::new(lo.x - m, lo.y - m),
        Point::new(hi.x + m, hi.y + m),
    )
}

/// What a view shows.
#[derive(Debug, Clone, Copy)]
pub struct ViewInput<'a> {
    pub scene: &'a MapScene,
    pub camera: &'a Camera,
    pub look: &'a Look,
    /// Road users (and anything else placed for this view).
    pub actors: &'a [Solid],
    /// Ground and scenery beyond this distance are left out, metres.
    pub draw_distance_m: f64,
    /// Seed of the per-piece paint wear.
    pub wear_seed: u64,
}

/// Colour multiplier of a tint group in a look.
fn tint_of(look: &Look, t: Tint) -> Rgb {
    match t {
        Tint::None => [1.0; 3],
        Tint::Building => look.building_tint,
        Tint::Vegetation => look.vegetation_tint,
    }
}

/// Renders which surface each pixel sees into `buf.frame`, and the table of surfaces
/// (`buf.surfaces`, `buf.classes`).
pub fn render_view(input: &ViewInput<'_>, buf: &mut ViewBuffers) {
    let ViewInput {
        scene,
        camera,
        look,
        ..
    } = *input;
    buf.surfaces.clear();
    buf.classes.clear();
    buf.surfaces.push(SurfaceKind::Sky);
    buf.classes.push(Class::Other as u8);
    for m in Material::ALL {
        buf.surfaces.push(SurfaceKind::Ground(m));
        buf.classes.push(m.class() as u8);
    }
    let wedge = view_wedge(camera, input.draw_distance_m);
    let region = wedge_bbox(&wedge);
    let mut r = Rasteriser::new(
        camera,
        &mut buf.frame,
        &mut buf.raster,
        ground_surface(Material::Terrain),
    );

    scene.ground_near(region, |b| box_in_wedge(&wedge, b), &mut buf.ids);
    for &i in &buf.ids {
        let g = &scene.ground[i as usize];
        if ground_shown(look, input.wear_seed, i, g) {
            r.ground_polygon(scene.ground_points(g), ground_surface(g.material));
        }
    }

    // Props may cast shadows into the view from beside or behind it: look a little wider.
    let light = look.to_sun().scale(-1.0);
    let shadow_reach = (30.0 / look.sun_elevation_deg.to_radians().tan()).min(80.0);
    let (lo, hi) = region;
    let wide = (
        Point::new(lo.x - shadow_reach, lo.y - shadow_reach),
        Point::new(hi.x + shadow_reach, hi.y + shadow_reach),
    );
    let shadow_wedge = Wedge {
        range_m: wedge.range_m + shadow_reach,
        half_angle_rad: (wedge.half_angle_rad + 0.6).min(std::f64::consts::PI),
        apex: wedge
            .apex
            .sub(Point::new(wedge.heading_rad.cos(), wedge.heading_rad.sin()).scale(shadow_reach)),
        ..wedge
    };
    scene.props_near(wide, &mut buf.ids);
    let props: Vec<&Solid> = buf
        .ids
        .iter()
        .map(|&i| &scene.props[i as usize])
        .filter(|p| box_in_wedge(&shadow_wedge, p.bbox))
        .map(|p| &p.solid)
        .collect();
    if look.shadow > 0.0 {
        for solid in props.iter().copied().chain(input.actors) {
            let shadow = solid.shadow(light);
            if shadow.len() >= 3 {
                r.shadow_polygon(&shadow);
            }
        }
    }

    for solid in props.iter().copied().chain(input.actors) {
        for f in &solid.faces {
            let id = buf.surfaces.len() as SurfaceId;
            let tint = tint_of(look, f.tint);
            let light = look.light(f.normal);
            let lit = [
                f.colour[0] * tint[0] * light,
                f.colour[1] * tint[1] * light,
                f.colour[2] * tint[2] * light,
            ];
            if r.face(solid.face_points(f), f.normal, id) {
                buf.surfaces
                    .push(if f.tint == Tint::Building && f.normal.z.abs() < 0.1 {
                        SurfaceKind::Facade {
                            lit,
                            along: Point::new(-f.normal.y, f.normal.x).normalized(),
                        }
                    } else {
                        SurfaceKind::Face(lit)
                    });
                buf.classes.push(solid.class as u8);
            }
        }
    }
    debug_assert!(
        buf.frame
            .surface
            .iter()
            .all(|&s| (s as usize) < buf.surfaces.len())
    );
}

/// The label of the view: the class of the surface at each pixel centre.
pub fn label_image(buf: &ViewBuffers, out: &mut Vec<u8>) {
    out.clear();
    out.extend(buf.frame.surface.iter().map(|&s| {
        buf.classes
            .get(s as usize)
            .copied()
            .unwrap_or(Class::Other as u8)
    }));
}

/// Tileable value noise for textures: smoothed random values on a 256 × 256 torus.
#[derive(Debug, Clone, PartialEq)]
pub struct NoiseTexture {
    values: Vec<f32>,
}

const NOISE_SIZE: usize = 256;

impl Default for NoiseTexture {
    fn default() -> Self {
        Self::new()
    }
}

impl NoiseTexture {
    /// The same texture every time (a fixed seed): texture is not part of what varies.
    pub fn new() -> Self {
        let n = NOISE_SIZE;
        let mut v: Vec<f32> = (0..n * n)
            .map(|i| unit(hash64(0x5EED_7E47, i as u64)) as f32)
            .collect();
        // Two box blurs with wrap-around: soft grain, still tileable.
        for _ in 0..2 {
            let src = v.clone();
            for y in 0..n {
                for x in 0..n {
                    let mut s = 0.0;
                    for dy in [n - 1, 0, 1] {
                        for dx in [n - 1, 0, 1] {
                            s += src[((y + dy) % n) * n + (x + dx) % n];
                        }
                    }
                    v[y * n + x] = s / 9.0;
                }
            }
        }
        // Stretch back to roughly [0, 1] around 0.5.
        for x in &mut v {
            *x = (0.5 + (*x - 0.5) * 3.0).clamp(0.0, 1.0);
        }
        NoiseTexture { values: v }
    }

    /// The largest integer not above `v` (what `floor` gives, without a libm call per texel).
    fn floor(v: f64) -> i64 {
        let i = v as i64;
        if (i as f64) > v { i - 1 } else { i }
    }

    fn texel(&self, x: i64, y: i64) -> f32 {
        let m = NOISE_SIZE as i64 - 1;
        self.values[((y & m) * NOISE_SIZE as i64 + (x & m)) as usize]
    }

    /// Nearest texel at texture coordinates (`x`, `y`), in [0, 1].
    pub fn nearest(&self, x: f64, y: f64) -> f32 {
        self.texel(Self::floor(x), Self::floor(y))
    }

    /// Bilinear sample at texture coordinates (`x`, `y`), in [0, 1].
    pub fn smooth(&self, x: f64, y: f64) -> f32 {
        let (ix, iy) = (Self::floor(x), Self::floor(y));
        let (tx, ty) = ((x - ix as f64) as f32, (y - iy as f64) as f32);
        let a = self.texel(ix, iy) + (self.texel(ix + 1, iy) - self.texel(ix, iy)) * tx;
        let b = self.texel(ix, iy + 1) + (self.texel(ix + 1, iy + 1) - self.texel(ix, iy + 1)) * tx;
        a + (b - a) * ty
    }
}

/// Texture scales: grain texels per metre, blotch texels per metre.
const GRAIN_PER_M: f64 = 14.0;
const BLOTCH_PER_M: f64 = 0.3;

/// The colour image of the view (RGB8, row-major) from its surfaces and the look.
pub fn colour_image(
    input: &ViewInput<'_>,
    buf: &ViewBuffers,
    noise: &NoiseTexture,
    noise_seed: u64,
    out: &mut Vec<u8>,
) {
    let ViewInput { camera, look, .. } = *input;
    let frame = &buf.frame;
    let (w, h) = (frame.width, frame.height);
    out.clear();
    out.resize(w * h * 3, 0);
    let ground_light = look.light(Vec3::new(0.0, 0.0, 1.0));
    let materials: Vec<Rgb> = Material::ALL.iter().map(|&m| look.material(m)).collect();
    let step = camera.right.scale(1.0 / camera.fx);
    let horizon0 = camera.horizon_v(0.0);
    let horizon_slope = camera.horizon_v(1.0) - horizon0;
    let sky_span = 0.6 * h as f64;
    for row in 0..h {
        let v = row as f64 + 0.5;
        let mut ray = camera.ray(0.5, v);
        for col in 0..w {
            let i = row * w + col;
            let s = frame.surface[i];
            let inv = f64::from(frame.inv_depth[i]);
            let mut c = match buf.surfaces.get(s as usize) {
                Some(SurfaceKind::Ground(m)) => {
                    let z = 1.0 / inv.max(1e-9);
                    let p = camera.position.add(ray.scale(z));
                    let base = materials[*m as usize];
                    let grain_amp = look.grain * (6.0 / z).clamp(0.15, 1.0) as f32;
                    let grain = (noise.nearest(p.x * GRAIN_PER_M, p.y * GRAIN_PER_M) - 0.5) * 2.0;
                    let blotch = (noise.smooth(p.x * BLOTCH_PER_M, p.y * BLOTCH_PER_M) - 0.5) * 2.0;
                    let k = (1.0 + grain_amp * grain) * (1.0 + look.blotches * blotch);
                    let mut c = base.map(|b| b * k);
                    if matches!(m, Material::WhitePaint | Material::YellowPaint) {
                        let fade = (look.paint_fade + 0.35 * blotch).clamp(0.0, 0.9);
                        let road = materials[Material::Road as usize];
                        for (ch, r) in c.iter_mut().zip(road) {
                            *ch += (r - *ch) * fade;
                        }
                    }
                    let light = if frame.shadow[i] != 0 {
                        ground_light * (1.0 - look.shadow)
                    } else {
                        ground_light
                    };
                    c.map(|ch| ch * light)
                }
                Some(SurfaceKind::Face(lit)) => *lit,
                Some(SurfaceKind::Facade { lit, along }) => {
                    let z = 1.0 / inv.max(1e-9);
                    let p = camera.position.add(ray.scale(z));
                    facade(*lit, p.x * along.x + p.y * along.y, p.z, z, look)
                }
                Some(SurfaceKind::Sky) | None => {
                    let hv = horizon0 + horizon_slope * col as f64;
                    let t = ((hv - v) / sky_span).clamp(0.0, 1.0).sqrt() as f32;
                    let (a, b) = (look.sky_horizon, look.sky_zenith);
                    [
                        a[0] + (b[0] - a[0]) * t,
                        a[1] + (b[1] - a[1]) * t,
                        a[2] + (b[2] - a[2]) * t,
                    ]
                }
            };
            if inv > 0.0 {
                let fog = (1.0 - (-look.fog_per_m / inv).exp()) as f32;
                for (ch, f) in c.iter_mut().zip(look.fog) {
                    *ch += (f - *ch) * fog;
                }
            }
            let n = if look.sensor_noise > 0.0 {
                (unit(hash64(noise_seed, i as u64)) as f32 - 0.5) * 2.0 * look.sensor_noise
            } else {
                0.0
            };
            for (k, ch) in c.iter().enumerate() {
                out[i * 3 + k] = (ch * look.exposure * 255.0 + n).clamp(0.0, 255.0) as u8;
            }
            ray = ray.add(step);
        }
    }
    if let Some(rain) = &look.rain {
        draw_rain(out, w, h, rain);
    }
}

/// Storeys and window bays of building walls, metres: windows fill part of each.
const STOREY_M: f64 = 3.4;
const BAY_M: f64 = 3.0;
const WINDOW_SILL_M: (f64, f64) = (0.9, 2.4);
const WINDOW_BAY_M: (f64, f64) = (0.7, 2.3);
/// Beyond this depth window rows melt into the wall's mean colour (they would alias).
const FACADE_FADE_M: (f64, f64) = (60.0, 140.0);

/// A wall's colour at horizontal position `s` and height `h`: dark glass reflecting the
/// sky in a grid of windows above the ground floor's plinth, plain wall between.
fn facade(lit: Rgb, s: f64, h: f64, depth: f64, look: &Look) -> Rgb {
    let glass = [
        0.25 * lit[0] + 0.35 * look.sky_horizon[0],
        0.25 * lit[1] + 0.35 * look.sky_horizon[1],
        0.25 * lit[2] + 0.4 * look.sky_horizon[2],
    ];
    let in_storey = h.rem_euclid(STOREY_M);
    let in_bay = s.rem_euclid(BAY_M);
    let window = h > 0.5
        && (WINDOW_SILL_M.0..WINDOW_SILL_M.1).contains(&in_storey)
        && (WINDOW_BAY_M.0..WINDOW_BAY_M.1).contains(&in_bay);
    // Share of a wall that is glass, for the far mix.
    let share = ((WINDOW_SILL_M.1 - WINDOW_SILL_M.0) / STOREY_M * (WINDOW_BAY_M.1 - WINDOW_BAY_M.0)
        / BAY_M) as f32;
    let far =
        ((depth - FACADE_FADE_M.0) / (FACADE_FADE_M.1 - FACADE_FADE_M.0)).clamp(0.0, 1.0) as f32;
    let near = if window { glass } else { lit };
    let mean = [0, 1, 2].map(|k| lit[k] + (glass[k] - lit[k]) * share);
    [0, 1, 2].map(|k| near[k] + (mean[k] - near[k]) * far)
}

/// Rain streaks: thin bright lines blended over the image.
fn draw_rain(rgb: &mut [u8], w: usize, h: usize, rain: &super::look::Rain) {
    let (sin, cos) = f64::from(rain.angle_deg).to_radians().sin_cos();
    let len = f64::from(rain.length_px) * h as f64;
    let a = rain.opacity;
    for k in 0..u64::from(rain.streaks) {
        let hx = hash64(rain.seed, 3 * k);
        let hy = hash64(rain.seed, 3 * k + 1);
        let hl = hash64(rain.seed, 3 * k + 2);
        let (x0, y0) = (unit(hx) * w as f64, unit(hy) * h as f64);
        let l = len * (0.5 + unit(hl));
        let steps = l.ceil() as usize;
        for t in 0..steps {
            let x = x0 + sin * t as f64;
            let y = y0 + cos * t as f64;
            if x < 0.0 || y < 0.0 || x >= w as f64 || y >= h as f64 {
                break;
            }
            let i = (y as usize * w + x as usize) * 3;
            for ch in &mut rgb[i..i + 3] {
                *ch = (f32::from(*ch) + (220.0 - f32::from(*ch)) * a) as u8;
            }
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::render::camera::{CameraConfig, CameraPose};
    use crate::render::scene::SceneryConfig;
    use crate::render::solids::{Actor, ActorColours, ActorKind};
    use maps::geometry::offset_polyline;
    use maps::{
        Direction, DrivingSide, Junction, JunctionId, JunctionKind, Lane, LaneId, LatLon, Map,
        Projection, Road, RoadId, RoadSource,
    };

    /// One straight 200 m one-lane road along the x axis, 3.5 m wide.
    pub(crate) fn straight_road() -> Map {
        let mut map = Map::new(
            Projection::local(LatLon::new(0.0, 0.0)),
            DrivingSide::Right,
            "car",
        );
        let centre = vec![Point::new(0.0, 0.0), Point::new(200.0, 0.0)];
        for (id, p) in [(0, centre[0]), (1, centre[1])] {
            map.junctions.insert(
                JunctionId(id),
                Junction {
                    id: JunctionId(id),
                    kind: JunctionKind::DeadEnd,
                    osm_node_id: None,
                    point: p,
                    polygon: vec![],
                    roads: vec![RoadId(0)],
                    control: None,
                },
            );
        }
        map.roads.insert(
            RoadId(0),
            Road {
                id: RoadId(0),
                source: RoadSource::OsmWay,
                osm_way_ids: vec![1],
                highway: "residential".into(),
                name: None,
                reference_line: centre.clone(),
                start_junction: JunctionId(0),
                end_junction: JunctionId(1),
                lanes_forward: vec![LaneId(0)],
                lanes_backward: vec![],
                speed_limit_kmh: 30.0,
                speed_limit_is_default: false,
                is_roundabout: false,
                allows_cars: true,
            },
        );
        map.lanes.insert(
            LaneId(0),
            Lane {
                id: LaneId(0),
                road: RoadId(0),
                direction: Direction::Forward,
                index_from_centre: 0,
                left: offset_polyline(&centre, 1.75),
                right: offset_polyline(&centre, -1.75),
                centre,
                width_m: 3.5,
                length_m: 200.0,
                speed_limit_kmh: 30.0,
                turns: vec![],
                from_junction: JunctionId(0),
                to_junction: JunctionId(1),
            },
        );
        map
    }

    fn bare() -> SceneryConfig {
        SceneryConfig {
            sidewalk_share: 0.0,
            building_share: 0.0,
            trees: false,
            ..SceneryConfig::default()
        }
    }

    fn camera(width: u32, height: u32) -> Camera {
        Camera::new(
            &CameraConfig {
                width,
                height,
                height_m: 1.6,
                pitch_deg: 6.0,
                hfov_deg: 69.0,
            },
            &CameraPose {
                position: Vec3::new(10.0, 0.4, 1.6),
                yaw: 0.03,
                pitch: 6f64.to_radians(),
                roll: 0.01,
            },
        )
    }

    fn render(scene: &MapScene, cam: &Camera, actors: &[Solid]) -> (ViewBuffers, Vec<u8>) {
        let look = Look::plain();
        let input = ViewInput {
            scene,
            camera: cam,
            look: &look,
            actors,
            draw_distance_m: 300.0,
            wear_seed: 1,
        };
        let mut buf = ViewBuffers::default();
        render_view(&input, &mut buf);
        let mut label = Vec::new();
        label_image(&buf, &mut label);
        (buf, label)
    }

    #[test]
    fn a_flat_road_is_labelled_where_pixel_rays_hit_the_lane() {
        let map = straight_road();
        let scene = MapScene::build(&map, &bare(), 0);
        let cam = camera(160, 120);
        let (_, label) = render(&scene, &cam, &[]);
        let ground = cam.ground_plane();
        let (mut road, mut checked) = (0, 0);
        for row in 0..120 {
            for col in 0..160 {
                let (u, v) = (col as f64 + 0.5, row as f64 + 0.5);
                let inv = ground.at(u, v);
                let got = label[row * 160 + col];
                if inv <= 0.0 {
                    assert_eq!(got, Class::Other as u8, "sky at {col},{row}");
                    continue;
                }
                let hit = cam.position.add(cam.ray(u, v).scale(1.0 / inv));
                // Pixel centres within a hair of an edge could go either way in floating point.
                let margin = 1e-7 / inv;
                let inside_y = hit.y.abs() < 1.75 - margin;
                let outside_y = hit.y.abs() > 1.75 + margin;
                let inside_x = hit.x > margin && hit.x < 200.0 - margin;
                let outside_x = hit.x < -margin || hit.x > 200.0 + margin;
                if inside_y && inside_x {
                    assert_eq!(got, Class::Road as u8, "road at {col},{row} hit {hit:?}");
                    road += 1;
                } else if outside_y || outside_x {
                    assert_eq!(
                        got,
                        Class::Other as u8,
                        "off-road at {col},{row} hit {hit:?}"
                    );
                } else {
                    continue;
                }
                checked += 1;
            }
        }
        assert!(road > 1000 && checked > 8000, "{road} {checked}");
    }

    #[test]
    fn a_car_ahead_hides_a_person_behind_it() {
        let map = straight_road();
        let scene = MapScene::build(&map, &bare(), 0);
        let cam = camera(160, 120);
        let grey = ActorColours {
            main: [0.5; 3],
            second: [0.2; 3],
            third: [0.1; 3],
        };
        let car = Actor {
            kind: ActorKind::Vehicle,
            position: Point::new(20.0, 0.4),
            heading_rad: 0.0,
            length_m: 4.5,
            width_m: 1.8,
            height_m: 1.5,
        };
        let person = Actor {
            kind: ActorKind::Pedestrian,
            position: Point::new(24.0, 0.4),
            heading_rad: 0.0,
            length_m: 0.4,
            width_m: 0.55,
            height_m: 1.4,
        };
        let count = |label: &[u8], c: Class| label.iter().filter(|&&v| v == c as u8).count();
        let (_, alone) = render(&scene, &cam, &[person.solid(&grey)]);
        assert!(count(&alone, Class::Human) > 10, "the person alone is seen");
        let solids = [person.solid(&grey), car.solid(&grey)];
        let (buf, both) = render(&scene, &cam, &solids);
        assert_eq!(count(&both, Class::Human), 0, "the car hides the person");
        assert!(count(&both, Class::Vehicle) > 200);
        // The vehicle pixels are nearer than the ground would be there.
        let g = cam.ground_plane();
        for (i, &v) in both.iter().enumerate() {
            if v == Class::Vehicle as u8 {
                let (u, r) = ((i % 160) as f64 + 0.5, (i / 160) as f64 + 0.5);
                assert!(f64::from(buf.frame.inv_depth[i]) >= g.at(u, r) as f32 as f64);
            }
        }
        // Every label value is a class id.
        assert!(both.iter().all(|&v| v < 5));
    }
}
