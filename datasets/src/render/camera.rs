//! The pinhole camera: where it stands, where it looks, and how a world point lands on a
//! pixel.
//!
//! World frame: the map's metric frame with z up (x east, y north, metres). Camera frame:
//! x right, y down, z forward (the usual computer-vision convention), so a point at camera
//! coordinates `(x, y, z)` projects to the pixel position `(fx·x/z + cx, fy·y/z + cy)`.
//! Pixel `(col, row)` covers `[col, col + 1) × [row, row + 1)`; its centre is at
//! `(col + 0.5, row + 0.5)`, and labels are sampled there.
//!
//! Every plane seen by the camera has an inverse depth `1/z` that is an affine function of
//! the pixel position ([`DepthPlane`]); the rasteriser uses that for exact per-pixel depth
//! of the ground and of every face, so occlusion is decided per pixel centre.

use serde::{Deserialize, Serialize};

/// A 3D vector or point in metres.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Vec3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

// Plain methods, as maps' `Point` does: `a.sub(b).dot(n)` reads left to right.
#[allow(clippy::should_implement_trait)]
impl Vec3 {
    pub const fn new(x: f64, y: f64, z: f64) -> Self {
        Vec3 { x, y, z }
    }
    pub fn add(self, o: Vec3) -> Vec3 {
        Vec3::new(self.x + o.x, self.y + o.y, self.z + o.z)
    }
    pub fn sub(self, o: Vec3) -> Vec3 {
        Vec3::new(self.x - o.x, self.y - o.y, self.z - o.z)
    }
    pub fn scale(self, s: f64) -> Vec3 {
        Vec3::new(self.x * s, self.y * s, self.z * s)
    }
    pub fn dot(self, o: Vec3) -> f64 {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    pub fn cross(self, o: Vec3) -> Vec3 {
        Vec3::new(
            self.y * o.z - self.z * o.y,
            self.z * o.x - self.x * o.z,
            self.x * o.y - self.y * o.x,
        )
    }
    pub fn norm(self) -> f64 {
        self.dot(self).sqrt()
    }
    /// Unit vector, or zero for the zero vector.
    pub fn normalized(self) -> Vec3 {
        let n = self.norm();
        if n > 0.0 {
            self.scale(1.0 / n)
        } else {
            Vec3::default()
        }
    }
    /// Linear interpolation towards `o`.
    pub fn lerp(self, o: Vec3, t: f64) -> Vec3 {
        self.add(o.sub(self).scale(t))
    }
}

/// The camera's fixed properties: image size, mounting height and tilt, field of view.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CameraConfig {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Height of the optical centre above the road, metres.
    pub height_m: f64,
    /// Downward tilt of the optical axis, degrees (0 = level, horizon through the centre).
    pub pitch_deg: f64,
    /// Horizontal field of view, degrees.
    pub hfov_deg: f64,
}

impl Default for CameraConfig {
    /// The seed projects' front camera: 1.6 m up, 69° wide, tilted a little down, 480 × 270.
    fn default() -> Self {
        CameraConfig {
            width: 480,
            height: 270,
            height_m: 1.6,
            pitch_deg: 4.0,
            hfov_deg: 69.0,
        }
    }
}

impl CameraConfig {
    /// Why the configuration cannot make images, if it cannot.
    pub fn problem(&self) -> Option<String> {
        if self.width == 0 || self.height == 0 || self.width > 8192 || self.height > 8192 {
            return Some(format!(
                "image size {}x{} must be between 1x1 and 8192x8192",
                self.width, self.height
            ));
        }
        if !(self.hfov_deg > 1.0 && self.hfov_deg < 170.0) {
            return Some(format!(
                "horizontal field of view {}° must lie between 1° and 170°",
                self.hfov_deg
            ));
        }
        if !(self.height_m > 0.05 && self.height_m < 100.0) {
            return Some(format!(
                "camera height {} m must lie between 0.05 and 100 m",
                self.height_m
            ));
        }
        if self.pitch_deg.is_nan() || self.pitch_deg.abs() >= 80.0 {
            return Some(format!(
                "camera pitch {}° must lie between -80° and 80°",
                self.pitch_deg
            ));
        }
        None
    }
}

