//! WGS84 to a local metric east-north frame, and back.
//!
//! Both conventions use one transverse Mercator implementation (Krüger's series to the
//! sixth order in the third flattening, the formulation PROJ's `tmerc` uses), which stays
//! at the sub-millimetre level well beyond the 10 km around an origin that maps need:
//!
//! - [`Projection::Local`]: a transverse Mercator centred on the origin's meridian with
//!   scale 1, shifted so the origin is (0, 0). This is the default for OSM imports.
//! - [`Projection::Utm`]: Lanelet2's `UtmProjector` convention: the UTM zone of the origin,
//!   scale 0.9996, minus the origin's own easting and northing. The INTERACTION maps use it
//!   with origin (0, 0), which is what lines their Lanelet2 maps up with their track files.

use serde::{Deserialize, Serialize};

use crate::geometry::Point;

/// WGS84 semi-major axis, metres.
const WGS84_A: f64 = 6_378_137.0;
/// WGS84 flattening.
const WGS84_F: f64 = 1.0 / 298.257_223_563;

/// A geographic position in degrees.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LatLon {
    pub lat: f64,
    pub lon: f64,
}

impl LatLon {
    pub fn new(lat: f64, lon: f64) -> Self {
        Self { lat, lon }
    }
}

/// How a map's metric frame relates to WGS84. Stored in every map.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
// Externally tagged (`{"local": {...}}`): the binary form (postcard) can read it back,
// which it cannot for internally tagged enums.
#[serde(rename_all = "snake_case")]
pub enum Projection {
    /// Transverse Mercator on the origin's meridian, scale 1, origin at (0, 0).
    Local { origin: LatLon },
    /// Lanelet2 / INTERACTION: UTM zone of the origin, minus the origin's UTM position.
    Utm { origin: LatLon, zone: u8 },
}

impl Projection {
    pub fn local(origin: LatLon) -> Self {
        Projection::Local { origin }
    }

    /// Lanelet2's `UtmProjector(Origin(lat, lon))`: zone `floor((lon + 180) / 6) + 1`.
    pub fn utm(origin: LatLon) -> Self {
        let zone = (((origin.lon + 180.0) / 6.0).floor() as i32 + 1).clamp(1, 60) as u8;
        Projection::Utm { origin, zone }
    }

    pub fn origin(&self) -> LatLon {
        match *self {
            Projection::Local { origin } | Projection::Utm { origin, .. } => origin,
        }
    }

    fn transverse_mercator(&self) -> (TransverseMercator, (f64, f64)) {
        match *self {
            Projection::Local { origin } => {
                let tm = TransverseMercator::new(origin.lon, 1.0);
                let offset = tm.forward(origin.lat, origin.lon);
                (tm, offset)
            }
            Projection::Utm { origin, zone } => {
                let central = f64::from(zone) * 6.0 - 183.0;
                let tm = TransverseMercator::new(central, 0.9996);
                let offset = tm.forward(origin.lat, origin.lon);
                (tm, offset)
            }
        }
    }

    /// Geographic position to map metres (x east, y north).
    pub fn project(&self, p: LatLon) -> Point {
        let (tm, (x0, y0)) = self.transverse_mercator();
        let (x, y) = tm.forward(p.lat, p.lon);
        Point::new(x - x0, y - y0)
    }

    /// Map metres back to a geographic position.
    pub fn unproject(&self, p: Point) -> LatLon {
        let (tm, (x0, y0)) = self.transverse_mercator();
        let (lat, lon) = tm.inverse(p.x + x0, p.y + y0);
        LatLon { lat, lon }
    }

    /// A projector that caches the series constants, for projecting many points.
    pub fn projector(&self) -> Projector {
        let (tm, offset) = self.transverse_mercator();
        Projector { tm, offset }
    }
}

/// [`Projection`] with its constants computed once.
#[derive(Debug, Clone)]
pub struct Projector {
    tm: TransverseMercator,
    offset: (f64, f64),
}

impl Projector {
    pub fn project(&self, p: LatLon) -> Point {
        let (x, y) = self.tm.forward(p.lat, p.lon);
        Point::new(x - self.offset.0, y - self.offset.1)
    }

    pub fn unproject(&self, p: Point) -> LatLon {
        let (lat, lon) = self.tm.inverse(p.x + self.offset.0, p.y + self.offset.1);
        LatLon { lat, lon }
    }
}

/// Krüger-series transverse Mercator with false easting 500 km for UTM (scale != 1) and
/// none for the local frame; the offset is removed by the caller anyway.
#[derive(Debug, Clone)]
struct TransverseMercator {
    lon0: f64,
    false_easting: f64,
    /// Rectifying radius times k0.
    a_hat: f64,
    alpha: [f64; 6],
    beta: [f64; 6],
    /// 2 sqrt(n) / (1 + n): the eccentricity-related constant for conformal latitude.
    e: f64,
}

