//! What OSM tags mean for driving: lane counts, widths, speed limits, driving side.
//!
//! Every default lives in one table here, and `docs/maps.md` reproduces them.

use crate::model::DrivingSide;
use crate::osm::Tags;
use crate::projection::LatLon;

/// Per road class: (highway, lanes per direction, lane width m, speed km/h) when untagged.
/// Lane counts follow SUMO's OSM type map so lane lengths are comparable with netconvert.
pub const CLASS_DEFAULTS: &[(&str, u8, f64, f64)] = &[
    ("motorway", 2, 3.5, 120.0),
    ("motorway_link", 1, 3.5, 80.0),
    ("trunk", 2, 3.5, 100.0),
    ("trunk_link", 1, 3.5, 60.0),
    ("primary", 2, 3.5, 80.0),
    ("primary_link", 1, 3.25, 50.0),
    ("secondary", 1, 3.25, 60.0),
    ("secondary_link", 1, 3.25, 50.0),
    ("tertiary", 1, 3.25, 50.0),
    ("tertiary_link", 1, 3.25, 40.0),
    ("unclassified", 1, 3.0, 50.0),
    ("residential", 1, 3.0, 40.0),
    ("living_street", 1, 3.0, 10.0),
    ("road", 1, 3.0, 40.0),
    ("service", 1, 2.75, 20.0),
    ("cycleway", 1, 1.5, 20.0),
    ("footway", 1, 1.5, 5.0),
    ("path", 1, 1.5, 5.0),
    ("pedestrian", 1, 2.0, 5.0),
    ("track", 1, 2.5, 20.0),
    ("busway", 1, 3.25, 50.0),
    ("bridleway", 1, 1.5, 5.0),
];

fn class_defaults(highway: &str) -> (u8, f64, f64) {
    CLASS_DEFAULTS
        .iter()
        .find(|(h, ..)| *h == highway)
        .map(|&(_, n, w, v)| (n, w, v))
        .unwrap_or((1, 3.0, 40.0))
}

/// Travel directions of a way.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Oneway {
    No,
    Forward,
    Backward,
}

/// `oneway=yes|true|1` forward, `-1|reverse` backward, `no` two-way; roundabouts and
/// motorways are one-way unless tagged otherwise.
pub fn oneway(tags: &Tags) -> Oneway {
    match tags.get("oneway") {
        Some("yes" | "true" | "1") => Oneway::Forward,
        Some("-1" | "reverse") => Oneway::Backward,
        Some("no" | "false" | "0") => Oneway::No,
        _ if is_roundabout(tags) => Oneway::Forward,
        _ if tags.is("highway", "motorway") => Oneway::Forward,
        _ => Oneway::No,
    }
}

pub fn is_roundabout(tags: &Tags) -> bool {
    tags.is_any("junction", &["roundabout", "circular"])
}

/// A lane count tag (`lanes`, `lanes:forward`, ...) when it is a usable number (1 to 8).
pub fn parse_count(tags: &Tags, key: &str) -> Option<u8> {
    let v = tags.get(key)?;
    // "2;3" (disagreeing mappers) takes the first; absurd values are ignored.
    let n: u8 = v.split(';').next()?.trim().parse().ok()?;
    (1..=8).contains(&n).then_some(n)
}

/// Lanes (forward, backward) along the way's node order.
///
/// `lanes:forward` / `lanes:backward` win; otherwise `lanes` is split between the directions
/// (odd counts give the extra lane to forward), a two-way `lanes=1` still gets one lane each
/// way (a narrow two-way street must be drivable both ways), and untagged ways take the class
/// default per direction.
pub fn lane_counts(tags: &Tags, highway: &str) -> (u8, u8) {
    let dir = oneway(tags);
    let default = class_defaults(highway).0;
    let total = parse_count(tags, "lanes");
    let fwd = parse_count(tags, "lanes:forward");
    let bwd = parse_count(tags, "lanes:backward");
    match dir {
        Oneway::Forward => (fwd.or(total).unwrap_or(default), 0),
        Oneway::Backward => (0, bwd.or(total).unwrap_or(default)),
        Oneway::No => match (fwd, bwd, total) {
            (Some(f), Some(b), _) => (f, b),
            (Some(f), None, Some(t)) => (f, t.saturating_sub(f).max(1)),
            (None, Some(b), Some(t)) => (t.saturating_sub(b).max(1), b),
            (Some(f), None, None) => (f, default),
            (None, Some(b), None) => (default, b),
            (None, None, Some(t)) if t >= 2 => (t.div_ceil(2), t / 2),
            (None, None, Some(_)) => (1, 1),
            (None, None, None) => (default, default),
        },
    }
}

