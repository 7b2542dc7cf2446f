//! 3D shapes: closed convex pieces (boxes and prisms) made of planar faces with outward
//! normals, grouped into solids of one class each — vehicles, people, buildings, trees.
//!
//! Road users come in as [`Actor`]s: oriented boxes with a kind. That is all the renderer
//! needs to know about them, so positions can come from random placement
//! ([`super::placement`]) or, later, from the traffic world's scene.

use maps::geometry::{Point, convex_hull};
use serde::{Deserialize, Serialize};

use super::camera::Vec3;
use crate::classes::Class;

/// An RGB colour with channels in [0, 1].
pub type Rgb = [f32; 3];

/// Which per-view colour change applies to a face (the look of a view tints whole groups
/// of things, e.g. every building a little warmer).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Tint {
    None,
    Building,
    Vegetation,
}

/// One planar face: a range of its solid's points (counter-clockwise seen from outside).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Face {
    pub start: u32,
    pub end: u32,
    pub normal: Vec3,
    pub colour: Rgb,
    pub tint: Tint,
}

/// A closed 3D shape of one class.
#[derive(Debug, Clone, PartialEq)]
pub struct Solid {
    pub class: Class,
    pub points: Vec<Vec3>,
    pub faces: Vec<Face>,
}

impl Solid {
    pub fn new(class: Class) -> Self {
        Solid {
            class,
            points: Vec::new(),
            faces: Vec::new(),
        }
    }

    /// The points of face `f`.
    pub fn face_points(&self, f: &Face) -> &[Vec3] {
        &self.points[f.start as usize..f.end as usize]
    }

    fn push_face(&mut self, pts: &[Vec3], colour: Rgb, tint: Tint) {
        let start = self.points.len() as u32;
        self.points.extend_from_slice(pts);
        // Newell's normal: robust for any planar polygon, outward for counter-clockwise
        // points seen from outside.
        let mut n = Vec3::default();
        for i in 0..pts.len() {
            let (a, b) = (pts[i], pts[(i + 1) % pts.len()]);
            n.x += (a.y - b.y) * (a.z + b.z);
            n.y += (a.z - b.z) * (a.x + b.x);
            n.z += (a.x - b.x) * (a.y + b.y);
        }
        self.faces.push(Face {
            start,
            end: self.points.len() as u32,
            normal: n.normalized(),
            colour,
            tint,
        });
    }

    /// A vertical prism: the polygon `ring` (counter-clockwise, ground plane) from height
    /// `z0` to `z1`, with its top shrunk towards the centre by `top_scale` (1 = a prism,
    /// < 1 a frustum). Its bottom face is left out when it stands on the ground (never seen
    /// from above ground).
    pub fn add_prism(
        &mut self,
        ring: &[Point],
        (z0, z1): (f64, f64),
        top_scale: f64,
        colour: Rgb,
        tint: Tint,
    ) {
        let n = ring.len();
        if n < 3 || z1 <= z0 {
            return;
        }
        let c = ring
            .iter()
            .fold(Point::default(), |a, p| a.add(*p))
            .scale(1.0 / n as f64);
        let top: Vec<Vec3> = ring
            .iter()
            .map(|p| {
                let q = c.add(p.sub(c).scale(top_scale));
                Vec3::new(q.x, q.y, z1)
            })
            .collect();
        let bottom: Vec<Vec3> = ring.iter().map(|p| Vec3::new(p.x, p.y, z0)).collect();
        for i in 0..n {
            let j = (i + 1) % n;
            self.push_face(&[bottom[i], bottom[j], top[j], top[i]], colour, tint);
        }
        if top_scale > 0.0 {
            self.push_face(&top, colour, tint);
        }
        if z0 > 0.0 {
            let rev: Vec<Vec3> = bottom.iter().rev().copied().collect();
            self.push_face(&rev, colour, tint);
        }
    }

    /// A box around `centre` turned to `heading`, `length` along it, `width` across.
    pub fn add_box(&mut self, frame: &Placement, extent: BoxExtent, colour: Rgb, tint: Tint) {
        let ring = frame.rectangle(extent.x, extent.y);
        self.add_prism(&ring, extent.z, 1.0, colour, tint);
    }