impl TransverseMercator {
    fn new(lon0: f64, k0: f64) -> Self {
        let n = WGS84_F / (2.0 - WGS84_F);
        let (n2, n3) = (n * n, n * n * n);
        let (n4, n5, n6) = (n3 * n, n3 * n2, n3 * n3);
        let a_rect = WGS84_A / (1.0 + n) * (1.0 + n2 / 4.0 + n4 / 64.0 + n6 / 256.0);
        let alpha = [
            n / 2.0 - 2.0 * n2 / 3.0 + 5.0 * n3 / 16.0 + 41.0 * n4 / 180.0 - 127.0 * n5 / 288.0
                + 7891.0 * n6 / 37800.0,
            13.0 * n2 / 48.0 - 3.0 * n3 / 5.0 + 557.0 * n4 / 1440.0 + 281.0 * n5 / 630.0
                - 1983433.0 * n6 / 1935360.0,
            61.0 * n3 / 240.0 - 103.0 * n4 / 140.0
                + 15061.0 * n5 / 26880.0
                + 167603.0 * n6 / 181440.0,
            49561.0 * n4 / 161280.0 - 179.0 * n5 / 168.0 + 6601661.0 * n6 / 7257600.0,
            34729.0 * n5 / 80640.0 - 3418889.0 * n6 / 1995840.0,
            212378941.0 * n6 / 319334400.0,
        ];
        let beta = [
            n / 2.0 - 2.0 * n2 / 3.0 + 37.0 * n3 / 96.0 - n4 / 360.0 - 81.0 * n5 / 512.0
                + 96199.0 * n6 / 604800.0,
            n2 / 48.0 + n3 / 15.0 - 437.0 * n4 / 1440.0 + 46.0 * n5 / 105.0
                - 1118711.0 * n6 / 3870720.0,
            17.0 * n3 / 480.0 - 37.0 * n4 / 840.0 - 209.0 * n5 / 4480.0 + 5569.0 * n6 / 90720.0,
            4397.0 * n4 / 161280.0 - 11.0 * n5 / 504.0 - 830251.0 * n6 / 7257600.0,
            4583.0 * n5 / 161280.0 - 108847.0 * n6 / 3991680.0,
            20648693.0 * n6 / 638668800.0,
        ];
        let e = 2.0 * n.sqrt() / (1.0 + n);
        let false_easting = if k0 == 1.0 { 0.0 } else { 500_000.0 };
        Self {
            lon0,
            false_easting,
            a_hat: k0 * a_rect,
            alpha,
            beta,
            e,
        }
    }

    fn forward(&self, lat: f64, lon: f64) -> (f64, f64) {
        let phi = lat.to_radians();
        let lam = (lon - self.lon0).to_radians();
        // Conformal latitude.
        let t = (phi.sin().atanh() - self.e * (self.e * phi.sin()).atanh()).sinh();
        let xi_p = t.atan2(lam.cos());
        let eta_p = (lam.sin() / (1.0 + t * t).sqrt()).atanh();
        let (d_xi, d_eta) = kruger_sum(&self.alpha, xi_p, eta_p);
        let (xi, eta) = (xi_p + d_xi, eta_p + d_eta);
        (self.false_easting + self.a_hat * eta, self.a_hat * xi)
    }

    fn inverse(&self, x: f64, y: f64) -> (f64, f64) {
        let xi = y / self.a_hat;
        let eta = (x - self.false_easting) / self.a_hat;
        let (d_xi, d_eta) = kruger_sum(&self.beta, xi, eta);
        let (xi_p, eta_p) = (xi - d_xi, eta - d_eta);
        let chi = (xi_p.sin() / eta_p.cosh()).asin();
        let lam = eta_p.sinh().atan2(xi_p.cos());
        // Latitude from conformal latitude by Newton iteration on tau = tan(phi).
        let tau_p = chi.tan();
        let mut tau = tau_p;
        for _ in 0..8 {
            let sigma = (self.e * (self.e * tau / (1.0 + tau * tau).sqrt()).atanh()).sinh();
            let tau_i_p = tau * (1.0 + sigma * sigma).sqrt() - sigma * (1.0 + tau * tau).sqrt();
            let d = (tau_p - tau_i_p) / (1.0 + tau_i_p * tau_i_p).sqrt()
                * (1.0 + (1.0 - self.e * self.e) * tau * tau)
                / ((1.0 - self.e * self.e) * (1.0 + tau * tau).sqrt());
            tau += d;
            if d.abs() < 1e-14 {
                break;
            }
        }
        (tau.atan().to_degrees(), self.lon0 + lam.to_degrees())
    }
}

