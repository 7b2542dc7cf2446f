//! Domain randomisation: the look of one view, drawn from the view's own generator, so a
//! segmenter trained on the images does not learn one road colour, one sky or one sun.
//!
//! A [`Look`] is plain data (recorded in each item's `params`): colours of road, paint,
//! sidewalks, grass, buildings and trees; how worn the paint is (faded everywhere, and a
//! share of marking pieces missing, which the label follows: a missing dash is road);
//! texture noise; sun direction and strength, ambient light and shadow depth; the sky
//! gradient; haze and fog by depth; rain streaks; exposure and sensor noise.

use rand::Rng;
use serde::{Deserialize, Serialize};

use super::scene::{CentreLineStyle, Material, uniform};
use super::solids::Rgb;

/// How much the look varies between views.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RandomiseConfig {
    /// False: every view gets the same plain look (clear noon, grey road, white paint).
    pub enabled: bool,
    /// Share of views with fog (beyond the light haze every view has).
    pub fog_probability: f64,
    /// Share of views with rain.
    pub rain_probability: f64,
    /// Most of a view's marking pieces that may be worn away.
    pub max_paint_missing: f64,
    /// Camera pose jitter (uniform in ± these).
    pub camera: CameraJitter,
}

impl Default for RandomiseConfig {
    fn default() -> Self {
        RandomiseConfig {
            enabled: true,
            fog_probability: 0.15,
            rain_probability: 0.15,
            max_paint_missing: 0.3,
            camera: CameraJitter::default(),
        }
    }
}

/// Uniform jitter of the camera around its nominal pose.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CameraJitter {
    pub height_m: f64,
    pub pitch_deg: f64,
    pub roll_deg: f64,
    pub yaw_deg: f64,
    /// Sideways from the lane centre.
    pub lateral_m: f64,
}

impl Default for CameraJitter {
    fn default() -> Self {
        CameraJitter {
            height_m: 0.1,
            pitch_deg: 1.5,
            roll_deg: 1.5,
            yaw_deg: 4.0,
            lateral_m: 0.5,
        }
    }
}

/// Rain as streaks over the image.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Rain {
    pub streaks: u32,
    pub length_px: f32,
    /// From vertical, degrees.
    pub angle_deg: f32,
    /// Blend weight of a streak towards its colour.
    pub opacity: f32,
    pub seed: u64,
}

/// Everything that decides how one view looks. Colours are RGB in [0, 1].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Look {
    pub road: Rgb,
    pub sidewalk: Rgb,
    pub kerb: Rgb,
    pub terrain: Rgb,
    pub white_paint: Rgb,
    pub yellow_paint: Rgb,
    pub centre_lines: CentreLineStyle,
    /// How far paint is blended towards the road colour, on average.
    pub paint_fade: f32,
    /// Share of marking pieces worn away completely (label: road).
    pub paint_missing: f64,
    /// Amplitude of fine texture noise (asphalt grain, grass).
    pub grain: f32,
    /// Amplitude of large blotches (patches, wet spots, worn tracks).
    pub blotches: f32,
    pub building_tint: Rgb,
    pub vegetation_tint: Rgb,
    pub sky_horizon: Rgb,
    pub sky_zenith: Rgb,
    pub sun_azimuth_deg: f64,
    pub sun_elevation_deg: f64,
    /// Direct light on a surface facing the sun, and light from everywhere.
    pub sun: f32,
    pub ambient: f32,
    /// Fraction of light a cast shadow takes away.
    pub shadow: f32,
    /// Haze and fog: extinction per metre of depth.
    pub fog_per_m: f64,
    pub fog: Rgb,
    pub rain: Option<Rain>,
    pub exposure: f32,
    /// Standard deviation-like amplitude of per-pixel noise, in 0..255 units.
    pub sensor_noise: f32,
}

fn rgb(rng: &mut impl Rng, base: Rgb, spread: f32, tint: f32) -> Rgb {
    let k = 1.0 + spread * (rng.random::<f32>() * 2.0 - 1.0);
    let mut c = [0.0f32; 3];
    for (ch, b) in c.iter_mut().zip(base) {
        let t = 1.0 + tint * (rng.random::<f32>() * 2.0 - 1.0);
        *ch = (b * k * t).clamp(0.0, 1.0);
    }
    c
}

