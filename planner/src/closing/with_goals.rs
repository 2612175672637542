//! The pair certificate with the plans' form: where the ball bound
//! ([`super::unavoidable`]) leaves two robots near touching, the most
//! they can keep under plans of the team's form from their starts to
//! their goals, from each robot's reach along the directions of a frame
//! ([`Reach`]; docs/ENGINE.md, "With the plans' form").

use std::f64::consts::FRAC_1_SQRT_2;

use nalgebra::Vector3;

use super::unavoidable;
use crate::basis::DENSE_FACTOR;
use crate::braking::{AxisMotion, Memo, Reach, solves_programs};
use crate::problem::{Dim, Problem, scaled, scaled_norm};

/// A pair the ball leaves within this many times the separation it must
/// keep is checked with the plans' form too ([`Problem::kept_with_goals`]): on
/// the closest pairs of six 16-robot starts at 0.6-1.0 m/s that bound was
/// 0.86-0.92 of the ball's.
pub const WITH_GOALS_WITHIN: f64 = 1.2;

impl Problem {
    /// Where robots `i` and `j` cannot keep `touching` (scaled)
    /// apart over `window` (s), their accelerations within `max_acceleration`:
    /// whatever they do ([`unavoidable`], the ball), or, where the ball
    /// leaves them near that and this process solves programs
    /// ([`solves_programs`]), under every plan of the team's form from their
    /// starts to their goals ([`Problem::kept_with_goals`]). The most they can keep,
    /// and when.
    pub fn unavoidable_pair(
        &self,
        (i, j): (usize, usize),
        max_acceleration: f64,
        window: (f64, f64),
        touching: f64,
    ) -> Option<(f64, f64)> {
        let team = &self.team;
        let (a, b) = team.separation();
        let (si, sj) = (&self.starts[i], &self.starts[j]);
        // The ball of reachable offsets, scaled: its radius by the larger of
        // the two scales (a sphere holds it).
        let spread = max_acceleration * if team.dim == Dim::Three { (1.0 / a).max(1.0 / b) } else { 1.0 / a };
        let (q, r) = (
            scaled(team.dim, &(si.position - sj.position), a, b),
            scaled(team.dim, &(si.velocity - sj.velocity), a, b),
        );
        let near = if solves_programs() { touching * WITH_GOALS_WITHIN } else { touching };
        let (most, at) = unavoidable(q, r, spread, window, near)?;
        if most < touching {
            return Some((most, at));
        }
        // Least at the first instants (a pair at rest or parting): no claim.
        // The plans' form certifies pairs closing fast, where a polynomial
        // cannot turn in time; elsewhere its programs would only cost time.
        if at < 2.0 * window.0 {
            return None;
        }
        // The frame: along the offset where the ball is least, across it (in
        // the horizontal plane), and up.
        let offset = (si.position - sj.position) + (si.velocity - sj.velocity) * at;
        let along = Vector3::new(offset.x, offset.y, 0.0).try_normalize(1e-12).unwrap_or_else(Vector3::x);
        let frame = [along, Vector3::new(-along.y, along.x, 0.0), Vector3::z()];
        self.kept_with_goals((i, j), max_acceleration, frame, (window, at), touching)
    }

