//! The rasteriser: fills polygons at pixel centres, with an exact per-pixel depth test.
//!
//! Every surface is a planar polygon: ground polygons (road, markings, sidewalks, shadows)
//! on z = 0, and the faces of 3D solids. A polygon is clipped against the camera's near
//! plane in camera coordinates, projected, and scanline-filled: a pixel belongs to it when
//! its centre lies inside (non-zero winding), so labels are pixel-exact and never blended.
//! Ground polygons are painted in a fixed layer order without a depth test (they all lie
//! on the ground); faces are then drawn with a depth test against the inverse depth of
//! whatever is nearest so far, the ground included, so occlusion is correct per pixel.

use maps::geometry::Point;

use super::camera::{Camera, DepthPlane, Vec3};

/// Nearest depth drawn, metres: closer geometry is clipped away.
pub const NEAR_M: f64 = 0.05;

/// Surface ids of a frame's pixels: 0 is the sky, then the ground materials, then faces.
pub type SurfaceId = u32;

/// The sky's surface id.
pub const SKY: SurfaceId = 0;

/// Per-pixel buffers of one rendered view, row-major from the top-left.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Frame {
    pub width: usize,
    pub height: usize,
    /// What each pixel centre sees (see [`SurfaceId`]).
    pub surface: Vec<SurfaceId>,
    /// Inverse depth (1 / metres along the optical axis) of that surface; 0 for the sky.
    pub inv_depth: Vec<f32>,
    /// 1 where the ground lies in a cast shadow.
    pub shadow: Vec<u8>,
}

impl Frame {
    /// Resets the buffers to `width` × `height` of sky, reusing their memory.
    pub fn reset(&mut self, width: usize, height: usize) {
        let n = width * height;
        self.width = width;
        self.height = height;
        self.surface.clear();
        self.surface.resize(n, SKY);
        self.inv_depth.clear();
        self.inv_depth.resize(n, 0.0);
        self.shadow.clear();
        self.shadow.resize(n, 0);
    }
}

/// Scratch space for filling polygons, reused from one polygon to the next.
#[derive(Debug, Clone, Default)]
pub struct Scratch {
    crossings: Vec<(f64, i32)>,
    camera_pts: Vec<Vec3>,
    clipped: Vec<Vec3>,
    screen: Vec<(f64, f64)>,
}

/// Calls `span(row, c0, c1)` for every run `c0..c1` of pixel columns in row `row` whose
/// centres lie inside the polygon `pts` (continuous pixel positions, any orientation,
/// non-zero winding rule), clipped to a `width` × `height` image.
pub fn fill_polygon(
    pts: &[(f64, f64)],
    width: usize,
    height: usize,
    crossings: &mut Vec<(f64, i32)>,
    mut span: impl FnMut(usize, usize, usize),
) {
    if pts.len() < 3
        || width == 0
        || height == 0
        || pts.iter().any(|p| !(p.0.is_finite() && p.1.is_finite()))
    {
        return;
    }
    let (mut lo_x, mut hi_x, mut lo_y, mut hi_y) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in pts {
        lo_x = lo_x.min(x);
        hi_x = hi_x.max(x);
        lo_y = lo_y.min(y);
        hi_y = hi_y.max(y);
    }
    let (w, h) = (width as f64, height as f64);
    if !(hi_x > 0.0 && lo_x < w && hi_y > 0.0 && lo_y < h) {
        return;
    }
    let r0 = (lo_y - 0.5).ceil().max(0.0) as usize;
    let r1 = (hi_y - 0.5).floor().min(h - 1.0);
    if r1 < 0.0 {
        return;
    }
    for row in r0..=r1 as usize {
        let y = row as f64 + 0.5;
        crossings.clear();
        let n = pts.len();
        for i in 0..n {
            let (a, b) = (pts[i], pts[(i + 1) % n]);
            if (a.1 <= y) != (b.1 <= y) {
                let x = a.0 + (y - a.1) * (b.0 - a.0) / (b.1 - a.1);
                crossings.push((x, if b.1 > a.1 { 1 } else { -1 }));
            }
        }
        if crossings.len() == 2 {
            if crossings[1].0 < crossings[0].0 {
                crossings.swap(0, 1);
            }
        } else {
            crossings.sort_by(|p, q| p.0.total_cmp(&q.0));
        }
        let mut winding = 0;
        let mut start = 0.0;
        for &(x, d) in crossings.iter() {
            let was = winding;
            winding += d;
            if was == 0 && winding != 0 {
                start = x;
            } else if was != 0 && winding == 0 {
                // Columns whose centre c + 0.5 lies in [start, x).
                let c0 = (start - 0.5).ceil().max(0.0);
                let c1 = (x - 0.5).ceil().min(w);
                if c0 < c1 {
                    span(row, c0 as usize, c1 as usize);
                }
            }
        }
    }
}