fn range_f32(rng: &mut impl Rng, lo: f32, hi: f32) -> f32 {
    lo + (hi - lo) * rng.random::<f32>()
}

fn mix(a: Rgb, b: Rgb, t: f32) -> Rgb {
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

impl Look {
    /// A plain look: clear noon, grey road, fresh paint, no weather.
    pub fn plain() -> Look {
        Look {
            road: [0.36, 0.36, 0.37],
            sidewalk: [0.62, 0.61, 0.58],
            kerb: [0.75, 0.75, 0.72],
            terrain: [0.3, 0.42, 0.2],
            white_paint: [0.92, 0.92, 0.9],
            yellow_paint: [0.9, 0.72, 0.15],
            centre_lines: CentreLineStyle::DoubleYellow,
            paint_fade: 0.0,
            paint_missing: 0.0,
            grain: 0.06,
            blotches: 0.05,
            building_tint: [1.0; 3],
            vegetation_tint: [1.0; 3],
            sky_horizon: [0.78, 0.85, 0.92],
            sky_zenith: [0.35, 0.55, 0.85],
            sun_azimuth_deg: 200.0,
            sun_elevation_deg: 55.0,
            sun: 0.55,
            ambient: 0.55,
            shadow: 0.45,
            fog_per_m: 0.0015,
            fog: [0.78, 0.85, 0.92],
            rain: None,
            exposure: 1.0,
            sensor_noise: 0.0,
        }
    }

    /// A random look.
    pub fn draw(rng: &mut impl Rng, config: &RandomiseConfig) -> Look {
        if !config.enabled {
            return Look::plain();
        }
        let overcast = rng.random::<f32>();
        // Old asphalt is light grey, fresh asphalt nearly black; some roads are warm.
        let road_grey = range_f32(rng, 0.2, 0.55);
        let road = rgb(rng, [road_grey, road_grey, road_grey * 1.02], 0.0, 0.05);
        let sidewalk_grey = range_f32(rng, 0.5, 0.78);
        let sidewalk = rgb(
            rng,
            [sidewalk_grey, sidewalk_grey * 0.98, sidewalk_grey * 0.94],
            0.0,
            0.04,
        );
        let kerb = mix(sidewalk, [0.85, 0.85, 0.83], range_f32(rng, 0.0, 0.6));
        // Green grass to dry brown.
        let dry = rng.random::<f32>();
        let terrain = rgb(
            rng,
            mix([0.25, 0.42, 0.16], [0.5, 0.45, 0.3], dry * dry),
            0.2,
            0.05,
        );
        let white_paint = rgb(rng, [0.93, 0.93, 0.9], 0.1, 0.02);
        let yellow_paint = rgb(rng, [0.92, 0.72, 0.18], 0.12, 0.06);
        let centre_lines = match rng.random_range(0..10) {
            0..=5 => CentreLineStyle::DoubleYellow,
            6..=7 => CentreLineStyle::SingleYellow,
            _ => CentreLineStyle::DashedWhite,
        };
        let paint_fade = range_f32(rng, 0.0, 0.65).powi(2) * 1.4;
        let paint_missing = uniform(rng, (0.0, config.max_paint_missing.max(0.0)))
            * f64::from(rng.random::<u8>() % 2);
        // Clear blue to overcast grey; low sun gives warm light.
        let clear_zenith = rgb(rng, [0.3, 0.5, 0.85], 0.15, 0.05);
        let clear_horizon = rgb(rng, [0.75, 0.83, 0.92], 0.08, 0.03);
        let grey = range_f32(rng, 0.55, 0.85);
        let sky_zenith = mix(clear_zenith, [grey * 0.9; 3], overcast);
        let sky_horizon = mix(clear_horizon, [grey; 3], overcast);
        let sun_elevation_deg = uniform(rng, (15.0, 75.0));
        let sun_azimuth_deg = uniform(rng, (0.0, 360.0));
        let sun = range_f32(rng, 0.35, 0.7) * (1.0 - 0.85 * overcast);
        let ambient = range_f32(rng, 0.45, 0.65) + 0.25 * overcast;
        let shadow = (range_f32(rng, 0.35, 0.6) * (1.0 - overcast)).max(0.05);
        let fog = rng.random::<f64>() < config.fog_probability;
        let fog_per_m =
            uniform(rng, (0.0008, 0.004)) + if fog { uniform(rng, (0.01, 0.06)) } else { 0.0 };
        let rain = (rng.random::<f64>() < config.rain_probability).then(|| Rain {
            streaks: rng.random_range(150..900),
            length_px: range_f32(rng, 0.03, 0.12),
            angle_deg: range_f32(rng, -20.0, 20.0),
            opacity: range_f32(rng, 0.08, 0.3),
            seed: rng.random(),
        });
        let wet = if rain.is_some() { 0.75 } else { 1.0 };
        Look {
            road: road.map(|c| c * wet),
            sidewalk,
            kerb,
            terrain,
            white_paint,
            yellow_paint,
            centre_lines,
            paint_fade: paint_fade.min(0.85),
            paint_missing,
            grain: range_f32(rng, 0.02, 0.14),
            blotches: range_f32(rng, 0.0, 0.18),
            building_tint: rgb(rng, [1.0; 3], 0.15, 0.06),
            vegetation_tint: rgb(rng, [1.0; 3], 0.2, 0.08),
            sky_horizon,
            sky_zenith,
            sun_azimuth_deg,
            sun_elevation_deg,
            sun,
            ambient,
            shadow,
            fog_per_m,
            fog: sky_horizon,
            rain,
            exposure: range_f32(rng, 0.8, 1.2),
            sensor_noise: range_f32(rng, 0.0, 6.0),
        }
    }

    /// Base colour of a ground material.
    pub fn material(&self, m: Material) -> Rgb {
        match m {
            Material::Terrain => self.terrain,
            Material::Sidewalk => self.sidewalk,
            Material::Kerb => self.kerb,
            Material::Road => self.road,
            Material::WhitePaint => self.white_paint,
            Material::YellowPaint => self.yellow_paint,
        }
    }

    /// Unit vector towards the sun (world, z up).
    pub fn to_sun(&self) -> super::camera::Vec3 {
        let (el, az) = (
            self.sun_elevation_deg.to_radians(),
            self.sun_azimuth_deg.to_radians(),
        );
        super::camera::Vec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin())
    }

    /// Light on a surface with unit normal `n` (sun and ambient), without shadows.
    pub fn light(&self, n: super::camera::Vec3) -> f32 {
        self.ambient + self.sun * (n.dot(self.to_sun()).max(0.0) as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn looks_vary_and_repeat_with_the_seed() {
        let config = RandomiseConfig::default();
        let a = Look::draw(&mut ChaCha8Rng::seed_from_u64(1), &config);
        let b = Look::draw(&mut ChaCha8Rng::seed_from_u64(1), &config);
        let c = Look::draw(&mut ChaCha8Rng::seed_from_u64(2), &config);
        assert_eq!(a, b);
        assert_ne!(a, c);
        let plain = Look::draw(
            &mut ChaCha8Rng::seed_from_u64(1),
            &RandomiseConfig {
                enabled: false,
                ..config
            },
        );
        assert_eq!(plain, Look::plain());
        // Over many draws every colour stays in range and the weather shows up.
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let looks: Vec<Look> = (0..300).map(|_| Look::draw(&mut rng, &config)).collect();
        assert!(looks.iter().any(|l| l.rain.is_some()));
        assert!(looks.iter().any(|l| l.fog_per_m > 0.01));
        for l in &looks {
            for c in [l.road, l.sky_zenith, l.terrain, l.white_paint] {
                assert!(c.iter().all(|v| (0.0..=1.0).contains(v)));
            }
            assert!(l.to_sun().z > 0.0);
        }
    }
}