    /// A regular `sides`-gon prism (a cylinder, near enough) of `radius` at `centre`.
    pub fn add_cylinder(
        &mut self,
        centre: Point,
        radius: (f64, f64),
        z: (f64, f64),
        sides: usize,
        colour: Rgb,
        tint: Tint,
    ) {
        let ring: Vec<Point> = (0..sides)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / sides as f64;
                centre.add(Point::new(a.cos(), a.sin()).scale(radius.0))
            })
            .collect();
        let scale = if radius.0 > 0.0 {
            radius.1 / radius.0
        } else {
            1.0
        };
        self.add_prism(&ring, z, scale, colour, tint);
    }

    /// The outline seen from above (convex hull of every point).
    pub fn footprint(&self) -> Vec<Point> {
        let pts: Vec<Point> = self.points.iter().map(|p| Point::new(p.x, p.y)).collect();
        convex_hull(&pts)
    }

    /// The shadow cast on the ground by light travelling along `light` (pointing down):
    /// the convex hull of every point pushed along it to z = 0. Approximate for shapes that
    /// are not convex, which is what "at least approximate" shadows need.
    pub fn shadow(&self, light: Vec3) -> Vec<Point> {
        if light.z >= -1e-6 {
            return Vec::new();
        }
        let pts: Vec<Point> = self
            .points
            .iter()
            .map(|p| {
                let t = -p.z / light.z;
                Point::new(p.x + t * light.x, p.y + t * light.y)
            })
            .collect();
        convex_hull(&pts)
    }
}

/// A position and heading on the ground, for building oriented shapes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    pub centre: Point,
    /// Unit vector of the heading.
    pub along: Point,
}

impl Placement {
    pub fn new(centre: Point, heading: f64) -> Self {
        Placement {
            centre,
            along: Point::new(heading.cos(), heading.sin()),
        }
    }

    /// The point `forward` metres ahead and `left` metres to the left of the centre.
    pub fn at(&self, forward: f64, left: f64) -> Point {
        self.centre
            .add(self.along.scale(forward))
            .add(self.along.perp().scale(left))
    }

    /// The rectangle spanning `x` (forward, from..to) × `y` (left, from..to),
    /// counter-clockwise.
    pub fn rectangle(&self, x: (f64, f64), y: (f64, f64)) -> [Point; 4] {
        [
            self.at(x.0, y.0),
            self.at(x.1, y.0),
            self.at(x.1, y.1),
            self.at(x.0, y.1),
        ]
    }
}

/// A box in a [`Placement`]'s frame: forward, left and height ranges, metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxExtent {
    pub x: (f64, f64),
    pub y: (f64, f64),
    pub z: (f64, f64),
}

/// What kind of road user an [`Actor`] is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ActorKind {
    Vehicle,
    Pedestrian,
}

/// A road user as an oriented box standing on the ground: what the renderer needs from
/// any source of road users (random placement now, the traffic world's scene later).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Actor {
    pub kind: ActorKind,
    /// Centre of the footprint, map metres.
    pub position: Point,
    /// Radians, counter-clockwise from east.
    pub heading_rad: f64,
    pub length_m: f64,
    pub width_m: f64,
    pub height_m: f64,
}

/// Colours of one actor's parts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ActorColours {
    /// Paint (vehicles) or upper clothes (people).
    pub main: Rgb,
    /// Windows (vehicles) or trousers (people).
    pub second: Rgb,
    /// Tyres (vehicles) or skin (people).
    pub third: Rgb,
}

const TAIL_LIGHT: Rgb = [0.6, 0.05, 0.04];

impl Actor {
    /// The actor as a solid: a car body with a cabin, windows, wheels and tail lights; or a
    /// person with legs, body and head.
    pub fn solid(&self, colours: &ActorColours) -> Solid {
        match self.kind {
            ActorKind::Vehicle => self.vehicle(colours),
            ActorKind::Pedestrian => self.pedestrian(colours),
        }
    }