/// Clips a polygon in camera coordinates to the half-space z ≥ [`NEAR_M`]
/// (Sutherland–Hodgman against one plane; exact for any polygon).
fn clip_near(input: &[Vec3], out: &mut Vec<Vec3>) {
    out.clear();
    let n = input.len();
    for i in 0..n {
        let (a, b) = (input[i], input[(i + 1) % n]);
        let (ina, inb) = (a.z >= NEAR_M, b.z >= NEAR_M);
        if ina {
            out.push(a);
        }
        if ina != inb {
            let t = (NEAR_M - a.z) / (b.z - a.z);
            let mut p = a.lerp(b, t);
            p.z = NEAR_M;
            out.push(p);
        }
    }
}

/// Draws surfaces of a scene into a [`Frame`] through a [`Camera`].
#[derive(Debug)]
pub struct Rasteriser<'a> {
    pub camera: &'a Camera,
    pub frame: &'a mut Frame,
    scratch: &'a mut Scratch,
}

impl<'a> Rasteriser<'a> {
    /// Starts a view: the frame is reset to sky above the horizon and to `ground` (with the
    /// ground's exact inverse depth) below it.
    pub fn new(
        camera: &'a Camera,
        frame: &'a mut Frame,
        scratch: &'a mut Scratch,
        ground: SurfaceId,
    ) -> Self {
        let (w, h) = (camera.width as usize, camera.height as usize);
        frame.reset(w, h);
        let g = camera.ground_plane();
        for row in 0..h {
            let v = row as f64 + 0.5;
            let line = row * w;
            for col in 0..w {
                let inv = g.at(col as f64 + 0.5, v);
                if inv > 0.0 {
                    frame.surface[line + col] = ground;
                    frame.inv_depth[line + col] = inv as f32;
                }
            }
        }
        Rasteriser {
            camera,
            frame,
            scratch,
        }
    }

    /// Projects a polygon of world points into `scratch.screen`, clipped to the near plane;
    /// false when nothing of it is in front of the camera.
    fn project(&mut self, world: impl Iterator<Item = Vec3>) -> bool {
        let s = &mut *self.scratch;
        s.camera_pts.clear();
        s.camera_pts.extend(world.map(|p| self.camera.to_camera(p)));
        if s.camera_pts.iter().all(|c| c.z < NEAR_M) {
            return false;
        }
        let pts: &[Vec3] = if s.camera_pts.iter().all(|c| c.z >= NEAR_M) {
            &s.camera_pts
        } else {
            clip_near(&s.camera_pts, &mut s.clipped);
            &s.clipped
        };
        s.screen.clear();
        let cam = self.camera;
        s.screen.extend(
            pts.iter()
                .map(|c| (cam.fx * c.x / c.z + cam.cx, cam.fy * c.y / c.z + cam.cy)),
        );
        s.screen.len() >= 3
    }

    /// Paints a ground polygon (world metres on z = 0) with `surface`, over whatever ground
    /// is there, without a depth test.
    pub fn ground_polygon(&mut self, pts: &[Point], surface: SurfaceId) {
        if !self.project(pts.iter().map(|p| Vec3::new(p.x, p.y, 0.0))) {
            return;
        }
        let (w, h) = (self.frame.width, self.frame.height);
        let surfaces = &mut self.frame.surface;
        fill_polygon(
            &self.scratch.screen,
            w,
            h,
            &mut self.scratch.crossings,
            |row, c0, c1| {
                surfaces[row * w + c0..row * w + c1].fill(surface);
            },
        );
    }

    /// Marks the ground inside a polygon (world metres on z = 0) as shadowed.
    pub fn shadow_polygon(&mut self, pts: &[Point]) {
        if !self.project(pts.iter().map(|p| Vec3::new(p.x, p.y, 0.0))) {
            return;
        }
        let (w, h) = (self.frame.width, self.frame.height);
        let shadow = &mut self.frame.shadow;
        fill_polygon(
            &self.scratch.screen,
            w,
            h,
            &mut self.scratch.crossings,
            |row, c0, c1| {
                shadow[row * w + c0..row * w + c1].fill(1);
            },
        );
    }

