//! Whether a recording was made on a map: the one check every command that reads a
//! recording with a map runs before it measures, projects or judges anything.
//!
//! A recording given with another place's map does not fail on its own: its road users are
//! simply where the map has no lanes, so approaches, gaps and frames come out few and wrong.
//! The check is the share of the recording's vehicle positions that lie near the centre line
//! of one of the map's lanes. Measured on the INTERACTION roundabouts: at least 94.7 % of
//! every FT and EP recording's positions lie within [`NEAR_LANE_M`] of their own map's lanes,
//! at most 59.2 % of another roundabout's (FT, EP, SR, LN, OF); [`MIN_SHARE_NEAR_LANES`]
//! sits between the two.

use maps::Map;
use maps::geometry::Point;
use rstar::RTree;
use rstar::primitives::Line;

use crate::project::LogFrame;

/// Positions this close to a lane's centre line count as on the map's lanes, m.
pub const NEAR_LANE_M: f64 = 5.0;
/// Below this share of positions near a lane the recording is taken to belong to another
/// map.
pub const MIN_SHARE_NEAR_LANES: f64 = 0.8;

/// How a recording's positions lie on a map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OnMap {
    /// Positions checked.
    pub positions: usize,
    /// Of them, those within [`NEAR_LANE_M`] of a lane's centre line.
    pub near: usize,
}

impl OnMap {
    /// The share of positions near a lane (0 when there are none).
    pub fn share(&self) -> f64 {
        self.near as f64 / self.positions.max(1) as f64
    }

    /// Whether the recording belongs to the map: enough of its positions lie near a lane.
    /// A recording with no position passes (there is nothing to measure wrongly).
    pub fn on_map(&self) -> bool {
        self.positions == 0 || self.share() >= MIN_SHARE_NEAR_LANES
    }
}

/// The recording's road users do not drive on the map: too few of their positions lie near
/// a lane (the message gives the figures; the caller names the recording and the map).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error(
    "{:.1} % of their {} positions lie within {} m of a lane (at least {:.0} % must)",
    .0.share() * 100.0,
    .0.positions,
    NEAR_LANE_M,
    MIN_SHARE_NEAR_LANES * 100.0
)]
pub struct NotOnMap(pub OnMap);

/// The map's lanes' centre lines, indexed for the check.
#[derive(Debug)]
pub struct LaneLines {
    tree: RTree<Line<[f64; 2]>>,
}

impl LaneLines {
    /// Every lane of `map` (car lanes and the others: a recording's vehicles may use any).
    pub fn new(map: &Map) -> Self {
        let segments: Vec<Line<[f64; 2]>> = map
            .lanes
            .values()
            .flat_map(|lane| {
                lane.centre
                    .windows(2)
                    .map(|w| Line::new([w[0].x, w[0].y], [w[1].x, w[1].y]))
            })
            .collect();
        LaneLines {
            tree: RTree::bulk_load(segments),
        }
    }

    /// Whether `p` lies within [`NEAR_LANE_M`] of a lane's centre line.
    pub fn near(&self, p: Point) -> bool {
        self.tree
            .locate_within_distance([p.x, p.y], NEAR_LANE_M * NEAR_LANE_M)
            .next()
            .is_some()
    }

    /// How `positions` lie on the lanes.
    pub fn measure(&self, positions: impl IntoIterator<Item = Point>) -> OnMap {
        let (mut all, mut near) = (0, 0);
        for p in positions {
            all += 1;
            near += usize::from(self.near(p));
        }
        OnMap {
            positions: all,
            near,
        }
    }
}

/// The vehicles' positions in a recording's frames (pedestrians walk off the lanes).
pub fn vehicle_positions(frames: &[LogFrame]) -> impl Iterator<Item = Point> + '_ {
    frames.iter().flat_map(|f| {
        f.actors
            .iter()
            .filter(|a| a.kind == sim::ActorKind::Car)
            .map(|a| a.position)
    })
}

/// Checks that `positions` (a recording's vehicles) lie on `map`'s lanes.
pub fn check_on_map(
    map: &Map,
    positions: impl IntoIterator<Item = Point>,
) -> Result<OnMap, NotOnMap> {
    let measured = LaneLines::new(map).measure(positions);
    if measured.on_map() {
        Ok(measured)
    } else {
        Err(NotOnMap(measured))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_share_counts_positions_near_a_lane() {
        let m = OnMap {
            positions: 10,
            near: 8,
        };
        assert!((m.share() - 0.8).abs() < 1e-12);
        assert!(m.on_map());
        let m = OnMap {
            positions: 10,
            near: 7,
        };
        assert!(!m.on_map());
        let err = NotOnMap(m).to_string();
        assert_eq!(
            err,
            "70.0 % of their 10 positions lie within 5 m of a lane (at least 80 % must)"
        );
        assert!(
            OnMap {
                positions: 0,
                near: 0
            }
            .on_map()
        );
    }
}
