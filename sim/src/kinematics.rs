//! Vehicle motion shared by the traffic world and the tasks: constant-acceleration
//! longitudinal steps and the kinematic bicycle.

use maps::Point;

use crate::path::wrap_angle;

/// One step of constant acceleration `accel` from `speed` over `dt`, never reversing:
/// `(new speed, distance travelled)`. When the speed would cross zero the vehicle stops
/// exactly where it reaches zero.
pub fn advance_speed(speed: f64, accel: f64, dt: f64) -> (f64, f64) {
    let new_speed = (speed + accel * dt).max(0.0);
    let travelled = if new_speed > 0.0 {
        (speed + new_speed) / 2.0 * dt
    } else if accel < 0.0 {
        speed * speed / (-2.0 * accel)
    } else {
        0.0
    };
    (new_speed, travelled)
}

/// A kinematic bicycle: the rear axle's position and the heading. The reference point
/// of a vehicle (its centre) lies half a wheelbase ahead of the rear axle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bicycle {
    pub rear: Point,
    /// rad, counter-clockwise from +x.
    pub heading: f64,
    pub wheelbase_m: f64,
}

impl Bicycle {
    /// The bicycle whose centre is at `centre`.
    pub fn at_centre(centre: Point, heading: f64, wheelbase_m: f64) -> Self {
        Bicycle {
            rear: centre.sub(direction(heading).scale(wheelbase_m / 2.0)),
            heading,
            wheelbase_m,
        }
    }

    /// The centre (half a wheelbase ahead of the rear axle).
    pub fn centre(&self) -> Point {
        self.rear
            .add(direction(self.heading).scale(self.wheelbase_m / 2.0))
    }

    /// Moves `travelled` metres with the front wheels at `steer_rad` (left positive).
    pub fn advance(&mut self, travelled: f64, steer_rad: f64) {
        self.rear = self.rear.add(direction(self.heading).scale(travelled));
        self.heading = wrap_angle(self.heading + travelled / self.wheelbase_m * steer_rad.tan());
    }

    /// The pure pursuit steering angle towards `target`, within `±max_steer_rad`.
    pub fn pure_pursuit(&self, target: Point, max_steer_rad: f64) -> f64 {
        let to_target = target.sub(self.rear);
        let alpha = wrap_angle(to_target.y.atan2(to_target.x) - self.heading);
        let distance = to_target.norm().max(0.1);
        (2.0 * self.wheelbase_m * alpha.sin() / distance)
            .atan()
            .clamp(-max_steer_rad, max_steer_rad)
    }

    /// The front axle's position.
    pub fn front(&self) -> Point {
        self.rear
            .add(direction(self.heading).scale(self.wheelbase_m))
    }

    /// Stanley steering angle, within `±max_steer_rad`: the heading error of the front axle
    /// against the path point nearest to it (`path_point`, heading `path_heading`), plus
    /// `atan(gain · cross-track error / (speed + 1 m/s))` to close the lateral gap. Unlike
    /// pure pursuit it does not cut corners: the car turns when the path turns under its
    /// front wheels.
    pub fn stanley(
        &self,
        path_point: Point,
        path_heading: f64,
        speed_mps: f64,
        gain: f64,
        max_steer_rad: f64,
    ) -> f64 {
        // Positive when the path lies to the car's left (steer left).
        let cross_track = path_point
            .sub(self.front())
            .dot(direction(path_heading).perp());
        let heading_error = wrap_angle(path_heading - self.heading);
        (heading_error + (gain * cross_track / (speed_mps.max(0.0) + 1.0)).atan())
            .clamp(-max_steer_rad, max_steer_rad)
    }
}

/// The unit vector of a heading.
pub fn direction(heading: f64) -> Point {
    Point::new(heading.cos(), heading.sin())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn braking_stops_exactly_at_zero_speed() {
        let (v, d) = advance_speed(2.0, -8.0, 0.5);
        assert_eq!(v, 0.0);
        assert!((d - 0.25).abs() < 1e-12, "{d}");
        let (v, d) = advance_speed(10.0, 2.0, 0.5);
        assert!((v - 11.0).abs() < 1e-12 && (d - 5.25).abs() < 1e-12);
    }

    #[test]
    fn constant_steering_drives_a_circle_of_the_bicycle_radius() {
        // Radius of the rear axle's circle: wheelbase / tan(steer).
        let steer = 0.3_f64;
        let mut bike = Bicycle::at_centre(Point::new(0.0, 0.0), 0.0, 2.7);
        let radius = 2.7 / steer.tan();
        let start = bike.rear;
        let centre = start.add(Point::new(0.0, radius));
        for _ in 0..2000 {
            bike.advance(0.01, steer);
            assert!((bike.rear.distance(centre) - radius).abs() < 0.05);
        }
    }

    #[test]
    fn pure_pursuit_steers_towards_the_side_of_the_target() {
        let bike = Bicycle::at_centre(Point::new(0.0, 0.0), 0.0, 2.7);
        assert!(bike.pure_pursuit(Point::new(5.0, 2.0), 0.6) > 0.0);
        assert!(bike.pure_pursuit(Point::new(5.0, -2.0), 0.6) < 0.0);
        assert_eq!(bike.pure_pursuit(Point::new(0.0, 5.0), 0.6), 0.6);
    }

    /// Stanley steering on a circle of 6 m radius (a mini roundabout's ring) at 4 m/s:
    /// after settling, the front axle stays on the circle (within 10 cm) and the centre,
    /// half a wheelbase behind it, within 0.4 m of it.
    #[test]
    fn stanley_steering_holds_a_tight_circle() {
        let radius = 6.0;
        let on_circle = |p: Point| {
            let a = p.y.atan2(p.x);
            (
                Point::new(radius * a.cos(), radius * a.sin()),
                a + std::f64::consts::FRAC_PI_2,
            )
        };
        let mut bike =
            Bicycle::at_centre(Point::new(radius, 0.0), std::f64::consts::FRAC_PI_2, 2.7);
        let speed = 4.0;
        let (mut worst_front, mut worst): (f64, f64) = (0.0, 0.0);
        for step in 0..400 {
            let (point, heading) = on_circle(bike.front());
            let steer = bike.stanley(point, heading, speed, 2.0, 0.6);
            bike.advance(speed * 0.1, steer);
            if step > 50 {
                worst = worst.max((bike.centre().norm() - radius).abs());
                worst_front = worst_front.max((bike.front().norm() - radius).abs());
            }
        }
        assert!(worst_front < 0.1 && worst < 0.4, "{worst_front} {worst}");
    }
}