    /// Draws a planar face (world points, outward `normal`) where it is nearer than what
    /// is drawn; faces turned away from the camera are skipped (solids are closed).
    /// Returns whether any pixel took it.
    pub fn face(&mut self, pts: &[Vec3], normal: Vec3, surface: SurfaceId) -> bool {
        let Some(&p0) = pts.first() else {
            return false;
        };
        // Back-face culling: the camera must be on the outer side of the face's plane.
        if normal.dot(self.camera.position.sub(p0)) <= 0.0 {
            return false;
        }
        if !self.project(pts.iter().copied()) {
            return false;
        }
        let plane: DepthPlane = self.camera.depth_plane(normal, normal.dot(p0));
        let (w, h) = (self.frame.width, self.frame.height);
        let (surfaces, depth) = (&mut self.frame.surface, &mut self.frame.inv_depth);
        let mut drawn = false;
        fill_polygon(
            &self.scratch.screen,
            w,
            h,
            &mut self.scratch.crossings,
            |row, c0, c1| {
                let v = row as f64 + 0.5;
                let line = row * w;
                for col in c0..c1 {
                    let inv = plane.at(col as f64 + 0.5, v) as f32;
                    if inv > depth[line + col] {
                        depth[line + col] = inv;
                        surfaces[line + col] = surface;
                        drawn = true;
                    }
                }
            },
        );
        drawn
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::camera::{CameraConfig, CameraPose};

    fn spans(pts: &[(f64, f64)], w: usize, h: usize) -> Vec<u8> {
        let mut img = vec![0u8; w * h];
        fill_polygon(pts, w, h, &mut Vec::new(), |row, c0, c1| {
            img[row * w + c0..row * w + c1].fill(1)
        });
        img
    }

    #[test]
    fn fill_takes_pixels_whose_centres_are_inside() {
        // A square from 1.0 to 3.0: centres 1.5 and 2.5 in each direction.
        let img = spans(&[(1.0, 1.0), (3.0, 1.0), (3.0, 3.0), (1.0, 3.0)], 5, 5);
        let inside: Vec<usize> = (0..25).filter(|&i| img[i] == 1).collect();
        assert_eq!(inside, vec![6, 7, 11, 12]);
        // Just past a centre on both sides: still one pixel; clockwise the same.
        let img = spans(
            &[(1.49, 1.49), (1.49, 1.51), (1.51, 1.51), (1.51, 1.49)],
            3,
            3,
        );
        assert_eq!(img.iter().filter(|&&v| v == 1).count(), 1);
        // Off the image: nothing, and no panic on huge or NaN coordinates.
        let img = spans(&[(-1e9, 0.0), (-1e8, 0.0), (-1e8, 4.0)], 5, 5);
        assert!(img.iter().all(|&v| v == 0));
        let img = spans(&[(f64::NAN, 0.0), (3.0, 0.0), (3.0, 4.0)], 5, 5);
        assert!(img.iter().all(|&v| v == 0));
    }

    #[test]
    fn near_clipping_keeps_the_visible_part() {
        let mut out = Vec::new();
        clip_near(
            &[
                Vec3::new(0.0, 0.0, -1.0),
                Vec3::new(1.0, 0.0, 1.0),
                Vec3::new(0.0, 1.0, 1.0),
            ],
            &mut out,
        );
        assert_eq!(out.len(), 4);
        assert!(out.iter().all(|p| p.z >= NEAR_M - 1e-12));
    }

    #[test]
    fn a_box_in_front_hides_another_behind_it() {
        let config = CameraConfig {
            width: 64,
            height: 48,
            height_m: 1.5,
            pitch_deg: 0.0,
            hfov_deg: 60.0,
        };
        let cam = Camera::new(
            &config,
            &CameraPose {
                position: Vec3::new(0.0, 0.0, 1.5),
                yaw: 0.0,
                pitch: 0.0,
                roll: 0.0,
            },
        );
        // Two walls facing the camera (normal -x): the far one, bigger, drawn first.
        let wall = |x: f64, half: f64| {
            vec![
                Vec3::new(x, -half, 0.0),
                Vec3::new(x, half, 0.0),
                Vec3::new(x, half, 3.0),
                Vec3::new(x, -half, 3.0),
            ]
        };
        let normal = Vec3::new(-1.0, 0.0, 0.0);
        let (mut frame, mut scratch) = (Frame::default(), Scratch::default());
        let mut r = Rasteriser::new(&cam, &mut frame, &mut scratch, 1);
        assert!(r.face(&wall(20.0, 6.0), normal, 7));
        assert!(r.face(&wall(10.0, 1.0), normal, 8));
        // Drawn in the other order the result is the same.
        let (mut frame2, mut scratch2) = (Frame::default(), Scratch::default());
        let mut r2 = Rasteriser::new(&cam, &mut frame2, &mut scratch2, 1);
        assert!(r2.face(&wall(10.0, 1.0), normal, 8));
        r2.face(&wall(20.0, 6.0), normal, 7);
        assert_eq!(frame, frame2);
        let centre = 24 * 64 + 32;
        assert_eq!(frame.surface[centre], 8, "the near wall covers the centre");
        assert!((frame.inv_depth[centre] - 0.1).abs() < 1e-6);
        // The far wall shows beside the near one; the ground below both; sky above.
        assert_eq!(frame.surface[22 * 64 + 20], 7);
        assert_eq!(frame.surface[47 * 64 + 32], 1);
        assert_eq!(frame.surface[32], SKY);
        // A face seen from behind is not drawn.
        let mut r3 = Rasteriser::new(&cam, &mut frame2, &mut scratch2, 1);
        assert!(!r3.face(&wall(10.0, 1.0), Vec3::new(1.0, 0.0, 0.0), 9));
    }
}