    /// Whether robots `i` and `j` cannot keep `touching`
    /// (scaled) apart under plans of the team's form within
    /// `max_acceleration` from their starts to their goals at some dense
    /// instant of `window` (s): the most they can keep there, and when. At an
    /// instant, the most is the farthest corner of the box their offset lies
    /// in, in `frame` (orthonormal, the first two horizontal: each robot's
    /// reach along each of its directions, [`Reach`], its acceleration held
    /// within the limit along each, which holds it within the limit in all);
    /// the search starts at the instant nearest `around` (where the ball bound
    /// is least) and walks while that falls. Where the box leaves the pair
    /// just apart (`POLYGON_WITHIN`), its horizontal corner is cut by the
    /// slabs along the diagonals of the frame's first two directions, at the
    /// instant found (`farthest_in_slabs`). `None`: no such instant found,
    /// or a program that did not solve (no claim). The last 256 answers are
    /// kept (a problem is validated more than once).
    pub fn kept_with_goals(
        &self,
        (i, j): (usize, usize),
        max_acceleration: f64,
        frame: [Vector3<f64>; 3],
        ((from, to), around): ((f64, f64), f64),
        touching: f64,
    ) -> Option<(f64, f64)> {
        let team = &self.team;
        let form = team.form(max_acceleration);
        // The frame's directions (the box), then the diagonals of its
        // horizontal two (the polygon); per direction, the two robots'
        // motions along it.
        let (along, across) = (frame[0], frame[1]);
        let diagonals = [(along + across) * FRAC_1_SQRT_2, (along - across) * FRAC_1_SQRT_2];
        let directions: Vec<Vector3<f64>> = frame[..team.dim.axes()].iter().chain(&diagonals).copied().collect();
        let motions: Vec<[AxisMotion; 2]> =
            directions.iter().map(|d| [self.motion_along(i, d), self.motion_along(j, d)]).collect();
        let mut key: Vec<u64> = [from, to, around, touching].iter().map(|v| v.to_bits()).collect();
        key.extend(motions.iter().flatten().flat_map(|m| form.bits_with(*m)));
        KEPT.get_or(key, || {
            let (a, b) = team.separation();
            let last = DENSE_FACTOR * team.samples - 1;
            let step = team.horizon / last as f64;
            let (first, end) = ((from / step).ceil() as usize, ((to / step).floor() as usize).min(last));
            if first > end {
                return None;
            }
            let mut reaches = Vec::with_capacity(motions.len());
            for [mi, mj] in &motions {
                reaches.push([Reach::new(form, *mi)?, Reach::new(form, *mj)?]);
            }
            let axes = team.dim.axes();
            let normals: Vec<[f64; 2]> = [along, across].iter().chain(&diagonals).map(|d| [d.x, d.y]).collect();
            // The offset's range along each direction at dense instant `s`:
            // the frame's, and the diagonals' too with `polygon`.
            let mut slabs_at = |s: usize, polygon: bool| -> Option<Vec<(f64, f64)>> {
                let tau = s as f64 / last as f64;
                let count = if polygon { reaches.len() } else { axes };
                let mut slabs = Vec::with_capacity(count);
                for [ri, rj] in &mut reaches[..count] {
                    let ((lo_i, hi_i), (lo_j, hi_j)) = (ri.at(tau)?, rj.at(tau)?);
                    slabs.push((lo_i - hi_j, hi_i - lo_j));
                }
                Some(slabs)
            };
            let reach = |(lo, hi): (f64, f64)| lo.abs().max(hi.abs());
            let up = |slabs: &[(f64, f64)]| if axes == 3 { reach(slabs[2]) } else { 0.0 };
            let mut boxed_at = |s: usize| -> Option<f64> {
                let slabs = slabs_at(s, false)?;
                let corner = Vector3::new(reach(slabs[0]), reach(slabs[1]), up(&slabs));
                Some(scaled_norm(team.dim, &corner, a, b))
            };
            let mut at = ((around / step).round() as usize).clamp(first, end);
            let mut least = boxed_at(at)?;
            // Far from touching there, no claim: the bound's least was within
            // 2% of its value at the ball's instant on the pairs it certified,
            // and the walk costs a few programs an instant.
            if least >= touching * WALK_WITHIN {
                return None;
            }
            for walk in [-1_isize, 1] {
                while least >= touching {
                    let Some(next) = at.checked_add_signed(walk).filter(|s| (first..=end).contains(s)) else { break };
                    let kept = boxed_at(next)?;
                    if kept >= least {
                        break;
                    }
                    (at, least) = (next, kept);
                }
            }
            // The box's corner cut by the diagonals, where it is least and
            // near touching.
            if (touching..touching * POLYGON_WITHIN).contains(&least) {
                let slabs = slabs_at(at, true)?;
                let horizontal: Vec<(f64, f64)> = slabs[..2].iter().chain(&slabs[axes..]).copied().collect();
                let corner = Vector3::new(farthest_in_slabs(&normals, &horizontal), 0.0, up(&slabs));
                least = scaled_norm(team.dim, &corner, a, b);
            }
            (least < touching).then_some((least, at as f64 * step))
        })
    }
}

/// A pair whose bound at the ball's instant is within this many times the
/// separation it must keep is searched at the instants around it.
const WALK_WITHIN: f64 = 1.05;

