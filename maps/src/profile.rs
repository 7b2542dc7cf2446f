//! Road selection: which OSM ways become roads, and whether cars may use them.

use serde::{Deserialize, Serialize};

use crate::osm::Tags;

/// A road-selection profile. `car` is the default; `passenger` is the same without
/// `highway=service` (the scope of SUMO netconvert's `--keep-edges.by-vclass passenger`);
/// `all` also takes cycleways, footways and paths. Profiles can also be read from TOML.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RoadProfile {
    pub name: String,
    /// `highway=*` values that make a road.
    pub highways: Vec<String>,
    /// `highway=*` values among those that cars may drive on.
    pub car_highways: Vec<String>,
    /// Access keys, most specific first; the first one present decides.
    pub access_keys: Vec<String>,
    /// Access values that exclude a way.
    pub excluded_access: Vec<String>,
    /// `service=*` values that exclude a service road.
    pub excluded_service: Vec<String>,
}

const CAR_HIGHWAYS: &[&str] = &[
    "motorway",
    "motorway_link",
    "trunk",
    "trunk_link",
    "primary",
    "primary_link",
    "secondary",
    "secondary_link",
    "tertiary",
    "tertiary_link",
    "unclassified",
    "residential",
    "living_street",
    "road",
    "service",
];

impl Default for RoadProfile {
    fn default() -> Self {
        Self::car()
    }
}

fn strings(v: &[&str]) -> Vec<String> {
    v.iter().map(|s| (*s).to_owned()).collect()
}

impl RoadProfile {
    /// Motorway to residential, living streets and service roads (campus drives), honouring
    /// `motorcar` / `motor_vehicle` / `vehicle` / `access` = `no`.
    pub fn car() -> Self {
        RoadProfile {
            name: "car".into(),
            highways: strings(CAR_HIGHWAYS),
            car_highways: strings(CAR_HIGHWAYS),
            access_keys: strings(&["motorcar", "motor_vehicle", "vehicle", "access"]),
            excluded_access: strings(&["no", "agricultural", "forestry", "emergency"]),
            excluded_service: strings(&["emergency_access"]),
        }
    }

    /// The car profile without `highway=service`: netconvert's passenger-car scope.
    pub fn passenger() -> Self {
        let mut p = Self::car();
        p.name = "passenger".into();
        p.highways.retain(|h| h != "service");
        p.car_highways.retain(|h| h != "service");
        p
    }

    /// Every road a vehicle, bicycle or person can use; cars only where the car profile allows.
    pub fn all() -> Self {
        let mut p = Self::car();
        p.name = "all".into();
        p.highways.extend(strings(&[
            "cycleway",
            "footway",
            "path",
            "pedestrian",
            "track",
            "busway",
            "bridleway",
        ]));
        p.excluded_access.clear();
        p
    }

    pub fn by_name(name: &str) -> Option<Self> {
        match name {
            "car" => Some(Self::car()),
            "passenger" => Some(Self::passenger()),
            "all" => Some(Self::all()),
            _ => None,
        }
    }

    /// Whether a way becomes a road under this profile.
    pub fn selects(&self, tags: &Tags) -> bool {
        let Some(highway) = tags.get("highway") else {
            return false;
        };
        if !self.highways.iter().any(|h| h == highway) || tags.is("area", "yes") {
            return false;
        }
        if highway == "service"
            && tags
                .get("service")
                .is_some_and(|s| self.excluded_service.iter().any(|x| x == s))
        {
            return false;
        }
        // In the `all` profile a car ban does not remove the road, it only bars cars.
        self.excluded_access.is_empty() || self.cars_allowed(tags)
    }

    /// Whether passenger cars may use a selected way.
    pub fn cars_allowed(&self, tags: &Tags) -> bool {
        let Some(highway) = tags.get("highway") else {
            return false;
        };
        if !self.car_highways.iter().any(|h| h == highway) {
            return false;
        }
        let car_excluded = RoadProfile::car().excluded_access;
        let decisive = self.access_keys.iter().find_map(|k| tags.get(k));
        !decisive.is_some_and(|v| car_excluded.iter().any(|x| x == v))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tags(pairs: &[(&str, &str)]) -> Tags {
        Tags::from_pairs(pairs)
    }

    #[test]
    fn car_profile_honours_access_in_order() {
        let car = RoadProfile::car();
        assert!(car.selects(&tags(&[("highway", "residential")])));
        assert!(!car.selects(&tags(&[("highway", "footway")])));
        assert!(!car.selects(&tags(&[("highway", "residential"), ("access", "no")])));
        // A more specific key wins over `access`.
        assert!(car.selects(&tags(&[
            ("highway", "service"),
            ("access", "no"),
            ("motorcar", "yes")
        ])));
        assert!(!car.selects(&tags(&[("highway", "service"), ("motor_vehicle", "no")])));
        assert!(!car.selects(&tags(&[("highway", "residential"), ("area", "yes")])));
    }

    #[test]
    fn passenger_profile_drops_service_roads() {
        assert!(!RoadProfile::passenger().selects(&tags(&[("highway", "service")])));
        let all = RoadProfile::all();
        let cycleway = tags(&[("highway", "cycleway")]);
        assert!(all.selects(&cycleway) && !all.cars_allowed(&cycleway));
    }
}
