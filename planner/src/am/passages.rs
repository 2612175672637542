//! Restarts through narrow passages. Robots the cold start routed around
//! static obstacles meet where their routes pass closest to them (a door,
//! a gap between shelves), all at about the same time with one timing; the
//! iterations, which are local, rarely change who passes first, and an
//! attempt that jams there stays jammed. A restart moves the time each
//! routed robot passes its route's narrowest point by a seeded amount (up
//! to [`SPREAD`] of the horizon), keeping its route and rest at both ends:
//! another order through each passage per attempt.

use nalgebra::Vector3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::route::{Blockers, Warp, quintic_inverse};

/// The most a restart moves a passage, in normalised time: 0.4 verified
/// three more scenes of 8 robots on seeds 100-119 (doorway, aisles), and
/// on the held-out seeds 200-219 three fewer aisles of 16 and one more
/// pillar forest of 16, the rest alike (docs/experiments/2026-11-29-restarts-through-narrow-passages.md).
const SPREAD: f64 = 0.25;

/// The earliest and latest passage a restart gives (normalised time): a
/// robot keeps some of the horizon to reach its passage and to leave it.
const WINDOW: (f64, f64) = (0.15, 0.85);

/// A robot the cold start routed around the static obstacles.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Routed {
    /// Its index.
    pub robot: usize,
    /// Its route, start to goal.
    pub path: Vec<Vector3<f64>>,
    /// When (normalised time) the cold start's timing passes the route's
    /// narrowest point ([`Blockers::narrowest`]).
    pub passes: f64,
}

impl Routed {
    /// Robot `robot` on `path` around `blockers`.
    pub fn new(blockers: &Blockers, robot: usize, path: Vec<Vector3<f64>>) -> Self {
        let passes = quintic_inverse(blockers.narrowest(&path));
        Self { robot, path, passes }
    }

    /// A clock warp that passes the narrowest point up to [`SPREAD`]
    /// earlier or later (within [`WINDOW`]), drawn from `rng`.
    pub fn shifted(&self, rng: &mut ChaCha8Rng) -> Warp {
        let at = (self.passes + rng.random_range(-SPREAD..=SPREAD)).clamp(WINDOW.0, WINDOW.1);
        Warp { at, to: self.passes }
    }
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;

    use super::*;
    use crate::problem::{Dim, Obstacle, Spheroid, Team};
    use crate::route::{quintic, route};

    #[test]
    fn a_shifted_passage_moves_when_the_gap_is_passed_and_keeps_both_ends() {
        // A wall along y with a gap at y = 0.5 (disc centres 0.4-0.6 apart
        // there): a robot from left to right routed through it.
        let team = Team::default_for(Dim::Two, 1);
        let wall: Vec<Obstacle> = (0..=20)
            .map(|k| -1.0 + 0.1 * k as f64)
            .filter(|y| (y - 0.5).abs() > 0.2)
            .map(|y| Obstacle {
                position: Vector3::new(0.0, y, 0.0),
                velocity: Vector3::zeros(),
                shape: Spheroid::ball(0.08),
            })
            .collect();
        let blockers = Blockers::new(&team, &wall, 0.05, 0.0);
        let (start, goal) = (Vector3::new(-0.7, -0.5, 0.0), Vector3::new(0.7, -0.5, 0.0));
        let path = route(&blockers, &start, &goal).unwrap();
        let routed = Routed::new(&blockers, 0, path);
        let gap = crate::route::along(&routed.path, quintic(routed.passes));
        // The route hugs the gap's lower side: its closest approach is just
        // past the wall, beside the gap.
        assert!((gap - Vector3::new(0.0, 0.5, 0.0)).norm() < 0.3, "the narrowest point is at the gap: {gap:?}");
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut moved = 0;
        for _ in 0..20 {
            let warp = routed.shifted(&mut rng);
            assert!((WINDOW.0..=WINDOW.1).contains(&warp.at) && (warp.at - routed.passes).abs() <= SPREAD + 1e-12);
            assert!((warp.clock(warp.at) - routed.passes).abs() < 1e-12, "the gap is passed at the warp's time");
            assert_eq!((warp.clock(0.0), warp.clock(1.0)), (0.0, 1.0), "start and goal keep their times");
            moved += usize::from((warp.at - routed.passes).abs() > 0.05);
        }
        assert!(moved >= 10, "most draws move the passage: {moved} of 20");
    }
}