/// Lane width: `width` (the carriageway) shared among the lanes, else the class default.
pub fn lane_width(tags: &Tags, highway: &str, total_lanes: u8) -> f64 {
    let default = class_defaults(highway).1;
    tags.get("width")
        .and_then(parse_length_m)
        .map(|w| (w / f64::from(total_lanes.max(1))).clamp(2.0, 5.0))
        .unwrap_or(default)
}

fn parse_length_m(v: &str) -> Option<f64> {
    let v = v.trim();
    let (num, factor) = if let Some(n) = v.strip_suffix("ft") {
        (n, 0.3048)
    } else if let Some(n) = v.strip_suffix('m') {
        (n, 1.0)
    } else {
        (v, 1.0)
    };
    let x: f64 = num.trim().parse().ok()?;
    (x.is_finite() && x > 0.0).then_some(x * factor)
}

/// `XX:zone` speed limits (km/h) used when `maxspeed` names a zone instead of a number.
const ZONE_SPEEDS: &[(&str, f64)] = &[
    ("urban", 50.0),
    ("rural", 90.0),
    ("motorway", 130.0),
    ("trunk", 100.0),
    ("living_street", 7.0),
    ("walk", 7.0),
    ("bicycle_road", 30.0),
    ("zone20", 20.0),
    ("zone30", 30.0),
    ("zone:30", 30.0),
    ("zone40", 40.0),
    ("school", 30.0),
];

/// Country-specific zone speeds where they differ from [`ZONE_SPEEDS`].
const COUNTRY_ZONE_SPEEDS: &[(&str, &str, f64)] = &[
    ("DE", "rural", 100.0),
    ("AT", "rural", 100.0),
    ("FR", "rural", 80.0),
    ("GB", "urban", 48.28),
    ("GB", "rural", 96.56),
    ("GB", "motorway", 112.65),
    ("GB", "nsl_single", 96.56),
    ("GB", "nsl_dual", 112.65),
    ("UK", "nsl_single", 96.56),
    ("UK", "nsl_dual", 112.65),
    ("US", "urban", 40.23),
    ("FI", "rural", 80.0),
    ("FI", "urban", 50.0),
    ("CH", "rural", 80.0),
    ("CH", "motorway", 120.0),
    ("NL", "rural", 80.0),
];

/// Parses `maxspeed`: `50`, `30 mph`, `walk`, `none`, `DE:urban`, `RU:living_street`.
/// Returns km/h, or None when the value is not understood.
pub fn parse_maxspeed(v: &str) -> Option<f64> {
    let v = v.split(';').next()?.trim();
    match v {
        "walk" => return Some(7.0),
        "none" | "signals" | "variable" => return None,
        _ => {}
    }
    if let Some((country, zone)) = v.split_once(':') {
        let zone = zone.trim();
        if let Some(&(_, _, s)) = COUNTRY_ZONE_SPEEDS
            .iter()
            .find(|(c, z, _)| *c == country && *z == zone)
        {
            return Some(s);
        }
        return ZONE_SPEEDS
            .iter()
            .find(|(z, _)| *z == zone)
            .map(|&(_, s)| s);
    }
    let (num, factor) = if let Some(n) = v.strip_suffix("mph") {
        (n, 1.609_344)
    } else if let Some(n) = v.strip_suffix("knots") {
        (n, 1.852)
    } else if let Some(n) = v.strip_suffix("km/h") {
        (n, 1.0)
    } else {
        (v, 1.0)
    };
    let x: f64 = num.trim().parse().ok()?;
    (x.is_finite() && x > 0.0 && x < 400.0).then_some(x * factor)
}

/// Speed limit in km/h and whether it is a class default rather than a tag.
pub fn speed_limit_kmh(tags: &Tags, highway: &str, direction_key: Option<&str>) -> (f64, bool) {
    let tagged = direction_key
        .and_then(|k| tags.get(k))
        .or_else(|| tags.get("maxspeed"))
        .and_then(parse_maxspeed);
    match tagged {
        Some(s) => (s, false),
        None => (class_defaults(highway).2, true),
    }
}

/// Left-hand traffic regions, as coarse lon/lat boxes (min lon, min lat, max lon, max lat).
/// Good enough to pick a default; `--driving-side` overrides it.
const LEFT_HAND_TRAFFIC: &[(&str, [f64; 4])] = &[
    ("Great Britain", [-8.7, 49.8, 1.8, 60.9]),
    ("Ireland", [-10.7, 51.3, -5.9, 55.5]),
    ("US Virgin Islands", [-65.1, 17.6, -64.5, 18.5]),
    ("British Virgin Islands", [-64.9, 18.3, -64.2, 18.8]),
    ("Japan", [122.9, 24.0, 146.0, 45.6]),
    ("Australia", [112.9, -43.7, 153.7, -10.0]),
    ("New Zealand", [166.3, -47.4, 178.6, -34.3]),
    ("India", [68.1, 6.7, 97.4, 35.5]),
    ("South Africa", [16.4, -34.9, 32.9, -22.1]),
    ("Indonesia", [95.0, -11.0, 141.0, 6.0]),
    ("Thailand", [97.3, 5.6, 105.7, 20.5]),
    ("Malaysia", [99.6, 0.8, 119.3, 7.4]),
    ("Hong Kong", [113.8, 22.1, 114.5, 22.6]),
    ("Kenya", [33.9, -4.7, 41.9, 5.0]),
];

