//! Every correction of one projection: the robot pairs (all, or the broad
//! phase's candidates, half of them on the helper where there is one), the
//! obstacles, the box.

use super::super::pairs::{BROAD_PHASE_MIN_ROBOTS, Candidate};
use super::check::{Check, all_pairs, largest_steps, largest_target, push, reach_shares, robot_rows, robot_steps};
use super::helper::receive;
use super::limits::Limits;
use super::memory::{Projection, Stage};

impl Projection {
    /// Inter-robot corrections for every pair `i < j` (every candidate of
    /// the broad phase, in the same order): where the scaled distance `r` is
    /// below its target `t` (1, or more with the chord inflation) the offset
    /// is pushed to it, `c = d (t/r - 1)`, added to `i` and taken from `j`.
    /// Returns the sum of `||c||^2`, and, where the box corrections were
    /// made while the helper checked its half, theirs.
    pub(super) fn pairs<const D: usize>(&mut self, n: usize, count: usize, limits: &Limits) -> (f64, Option<f64>) {
        let sep = limits.robot_sep;
        let inv = sep.map(|s| 1.0 / (s * s));
        let Projection { pos, corr, touched, scratch, broad, steps, grow, helper, first, culprit, .. } = self;
        robot_steps(pos, D, n, count, limits, steps);
        let check = Check { pos, steps, n, count, limits, inv };
        let broad_phase = limits.broad_phase && n >= BROAD_PHASE_MIN_ROBOTS;
        if *first {
            if culprit.is_some_and(|(i, j)| check.violates::<D>(Candidate::whole(i, j, count), scratch)) {
                return (f64::INFINITY, None);
            }
            let found = if broad_phase {
                let candidates = broad.candidates(pos, D, n, count, reach_shares(steps, &sep, grow));
                candidates.iter().copied().find(|&pair| check.violates::<D>(pair, scratch))
            } else {
                all_pairs(n, count).find(|&pair| check.violates::<D>(pair, scratch))
            };
            *culprit = found.map(|c| (c.i, c.j));
            return (if culprit.is_some() { f64::INFINITY } else { 0.0 }, None);
        }
        if !broad_phase {
            return (check.push::<D>(all_pairs(n, count), scratch, corr, touched), None);
        }
        let Some(link) = helper.as_mut().filter(|h| h.stage == Stage::Evaluating) else {
            let candidates = broad.candidates(pos, D, n, count, reach_shares(steps, &sep, grow));
            return (check.push::<D>(candidates.iter().copied(), scratch, corr, touched), None);
        };
        // The box while the helper finds the pairs: the same corrections,
        // added in another order; the helper checks the second half of the
        // pairs into its own corrections: the same iteration up to rounding.
        let box_sq = clamp_to_box(pos, corr, touched, limits, D, count);
        let Some(mine) = receive(&link.firsts) else {
            // The helper is gone (it panicked; the scope reports it): this
            // thread checks every pair, for the rest of the run too.
            *helper = None;
            let candidates = broad.candidates(pos, D, n, count, reach_shares(steps, &sep, grow));
            return (check.push::<D>(candidates.iter().copied(), scratch, corr, touched), Some(box_sq));
        };
        let sum = check.push::<D>(mine.iter().copied(), scratch, corr, touched);
        link.spare_pairs = mine;
        link.stage = Stage::Checking;
        (sum, Some(box_sq))
    }

    /// Robot-obstacle corrections: where robot `i` is inside the (scaled)
    /// obstacle `m` at an instant, its position is pushed to the surface.
    pub(super) fn obstacles<const D: usize>(&mut self, n: usize, count: usize, limits: &Limits) -> f64 {
        if limits.obstacle_sep.is_empty() {
            return 0.0;
        }
        let stride = n * count;
        let Projection { pos, corr, touched, scratch, first, .. } = self;
        let robot_steps = if limits.chord { largest_steps(pos, D, n, count) } else { [0.0; 3] };
        let mut sum = 0.0;
        for (m, sep) in limits.obstacle_sep.iter().enumerate() {
            // The instants the obstacle is kept clear at (a moving one's
            // prediction may end before the grid does).
            let until = limits.until[m];
            if until == 0 {
                continue;
            }
            let inv = sep.map(|s| 1.0 / (s * s));
            let rows = &limits.tracks[m * D * count..(m + 1) * D * count];
            let track = robot_rows::<D>(rows, 1, count, 0);
            let bound = limits.chord.then(|| largest_target(&robot_steps, &largest_steps(rows, D, 1, count), &inv));
            for i in 0..n {
                let pi = robot_rows::<D>(pos, n, count, i);
                if !scratch.violated::<D>(&pi, &track, &inv, bound, 0..until) {
                    continue;
                }
                if *first {
                    return f64::INFINITY;
                }
                touched[i] = true;
                for k in 0..until {
                    let Some(c) = push::<D>(&pi, &track, k, &inv, sep, scratch.target[k], (i, m)) else {
                        continue;
                    };
                    for a in 0..D {
                        corr[a * stride + i * count + k] += c[a];
                        sum += c[a] * c[a];
                    }
                }
            }
        }
        sum
    }
}

/// Clamps the positions (`[axis][robot][count]`, `axes` axes) into the box
/// of `limits`: adds the corrections to `corr`, marks the robots moved in
/// `touched` and returns the corrections' sum of squares.
pub(super) fn clamp_to_box(
    pos: &[f64],
    corr: &mut [f64],
    touched: &mut [bool],
    limits: &Limits,
    axes: usize,
    count: usize,
) -> f64 {
    let robots = touched.len();
    let mut box_sq = 0.0;
    for ax in 0..axes {
        let (lo, hi) = (limits.lo[ax], limits.hi[ax]);
        for (i, touched) in touched.iter_mut().enumerate() {
            let range = (ax * robots + i) * count..(ax * robots + i + 1) * count;
            let mut any = false;
            for (p, c) in pos[range.clone()].iter().zip(&mut corr[range]) {
                let d = p.clamp(lo, hi) - p;
                *c += d;
                box_sq += d * d;
                any |= d != 0.0;
            }
            *touched |= any;
        }
    }
    box_sq
}