    fn vehicle(&self, c: &ActorColours) -> Solid {
        let mut s = Solid::new(Class::Vehicle);
        let f = Placement::new(self.position, self.heading_rad);
        let (hl, hw, h) = (self.length_m / 2.0, self.width_m / 2.0, self.height_m);
        let wheel_d = (0.42 * h).clamp(0.5, 1.1);
        let sill = 0.45 * wheel_d;
        // Tall vehicles (vans, buses) have a cabin over nearly their whole length.
        let tall = h > 2.1;
        let belt = if tall {
            sill + 0.35 * (h - sill)
        } else {
            sill + 0.5 * (h - sill)
        };
        s.add_box(
            &f,
            BoxExtent {
                x: (-hl, hl),
                y: (-hw, hw),
                z: (sill, belt),
            },
            c.main,
            Tint::None,
        );
        let (cab_back, cab_front) = if tall {
            (-hl, hl - 0.25)
        } else {
            (-0.62 * hl, 0.3 * hl)
        };
        let inset = 0.08 * self.width_m;
        let cabin = |x: (f64, f64), z: (f64, f64)| BoxExtent {
            x,
            y: (-hw + inset, hw - inset),
            z,
        };
        if tall {
            // A van or bus: a painted box with a windscreen and a band of side windows.
            let screen = cab_front - 1.1;
            s.add_box(&f, cabin((cab_back, screen), (belt, h)), c.main, Tint::None);
            s.add_box(
                &f,
                cabin((screen, cab_front), (belt, h - 0.08)),
                c.second,
                Tint::None,
            );
            s.add_box(
                &f,
                cabin((screen, cab_front), (h - 0.08, h)),
                c.main,
                Tint::None,
            );
        } else {
            // Glass all round the cabin, the roof in paint.
            s.add_box(
                &f,
                cabin((cab_back, cab_front), (belt, h - 0.06)),
                c.second,
                Tint::None,
            );
            s.add_box(
                &f,
                cabin((cab_back, cab_front), (h - 0.06, h)),
                c.main,
                Tint::None,
            );
        }
        let axle = hl - (0.9 * wheel_d).min(0.3 * hl);
        for x in [-axle, axle] {
            for (y0, y1) in [(-hw - 0.02, -hw + 0.22), (hw - 0.22, hw + 0.02)] {
                s.add_box(
                    &f,
                    BoxExtent {
                        x: (x - wheel_d / 2.0, x + wheel_d / 2.0),
                        y: (y0, y1),
                        z: (0.0, wheel_d),
                    },
                    c.third,
                    Tint::None,
                );
            }
        }
        let light_z = (belt - 0.2, belt - 0.05);
        for (y0, y1) in [(-hw + 0.05, -hw + 0.3), (hw - 0.3, hw - 0.05)] {
            s.add_box(
                &f,
                BoxExtent {
                    x: (-hl - 0.03, -hl + 0.01),
                    y: (y0, y1),
                    z: light_z,
                },
                TAIL_LIGHT,
                Tint::None,
            );
        }
        s
    }

    fn pedestrian(&self, c: &ActorColours) -> Solid {
        let mut s = Solid::new(Class::Human);
        let k = self.height_m / 1.75;
        let f = Placement::new(self.position, self.heading_rad);
        for side in [-0.09 * k, 0.09 * k] {
            s.add_cylinder(
                f.at(0.0, side),
                (0.075 * k, 0.075 * k),
                (0.0, 0.86 * k),
                6,
                c.second,
                Tint::None,
            );
        }
        s.add_cylinder(
            self.position,
            (0.2 * k, 0.17 * k),
            (0.86 * k, 1.47 * k),
            8,
            c.main,
            Tint::None,
        );
        s.add_cylinder(
            self.position,
            (0.1 * k, 0.09 * k),
            (1.5 * k, 1.75 * k),
            8,
            c.third,
            Tint::None,
        );
        s
    }
}

/// A building: a box with a roof of another colour.
pub fn building(frame: &Placement, size: (f64, f64), height: f64, wall: Rgb, roof: Rgb) -> Solid {
    let mut s = Solid::new(Class::Other);
    let ring = frame.rectangle((-size.0 / 2.0, size.0 / 2.0), (-size.1 / 2.0, size.1 / 2.0));
    s.add_prism(&ring, (0.0, height), 1.0, wall, Tint::Building);
    // The roof face of the prism is replaced by a slightly darker flat roof slab.
    if let Some(roof_face) = s.faces.iter_mut().find(|f| f.normal.z > 0.9) {
        roof_face.colour = roof;
    }
    s
}