/// The driving side at a position; right unless it falls in a listed left-hand region.
pub fn driving_side_at(p: LatLon) -> DrivingSide {
    let left = LEFT_HAND_TRAFFIC
        .iter()
        .any(|(_, [a, b, c, d])| p.lon >= *a && p.lon <= *c && p.lat >= *b && p.lat <= *d);
    if left {
        DrivingSide::Left
    } else {
        DrivingSide::Right
    }
}

/// `turn:lanes` split per lane (left to right), for one direction.
pub fn turn_lanes(tags: &Tags, key: &str) -> Vec<Vec<String>> {
    tags.get(key)
        .map(|v| {
            v.split('|')
                .map(|lane| {
                    lane.split(';')
                        .map(|t| t.trim().to_owned())
                        .filter(|t| !t.is_empty())
                        .collect()
                })
                .collect()
        })
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tags(pairs: &[(&str, &str)]) -> Tags {
        Tags::from_pairs(pairs)
    }

    #[test]
    fn lane_counts_follow_the_tags() {
        assert_eq!(
            lane_counts(&tags(&[("highway", "residential")]), "residential"),
            (1, 1)
        );
        assert_eq!(lane_counts(&tags(&[("lanes", "4")]), "primary"), (2, 2));
        assert_eq!(lane_counts(&tags(&[("lanes", "3")]), "secondary"), (2, 1));
        assert_eq!(
            lane_counts(
                &tags(&[("lanes", "3"), ("lanes:backward", "2")]),
                "secondary"
            ),
            (1, 2)
        );
        assert_eq!(
            lane_counts(&tags(&[("oneway", "yes"), ("lanes", "3")]), "primary"),
            (3, 0)
        );
        assert_eq!(
            lane_counts(&tags(&[("oneway", "-1"), ("lanes", "2")]), "primary"),
            (0, 2)
        );
        assert_eq!(
            lane_counts(&tags(&[("junction", "roundabout")]), "residential"),
            (1, 0)
        );
        assert_eq!(
            lane_counts(
                &tags(&[("junction", "roundabout"), ("oneway", "no")]),
                "residential"
            ),
            (1, 1)
        );
        assert_eq!(lane_counts(&tags(&[("lanes", "1")]), "residential"), (1, 1));
        assert_eq!(
            lane_counts(&tags(&[("highway", "motorway")]), "motorway"),
            (2, 0)
        );
    }

    #[test]
    fn maxspeed_units_and_zones() {
        assert_eq!(parse_maxspeed("50"), Some(50.0));
        assert!((parse_maxspeed("30 mph").unwrap_or(0.0) - 48.28).abs() < 0.01);
        assert_eq!(parse_maxspeed("walk"), Some(7.0));
        assert_eq!(parse_maxspeed("DE:urban"), Some(50.0));
        assert_eq!(parse_maxspeed("DE:rural"), Some(100.0));
        assert_eq!(parse_maxspeed("RU:living_street"), Some(7.0));
        assert_eq!(parse_maxspeed("none"), None);
        assert_eq!(parse_maxspeed("fast"), None);
        let (s, default) = speed_limit_kmh(&tags(&[("maxspeed", "25 mph")]), "residential", None);
        assert!(!default && (s - 40.23).abs() < 0.01);
        assert_eq!(
            speed_limit_kmh(&tags(&[]), "residential", None),
            (40.0, true)
        );
    }

    #[test]
    fn driving_side_regions() {
        assert_eq!(driving_side_at(LatLon::new(53.8, -1.54)), DrivingSide::Left); // Leeds
        assert_eq!(
            driving_side_at(LatLon::new(17.71, -64.88)),
            DrivingSide::Left
        ); // Frederiksted
        assert_eq!(
            driving_side_at(LatLon::new(42.05, -87.68)),
            DrivingSide::Right
        ); // Evanston
        assert_eq!(
            driving_side_at(LatLon::new(60.17, 24.94)),
            DrivingSide::Right
        ); // Helsinki
    }

    #[test]
    fn turn_lanes_split() {
        let t = tags(&[("turn:lanes:forward", "left|through;right|")]);
        assert_eq!(
            turn_lanes(&t, "turn:lanes:forward"),
            vec![
                vec!["left".to_owned()],
                vec!["through".into(), "right".into()],
                vec![]
            ]
        );
    }
}