/// A pair whose box bound, where least, is within this many times the
/// separation it must keep is bounded again with the diagonals too: on
/// 300 16-robot starts at 0.3-1.0 m/s (seeds 900, 2000, 3000) the
/// diagonals cut four such bounds (1.004-1.033 of it) by 0.2-1.8%,
/// certifying the two within 1.01, and their eight programs cost about
/// 7 ms then (docs/experiments/2026-11-29-pairs-bounded-with-diagonals.md;
/// about a tenth of that with [`crate::lp`]).
const POLYGON_WITHIN: f64 = 1.02;

/// The pairs checked lately.
static KEPT: Memo<Vec<u64>, Option<(f64, f64)>> = Memo::new();

/// The farthest point from the origin (m) of the polygon of 2D points `x`
/// with `lo <= n . x <= hi` for every unit normal `n` of `normals` and
/// range of `slabs`: the largest norm of its vertices, each the crossing
/// of two of the slabs' lines that every slab holds (a little past them
/// counts: a larger bound is the safe side). Bounded by the box of the
/// first two slabs' corner (their normals orthogonal).
pub(crate) fn farthest_in_slabs(normals: &[[f64; 2]], slabs: &[(f64, f64)]) -> f64 {
    let corner = |k: usize| slabs[k].0.abs().max(slabs[k].1.abs());
    let boxed = corner(0).hypot(corner(1));
    let lines: Vec<([f64; 2], f64)> =
        normals.iter().zip(slabs).flat_map(|(n, &(lo, hi))| [(*n, lo), (*n, hi)]).collect();
    let slack = 1e-9 * (1.0 + boxed);
    let inside = |x: [f64; 2]| {
        normals.iter().zip(slabs).all(|(n, (lo, hi))| {
            let v = n[0] * x[0] + n[1] * x[1];
            v >= lo - slack && v <= hi + slack
        })
    };
    let mut farthest: Option<f64> = None;
    for (k, (n, c)) in lines.iter().enumerate() {
        for (m, d) in &lines[k + 1..] {
            let det = n[0] * m[1] - n[1] * m[0];
            if det.abs() < 1e-9 {
                continue;
            }
            let x = [(c * m[1] - d * n[1]) / det, (n[0] * d - m[0] * c) / det];
            if inside(x) {
                farthest = Some(farthest.unwrap_or(0.0).max(x[0].hypot(x[1])));
            }
        }
    }
    farthest.map_or(boxed, |f| f.min(boxed))
}

#[cfg(test)]
mod tests {
    use super::super::most_kept;
    use super::*;

    /// Two robots head-on at `speed` each, `gap` m apart, each to a goal
    /// beyond the other's start; a limit of 3 m/s^2.
    fn head_on(gap: f64, speed: f64) -> Problem {
        use crate::problem::{StartState, Team};
        let team = Team { max_acceleration: Some(3.0), ..Team::default_for(Dim::Two, 2) };
        let start = |x: f64, v: f64| StartState {
            velocity: Vector3::new(v, 0.0, 0.0),
            ..StartState::at_rest(Vector3::new(x, 0.0, 0.0))
        };
        Problem {
            team,
            starts: vec![start(-gap / 2.0, speed), start(gap / 2.0, -speed)],
            goals: vec![Vector3::new(0.6, 0.3, 0.0), Vector3::new(-0.6, -0.3, 0.0)],
            obstacles: vec![],
        }
    }