/// The Krüger series term Σ_j c_j sin(2j ζ) for ζ = ξ + iη, as (real, imaginary) parts:
/// (Σ c_j sin 2jξ cosh 2jη, Σ c_j cos 2jξ sinh 2jη).
///
/// The multiples come from the recurrence sin((j+1)w) = 2 cos(w) sin(jw) − sin((j−1)w) in
/// complex arithmetic, w = 2ζ: four transcendental calls per point instead of four per term,
/// which is most of the cost of projecting a map's points for its GeoJSON.
fn kruger_sum(c: &[f64; 6], xi: f64, eta: f64) -> (f64, f64) {
    let (s, co) = (2.0 * xi).sin_cos();
    let (sh, ch) = ((2.0 * eta).sinh(), (2.0 * eta).cosh());
    // sin(w) and cos(w) for complex w = 2ξ + 2iη.
    let sin_w = (s * ch, co * sh);
    let cos_w = (co * ch, -s * sh);
    let mul = |a: (f64, f64), b: (f64, f64)| (a.0 * b.0 - a.1 * b.1, a.0 * b.1 + a.1 * b.0);
    let (mut prev, mut cur) = ((0.0, 0.0), sin_w);
    let mut sum = (0.0, 0.0);
    for &cj in c {
        sum.0 += cj * cur.0;
        sum.1 += cj * cur.1;
        let twice = mul(cos_w, cur);
        let next = (2.0 * twice.0 - prev.0, 2.0 * twice.1 - prev.1);
        prev = cur;
        cur = next;
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn kruger_sum_matches_the_terms_evaluated_one_by_one() {
        let tm = TransverseMercator::new(3.0, 0.9996);
        for &(xi, eta) in &[
            (0.0, 0.0),
            (0.7, 0.05),
            (-1.2, -0.1),
            (0.3, 0.6),
            (1.5, 0.001),
        ] {
            let (mut re, mut im) = (0.0, 0.0);
            for (j, b) in tm.beta.iter().enumerate() {
                let k = 2.0 * (j as f64 + 1.0);
                re += b * (k * xi).sin() * (k * eta).cosh();
                im += b * (k * xi).cos() * (k * eta).sinh();
            }
            let (r, i) = kruger_sum(&tm.beta, xi, eta);
            assert!(
                (r - re).abs() < 1e-17 && (i - im).abs() < 1e-17,
                "({xi}, {eta}): {r} {i} against {re} {im}"
            );
        }
    }

    #[test]
    fn utm_zone_31_matches_interaction_convention() {
        // The INTERACTION README: easting of (0, 0) in zone 31 is 166021.44308054057 m.
        let tm = TransverseMercator::new(3.0, 0.9996);
        let (e, n) = tm.forward(0.0, 0.0);
        assert!((e - 166_021.443_080_540_57).abs() < 1e-6, "easting {e}");
        assert!(n.abs() < 1e-9);
        let p = Projection::utm(LatLon::new(0.0, 0.0));
        assert_eq!(
            p,
            Projection::Utm {
                origin: LatLon::new(0.0, 0.0),
                zone: 31
            }
        );
    }

    proptest! {
        #[test]
        fn round_trip_under_a_centimetre_within_10_km(
            lat0 in -80.0f64..80.0, lon0 in -179.0f64..179.0,
            dx in -10_000.0f64..10_000.0, dy in -10_000.0f64..10_000.0,
            utm in any::<bool>(),
        ) {
            let origin = LatLon::new(lat0, lon0);
            let proj = if utm { Projection::utm(origin) } else { Projection::local(origin) };
            let projector = proj.projector();
            let p = Point::new(dx, dy);
            let back = projector.project(projector.unproject(p));
            prop_assert!(back.distance(p) < 0.01, "{p:?} -> {back:?}");
            prop_assert!(projector.project(origin).distance(Point::new(0.0, 0.0)) < 1e-6);
        }

        #[test]
        fn local_frame_distances_match_geodesic_scale(lat0 in -70.0f64..70.0, lon0 in -179.0f64..179.0) {
            // 1 km east and north of the origin is 1 km in the map within 1 m (scale 1 at the meridian).
            let proj = Projection::local(LatLon::new(lat0, lon0)).projector();
            let north = proj.unproject(Point::new(0.0, 1000.0));
            prop_assert!((north.lon - lon0).abs() < 1e-9);
            let p = proj.project(north);
            prop_assert!((p.y - 1000.0).abs() < 1e-6);
        }
    }
}
