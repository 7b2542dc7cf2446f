//! Gap extraction on a hand-built case with known gaps: on the bundled montlake map, one
//! driver waits at an entry while three vehicles circulate past its merge point at known
//! times; the lag, the rejected gap, the accepted gap and what the driver could see when
//! each was offered are known exactly; a vehicle first seen at another entry's line is no
//! approach and offered nothing.

#![allow(clippy::unwrap_used)]

use std::path::Path;

use logs::project::LogFrame;
use maps::geometry::Point;
use sim::{Actor, ActorKind};
use traffic::decisions::{LabelConfig, approaches};
use traffic::gaps::offered_gaps;
use traffic::measure::RingGeometry;

const STEP_S: f64 = 0.1;
/// The circulating vehicles' speed, m/s.
const RING_SPEED: f64 = 6.0;
/// When each circulating vehicle passes the merge point, s; each is on the map from 5 s
/// before to 1 s after.
const PASSES: [f64; 3] = [10.0, 14.0, 22.0];
/// When the driver, stopped 2 m before its line, moves off, s.
const GO_S: f64 = 15.0;

fn car(id: u32, position: Point, heading_rad: f64) -> Actor {
    Actor {
        id,
        kind: ActorKind::Car,
        position,
        heading_rad,
        speed_mps: 0.0,
        length_m: 4.5,
        width_m: 1.8,
        lane: None,
        aggressiveness: None,
    }
}