    #[test]
    fn a_pair_the_ball_leaves_apart_is_certified_with_the_plans_form_and_a_farther_one_is_planned() {
        use crate::am::{AmSettings, Engine, Objective, Stop};
        use crate::metrics::Metrics;
        use crate::problem::{FEASIBILITY_TOLERANCE, ProblemError};
        let touching = 1.0 - FEASIBILITY_TOLERANCE;
        let window = (5.0 / 199.0, 5.0);
        // 0.33 m apart closing at 1.2 m/s: whatever they do, they can keep
        // more than the separation (the ball), but no two plans of the
        // team's form from zero acceleration do.
        let close = head_on(0.33, 0.6);
        let spread = 3.0 / 0.2;
        let (q, r) = (Vector3::new(1.65, 0.0, 0.0), Vector3::new(-6.0, 0.0, 0.0));
        let (ball, around) = most_kept(q, r, spread, window);
        assert!(ball > touching && ball < touching * WITH_GOALS_WITHIN, "{ball}");
        let frame = [Vector3::x(), Vector3::y(), Vector3::z()];
        let (kept, at) = close.kept_with_goals((0, 1), 3.0, frame, (window, around), touching).expect("certified");
        assert!(kept < touching && kept < ball && at > 0.0, "{kept} {ball}");
        match close.validate() {
            Err(ProblemError::CannotAvoid { i: 0, j: 1, scaled, .. }) => assert_eq!(scaled, kept),
            other => panic!("{other:?}"),
        }
        // Farther apart, the bound leaves them room, and a plan exists.
        let far = head_on(0.40, 0.6);
        assert_eq!(far.validate(), Ok(()));
        let settings = AmSettings { limit_acceleration: true, ..AmSettings::optimiser() };
        let engine = Engine::new(&far.team, 0, Objective::smoothness(), settings).unwrap();
        let outcome = engine.solve(&far).unwrap();
        assert_eq!(outcome.stop, Stop::Verified);
        let m = Metrics::measure(&far, &engine.plan(outcome.state.xi));
        assert!(m.success(0.2) && m.max_acceleration <= 3.0 + 1e-6, "{m:?}");
    }

    #[test]
    fn a_pair_the_box_leaves_just_apart_is_certified_with_the_diagonals() {
        use crate::problem::{FEASIBILITY_TOLERANCE, ProblemError};
        use crate::scenes::{Family, Scene};
        // Instance 3012 of `flowopt bench --robots 16 --start-speed 0.6
        // --max-acceleration 3 --seed 3000`: the box leaves robots 3 and 7
        // 0.9935 apart (scaled), just past the line, 0.99; with the
        // diagonals they keep 0.987 at the most. Without them it was
        // planned only over the limit (5.1 m/s^2).
        let scene = Scene { start_speed: 0.6, ..Scene::new(Family::Random, Dim::Two, 16, 3012) };
        let (mut problem, _) = scene.generate().unwrap();
        problem.team.max_acceleration = Some(3.0);
        match problem.validate() {
            Err(ProblemError::CannotAvoid { i: 3, j: 7, scaled, .. }) => {
                assert!(scaled < 1.0 - FEASIBILITY_TOLERANCE && scaled > 0.98, "{scaled}")
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn the_farthest_point_of_the_slabs_is_a_vertex_of_their_polygon() {
        let r = FRAC_1_SQRT_2;
        let normals = [[1.0, 0.0], [0.0, 1.0], [r, r], [r, -r]];
        // A square cut by its diagonals' slabs: an octagon.
        let octagon = farthest_in_slabs(&normals, &[(-1.0, 1.0), (-1.0, 1.0), (-1.0, 1.0), (-1.0, 1.0)]);
        let vertex = 1.0_f64.hypot(2.0_f64.sqrt() - 1.0);
        assert!((octagon - vertex).abs() < 1e-12, "{octagon} against {vertex}");
        // Diagonal slabs wider than the square's corners: the square's.
        let square = farthest_in_slabs(&normals, &[(-1.0, 1.0), (-1.0, 1.0), (-5.0, 5.0), (-5.0, 5.0)]);
        assert!((square - 2.0_f64.sqrt()).abs() < 1e-12, "{square}");
        // Off the origin and uneven, no point of the slabs is farther.
        let slabs = [(0.2, 0.9), (-0.4, 0.3), (0.0, 0.75), (-0.1, 0.8)];
        let bound = farthest_in_slabs(&normals, &slabs);
        let mut seen: f64 = 0.0;
        for k in 0..=400 {
            for m in 0..=400 {
                let x = [-1.0 + 2.0 * k as f64 / 400.0, -1.0 + 2.0 * m as f64 / 400.0];
                let inside =
                    normals.iter().zip(&slabs).all(|(n, (lo, hi))| (lo..=hi).contains(&&(n[0] * x[0] + n[1] * x[1])));
                if inside {
                    seen = seen.max(x[0].hypot(x[1]));
                }
            }
        }
        assert!(seen <= bound + 1e-12 && seen > bound - 0.01, "grid {seen}, bound {bound}");
    }
}