/// Where the camera is and how it is turned: position of the optical centre (world, z up),
/// heading (radians, counter-clockwise from east), downward pitch and roll (radians).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraPose {
    pub position: Vec3,
    pub yaw: f64,
    pub pitch: f64,
    pub roll: f64,
}

/// `1/z` of a plane as an affine function of the pixel position: `a·u + b·v + c`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthPlane {
    pub a: f64,
    pub b: f64,
    pub c: f64,
}

impl DepthPlane {
    /// Inverse depth at pixel position (`u`, `v`).
    pub fn at(&self, u: f64, v: f64) -> f64 {
        self.a * u + self.b * v + self.c
    }
}

/// A posed pinhole camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub width: u32,
    pub height: u32,
    /// Optical centre, world metres.
    pub position: Vec3,
    /// Camera axes in world coordinates (unit, orthogonal).
    pub right: Vec3,
    pub down: Vec3,
    pub forward: Vec3,
    /// Focal lengths and principal point, pixels.
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl Camera {
    /// The camera of `config` placed at `pose` (the pose's pitch is the total tilt).
    pub fn new(config: &CameraConfig, pose: &CameraPose) -> Self {
        let (sy, cy) = pose.yaw.sin_cos();
        let (sp, cp) = pose.pitch.sin_cos();
        let forward = Vec3::new(cy * cp, sy * cp, -sp);
        let level_right = Vec3::new(sy, -cy, 0.0);
        let level_down = forward.cross(level_right);
        let (sr, cr) = pose.roll.sin_cos();
        let right = level_right.scale(cr).add(level_down.scale(sr));
        let down = level_down.scale(cr).sub(level_right.scale(sr));
        let (w, h) = (f64::from(config.width), f64::from(config.height));
        let fx = (w / 2.0) / (config.hfov_deg.to_radians() / 2.0).tan();
        Camera {
            width: config.width,
            height: config.height,
            position: pose.position,
            right,
            down,
            forward,
            fx,
            fy: fx,
            cx: w / 2.0,
            cy: h / 2.0,
        }
    }

    /// World point to camera coordinates (x right, y down, z forward).
    pub fn to_camera(&self, p: Vec3) -> Vec3 {
        let d = p.sub(self.position);
        Vec3::new(d.dot(self.right), d.dot(self.down), d.dot(self.forward))
    }

    /// Camera coordinates to the continuous pixel position, or None behind the camera.
    pub fn project_camera(&self, c: Vec3) -> Option<(f64, f64)> {
        (c.z > 0.0).then(|| (self.fx * c.x / c.z + self.cx, self.fy * c.y / c.z + self.cy))
    }

    /// World point to the continuous pixel position, or None behind the camera.
    pub fn project(&self, p: Vec3) -> Option<(f64, f64)> {
        self.project_camera(self.to_camera(p))
    }

    /// World direction of the ray through pixel position (`u`, `v`), scaled so that its
    /// forward component is 1: the point at depth `z` is `position + z · ray`.
    pub fn ray(&self, u: f64, v: f64) -> Vec3 {
        let xn = (u - self.cx) / self.fx;
        let yn = (v - self.cy) / self.fy;
        self.forward
            .add(self.right.scale(xn))
            .add(self.down.scale(yn))
    }

    /// Inverse depth over the image of the world plane `normal · p = offset`.
    pub fn depth_plane(&self, normal: Vec3, offset: f64) -> DepthPlane {
        // p = C + z·ray with ray = f + xn·r + yn·d, so 1/z = (n·ray) / (k − n·C), and
        // n·ray is affine in (u, v).
        let k = offset - normal.dot(self.position);
        let (nf, nr, nd) = (
            normal.dot(self.forward),
            normal.dot(self.right),
            normal.dot(self.down),
        );
        let a = nr / (self.fx * k);
        let b = nd / (self.fy * k);
        let c = nf / k - a * self.cx - b * self.cy;
        DepthPlane { a, b, c }
    }

    /// Inverse depth of the ground (z = 0): positive below the horizon, zero on it,
    /// negative above it.
    pub fn ground_plane(&self) -> DepthPlane {
        self.depth_plane(Vec3::new(0.0, 0.0, 1.0), 0.0)
    }

    /// The row position (continuous) where the horizon crosses column position `u`.
    pub fn horizon_v(&self, u: f64) -> f64 {
        let g = self.ground_plane();
        if g.b.abs() < 1e-15 {
            return if g.a * u + g.c > 0.0 {
                f64::NEG_INFINITY
            } else {
                f64::INFINITY
            };
        }
        -(g.a * u + g.c) / g.b
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn level_camera(width: u32, height: u32, pitch_deg: f64, roll: f64) -> Camera {
        let config = CameraConfig {
            width,
            height,
            height_m: 1.6,
            pitch_deg,
            hfov_deg: 90.0,
        };
        Camera::new(
            &config,
            &CameraPose {
                position: Vec3::new(10.0, 20.0, 1.6),
                yaw: std::f64::consts::FRAC_PI_2,
                pitch: pitch_deg.to_radians(),
                roll,
            },
        )
    }

    #[test]
    fn a_known_ground_point_projects_to_the_expected_pixel() {
        // 90° wide, 200 px: fx = 100. Looking north from (10, 20), 1.6 m up, level.
        let cam = level_camera(200, 100, 0.0, 0.0);
        assert!((cam.fx - 100.0).abs() < 1e-9);
        // 10 m ahead, 2 m to the right (east), on the road.
        let (u, v) = cam.project(Vec3::new(12.0, 30.0, 0.0)).unwrap_or_default();
        assert!((u - (100.0 + 100.0 * 2.0 / 10.0)).abs() < 1e-9, "{u}");
        assert!((v - (50.0 + 100.0 * 1.6 / 10.0)).abs() < 1e-9, "{v}");
        // The ray through that position hits the ground at the point again.
        let ray = cam.ray(u, v);
        let z = 1.0 / cam.ground_plane().at(u, v);
        let hit = cam.position.add(ray.scale(z));
        assert!(hit.sub(Vec3::new(12.0, 30.0, 0.0)).norm() < 1e-9, "{hit:?}");
        assert!(cam.project(Vec3::new(10.0, 10.0, 0.0)).is_none());
    }

    #[test]
    fn horizon_row_follows_the_pitch() {
        let level = level_camera(200, 100, 0.0, 0.0);
        assert!((level.horizon_v(0.0) - 50.0).abs() < 1e-9);
        assert!((level.horizon_v(199.0) - 50.0).abs() < 1e-9);
        // Tilted down by 10°: the horizon rises by fy·tan(10°).
        let down = level_camera(200, 100, 10.0, 0.0);
        let expect = 50.0 - 100.0 * 10f64.to_radians().tan();
        assert!((down.horizon_v(100.0) - expect).abs() < 1e-9);
        // Ground below the horizon, sky above.
        let g = down.ground_plane();
        assert!(g.at(100.0, expect + 1.0) > 0.0 && g.at(100.0, expect - 1.0) < 0.0);
        // Rolled: the horizon tilts, and still passes through the centre when level.
        let rolled = level_camera(200, 100, 0.0, 5f64.to_radians());
        assert!((rolled.horizon_v(100.0) - 50.0).abs() < 1e-9);
        let slope = (rolled.horizon_v(150.0) - rolled.horizon_v(50.0)) / 100.0;
        assert!(
            (slope.abs() - 5f64.to_radians().tan()).abs() < 1e-9,
            "{slope}"
        );
    }

    #[test]
    fn depth_plane_of_a_wall_is_exact() {
        let cam = level_camera(200, 100, 3.0, 0.02);
        // A wall facing the camera 15 m north: y = 35.
        let plane = cam.depth_plane(Vec3::new(0.0, -1.0, 0.0), -35.0);
        for p in [Vec3::new(9.0, 35.0, 1.0), Vec3::new(13.0, 35.0, 3.0)] {
            let c = cam.to_camera(p);
            let (u, v) = cam.project_camera(c).unwrap_or_default();
            assert!((plane.at(u, v) - 1.0 / c.z).abs() < 1e-12);
        }
    }
}