#[test]
fn the_gaps_of_a_hand_built_approach_are_the_ones_built() {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/osm/montlake_roundabout.osm.pbf");
    let map = maps::import_file(&path, &Default::default()).unwrap();
    let id = *map.roundabouts.keys().next().unwrap();
    let g = RingGeometry::new(&map, id).unwrap();
    let line = &g.entries[0].line;
    let mid = line[0].add(line[line.len() - 1]).scale(0.5);
    let out = mid.sub(g.centre).scale(1.0 / mid.distance(g.centre));
    let d_line = mid.distance(g.centre);
    let r = g.radius_m;
    let theta_m = out.y.atan2(out.x);
    let tangent = |theta: f64| theta + g.turn * std::f64::consts::FRAC_PI_2;
    let omega = RING_SPEED / r;

    let mut frames = Vec::new();
    let mut inward_since: Option<f64> = None;
    for k in 0..=300 {
        let t = k as f64 * STEP_S;
        let mut actors = Vec::new();
        // The driver: 30 m out at 8 m/s, stopped 2 m before its line until GO_S, then in at
        // 5 m/s to the ring, then round it.
        let along = if t < GO_S {
            (8.0 * t).min(28.0)
        } else {
            28.0 + 5.0 * (t - GO_S)
        };
        let dist = d_line + 30.0 - along;
        if dist > r {
            actors.push(car(
                1,
                g.centre.add(out.scale(dist)),
                theta_m + std::f64::consts::PI,
            ));
        } else {
            let since = *inward_since.get_or_insert(t);
            let theta = theta_m + g.turn * 5.0 * (t - since) / r;
            actors.push(car(
                1,
                g.centre.add(Point::new(theta.cos(), theta.sin()).scale(r)),
                tangent(theta),
            ));
        }
        // The circulating vehicles (drifting outwards by a hair, so never towards a line).
        for (j, &pass) in PASSES.iter().enumerate() {
            if t >= pass - 5.0 - 1e-9 && t <= pass + 1.0 + 1e-9 {
                let theta = theta_m - g.turn * omega * (pass - t);
                let radius = r + 1e-4 * t;
                actors.push(car(
                    10 + j as u32,
                    g.centre
                        .add(Point::new(theta.cos(), theta.sin()).scale(radius)),
                    tangent(theta),
                ));
            }
        }
        frames.push(LogFrame {
            time_ns: 1_000_000_000 + k * 100_000_000,
            actors,
        });
    }

    // A vehicle first seen 1.1 m before another entry's line and across it 0.3 s later (then
    // gone): it crossed a yield line without an approach (under `min_approach_s` of its
    // track before the line), so it is counted and left out, as `replay eval` leaves it out.
    assert!(g.entries.len() > 1);
    let line1 = &g.entries[1].line;
    let mid1 = line1[0].add(line1[line1.len() - 1]).scale(0.5);
    let out1 = mid1.sub(g.centre).scale(1.0 / mid1.distance(g.centre));
    for (j, f) in frames.iter_mut().skip(250).take(6).enumerate() {
        let outside = 1.1 - 0.4 * j as f64;
        f.actors.push(car(
            2,
            mid1.add(out1.scale(outside)),
            out1.y.atan2(out1.x) + std::f64::consts::PI,
        ));
    }
    let labels = LabelConfig::default();
    let found = offered_gaps(&map, &g, "hand-built", &frames, &labels);
    let approached: Vec<u32> = approaches(&map, &frames, &labels)
        .iter()
        .map(|a| a.track)
        .collect();
    assert_eq!(approached, [1]);
    assert_eq!((found.approaches, found.without_approach), (1, 1));
    let e = &found.measured.entering;
    assert_eq!(e.len(), 1, "{e:?}");
    let e = &e[0];
    assert_eq!((e.track, e.entry), (1, 0));
    // At the line (10 m of driving before it) at 2.5 s; passes at 10 and 14 s while it waits;
    // it merges at about 15.5 s, before the pass at 22 s.
    let near = |a: f64, b: f64, tol: f64| (a - b).abs() <= tol;
    assert!(near(e.at_line_s, 2.5, 0.11), "{e:?}");
    assert_eq!(e.gap_starts_s.len(), 3, "{e:?}");
    assert!(
        near(e.gap_starts_s[1], 10.0, 0.02) && near(e.gap_starts_s[2], 14.0, 0.02),
        "{e:?}"
    );
    assert!(
        near(e.rejected_s[0], 7.5, 0.12) && near(e.rejected_s[1], 4.0, 0.02),
        "{e:?}"
    );
    assert!(near(e.accepted_s.unwrap(), 8.0, 0.02), "{e:?}");

    let gaps = &found.gaps;
    assert_eq!(gaps.len(), 3);
    let accepted: Vec<bool> = gaps.iter().map(|g| g.accepted).collect();
    assert_eq!(accepted, [false, false, true]);
    let lengths: Vec<f64> = gaps.iter().map(|g| g.length_s).collect();
    assert!(
        near(lengths[0], 7.5, 0.12) && near(lengths[1], 4.0, 0.02) && near(lengths[2], 8.0, 0.02)
    );
    // Offered the lag at 2.5 s, nothing circulates yet: the estimate is the cap.
    let f0 = &gaps[0].features;
    assert!(near(f0.eta_s, traffic::measure::GAP_CAP_S, 1e-9), "{f0:?}");
    assert!(
        f0.own_speed_mps > 7.0 && near(f0.own_distance_m, 10.0, 0.9),
        "{f0:?}"
    );
    // Offered the gap after the first pass at 10 s: the second vehicle is 4 s (24 m) away at
    // 6 m/s, going round (not outwards); the driver has stood 7.5 s, 2 m before its line.
    let f1 = &gaps[1].features;
    assert!(near(f1.eta_s, 4.0, 0.1), "{f1:?}");
    assert!(near(f1.next_distance_m, 24.0, 0.5), "{f1:?}");
    assert!(
        near(f1.next_speed_mps, RING_SPEED, 0.1) && f1.next_outward_mps.abs() < 0.1,
        "{f1:?}"
    );
    assert!(
        f1.own_speed_mps < 0.1 && near(f1.own_distance_m, 2.0, 0.6),
        "{f1:?}"
    );
    assert!(
        near(f1.waited_s, 7.5, 0.12) && f1.rejected_before == 1,
        "{f1:?}"
    );
    assert_eq!(f1.upstream, 1);
    // Crossing the line at another time accepts another gap: the one the crossing falls in,
    // from the later of the arrival and the last pass (closed loop measures a policy so).
    let m = &found.measured;
    assert!(near(m.gap_at(0, 1, e.at_line_s, 5.0).unwrap(), 7.5, 0.12));
    assert!(near(m.gap_at(0, 1, e.at_line_s, 12.0).unwrap(), 4.0, 0.02));
    assert!(near(
        m.gap_at(0, 1, e.at_line_s, e.crossed_s).unwrap(),
        8.0,
        0.02
    ));
    // After the second pass at 14 s the third vehicle is not on the map yet.
    let f2 = &gaps[2].features;
    assert!(near(f2.eta_s, traffic::measure::GAP_CAP_S, 1e-9) && f2.rejected_before == 2);
}