/// A tree: a trunk and a two-tier canopy.
pub fn tree(centre: Point, height: f64, radius: f64, trunk: Rgb, leaves: Rgb) -> Solid {
    let mut s = Solid::new(Class::Other);
    let crown = 0.35 * height;
    s.add_cylinder(
        centre,
        (0.06 * radius + 0.1, 0.05 * radius + 0.08),
        (0.0, crown + 0.3),
        6,
        trunk,
        Tint::Vegetation,
    );
    s.add_cylinder(
        centre,
        (0.75 * radius, radius),
        (crown, crown + 0.3 * (height - crown)),
        8,
        leaves,
        Tint::Vegetation,
    );
    s.add_cylinder(
        centre,
        (radius, 0.2 * radius),
        (crown + 0.3 * (height - crown), height),
        8,
        leaves,
        Tint::Vegetation,
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn car() -> Actor {
        Actor {
            kind: ActorKind::Vehicle,
            position: Point::new(5.0, 2.0),
            heading_rad: 0.5,
            length_m: 4.5,
            width_m: 1.8,
            height_m: 1.5,
        }
    }

    fn grey() -> ActorColours {
        ActorColours {
            main: [0.5; 3],
            second: [0.2; 3],
            third: [0.1; 3],
        }
    }

    #[test]
    fn normals_are_unit_and_only_raised_pieces_have_bottoms() {
        for solid in [
            car().solid(&grey()),
            Actor {
                kind: ActorKind::Pedestrian,
                height_m: 1.8,
                ..car()
            }
            .solid(&grey()),
            tree(Point::new(1.0, 1.0), 7.0, 2.5, [0.3; 3], [0.2; 3]),
        ] {
            for f in &solid.faces {
                assert!((f.normal.norm() - 1.0).abs() < 1e-9);
            }
            assert!(solid.faces.iter().any(|f| f.normal.z > 0.99));
            // A bottom on the ground could never be seen: only raised pieces have one.
            for f in solid.faces.iter().filter(|f| f.normal.z < -0.99) {
                assert!(solid.face_points(f).iter().all(|p| p.z > 0.0));
            }
        }
    }

    #[test]
    fn a_box_has_outward_side_normals() {
        let mut s = Solid::new(Class::Other);
        let f = Placement::new(Point::new(0.0, 0.0), 0.0);
        s.add_box(
            &f,
            BoxExtent {
                x: (-2.0, 2.0),
                y: (-1.0, 1.0),
                z: (0.5, 1.5),
            },
            [1.0; 3],
            Tint::None,
        );
        // 4 sides, top and bottom.
        assert_eq!(s.faces.len(), 6);
        for face in &s.faces {
            let pts = s.face_points(face);
            let c = pts
                .iter()
                .fold(Vec3::default(), |a, p| a.add(*p))
                .scale(1.0 / pts.len() as f64);
            // The box centre (0, 0, 1) lies on the inner side of every face.
            assert!(face.normal.dot(Vec3::new(0.0, 0.0, 1.0).sub(c)) < 0.0);
        }
    }

    #[test]
    fn frustum_sides_face_away_from_the_axis() {
        let mut s = Solid::new(Class::Other);
        let c = Point::new(3.0, -2.0);
        s.add_cylinder(c, (2.0, 0.5), (1.0, 4.0), 8, [1.0; 3], Tint::None);
        // 8 sides, top, and a bottom (raised).
        assert_eq!(s.faces.len(), 10);
        for f in &s.faces[..8] {
            let pts = s.face_points(f);
            let m = pts
                .iter()
                .fold(Vec3::default(), |a, p| a.add(*p))
                .scale(0.25);
            let out = Vec3::new(m.x - c.x, m.y - c.y, 0.0);
            assert!(f.normal.dot(out) > 0.0);
            // Narrower at the top: the sides lean inwards, so their normals point up a bit.
            assert!(f.normal.z > 0.1);
        }
    }

    #[test]
    fn shadow_falls_away_from_the_sun() {
        let s = car().solid(&grey());
        // Sun in the west, 45° up: light travels east and down.
        let shadow = s.shadow(Vec3::new(1.0, 0.0, -1.0));
        let max_x = shadow.iter().map(|p| p.x).fold(f64::MIN, f64::max);
        let foot_max_x = s.footprint().iter().map(|p| p.x).fold(f64::MIN, f64::max);
        assert!(max_x > foot_max_x + 0.5, "{max_x} {foot_max_x}");
        assert!(s.shadow(Vec3::new(1.0, 0.0, 0.1)).is_empty());
    }
}
