//! Where iterations start: the optimiser's cold start (the smoothest curves,
//! or routes around static obstacles), the SF's sample, the rerouting of SF
//! samples through static obstacles, and the restarts' starts (perturbed,
//! with routed robots' passages moved: [`super::passages`]).

use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::engine::{AmState, Engine, EngineError, FIRST_CONSTRAINED_SAMPLE};
use super::passages::Routed;
use super::prepare::Prepared;
use crate::basis::BOUNDARY_ROWS;
use crate::plan::JointPlan;
use crate::problem::{Problem, scaled_norm};
use crate::route::{Blockers, Warp, route};

/// Amplitude of a restart's perturbation of the interior coefficients, in
/// robot separations.
const RESTART_AMPLITUDE: f64 = 0.5;

/// Straight segments closer than this (scaled) at one time meet head-on.
const HEAD_ON: f64 = 0.5;

/// The largest veering detour, as a fraction of the robot's move.
const VEER: f64 = 0.5;

/// Spacing of robots on the ring veering robots pass on, in separations.
const VEER_SPACING: f64 = 1.3;

/// Repairs SF samples the way the optimiser's cold start avoids static
/// obstacles: a robot whose curve passes through an inflated static
/// obstacle at a constrained sample gets a curve along a route around the
/// static obstacles instead ([`crate::route`]). Each robot is routed at
/// most once, however many samples of the problem are repaired. A robot
/// whose start or goal already lies within an inflated obstacle (a measured
/// start in near-contact) is left to the filter: every curve of it would
/// count as blocked.
pub struct Rerouter<'e> {
    engine: &'e Engine,
    problem: &'e Problem,
    blockers: Blockers,
    boundary: Vec<f64>,
    /// Per robot: its start or goal is within an inflated obstacle.
    pinned: Vec<bool>,
    /// Per robot: not routed yet, or its routed curve (`None`: walled off).
    routes: Vec<Option<Option<Vec<f64>>>>,
}

impl Rerouter<'_> {
    /// Reroutes the blocked robots of `xi` (the problem's coefficients,
    /// `[axis][robot][coef]`); returns how many were rerouted.
    ///
    /// # Panics
    /// If `xi` is not of the engine's length (the problem must be of the
    /// engine's team: [`Engine::prepare`] checks it).
    pub fn apply(&mut self, xi: &mut [f64]) -> usize {
        assert_eq!(xi.len(), self.engine.coeff_len(), "coefficients of the engine's team");
        if self.blockers.is_empty() {
            return 0;
        }
        let e = self.engine;
        let (n, axes, k) = (e.team.robots, e.team.dim.axes(), e.team.samples);
        let positions = JointPlan::new(&e.team, xi.to_vec()).sampled(k, 0);
        let mut count = 0;
        for i in 0..n {
            if self.pinned[i] {
                continue;
            }
            let blocked = (FIRST_CONSTRAINED_SAMPLE..k).any(|s| {
                let mut p = Vector3::zeros();
                for a in 0..axes {
                    p[a] = positions[(a * n + i) * k + s];
                }
                self.blockers.blocks(&p)
            });
            if !blocked {
                continue;
            }
            let route =
                self.routes[i].get_or_insert_with(|| e.routed_curve(self.problem, &self.blockers, &self.boundary, i));
            if let Some(curve) = route {
                set_curve(xi, curve, n, e.n_xi, i);
                count += 1;
            }
        }
        count
    }
}

/// Writes robot `i`'s `curve` (`[axis][coef]`, `nx` per axis) into the
/// coefficients `xi` of a team of `n` (`[axis][robot][coef]`).
fn set_curve(xi: &mut [f64], curve: &[f64], n: usize, nx: usize, i: usize) {
    for (a, c) in curve.chunks_exact(nx).enumerate() {
        xi[(a * n + i) * nx..(a * n + i + 1) * nx].copy_from_slice(c);
    }
}

/// The veering detour's coefficients at `degree`, up to scale: 0 with its
/// velocity and acceleration at both ends. The bump of the default degree
/// (its interior coefficients lifted together, each by 1), raised exactly
/// to higher degrees, so that a team planned at a finer resolution
/// ([`crate::problem::Team::resolved_for_workspace`]) veers along the same
/// curve.
fn veer_bump(degree: usize) -> Vec<f64> {
    let base = degree.min(crate::problem::Team::DEFAULT_DEGREE);
    let interior = BOUNDARY_ROWS / 2..base + 1 - BOUNDARY_ROWS / 2;
    let mut bump: Vec<f64> = (0..=base).map(|c| if interior.contains(&c) { 1.0 } else { 0.0 }).collect();
    // Degree elevation p -> p + 1: c'_k = k/(p+1) c_{k-1} + (1 - k/(p+1)) c_k.
    for p in base..degree {
        let q = (p + 1) as f64;
        bump = (0..=p + 1)
            .map(|k| {
                let before = if k > 0 { bump[k - 1] } else { 0.0 };
                let here = bump.get(k).copied().unwrap_or(0.0);
                k as f64 / q * before + (1.0 - k as f64 / q) * here
            })
            .collect();
    }
    bump
}

impl Engine {
    /// The optimiser's cold start: per robot the smoothest curve meeting the
    /// boundary conditions, or, with `routed_start`, a fitted route around the
    /// static obstacles when its straight segment crosses one; with the
    /// robots so routed.
    pub(super) fn smooth_start(&self, problem: &Problem, b: &[f64]) -> (Vec<f64>, Vec<Routed>) {
        let n = self.team.robots;
        let nx = self.n_xi;
        let mut xi = vec![0.0; self.coeff_len()];
        for (row, bv) in xi.chunks_exact_mut(nx).zip(b.chunks_exact(BOUNDARY_ROWS)) {
            self.reference.curve(bv, row);
        }
        if self.settings.veer {
            self.veer(problem, &mut xi);
        }
        if !self.settings.routed_start {
            return (xi, Vec::new());
        }
        let blockers = self.blockers(problem);
        if blockers.is_empty() {
            return (xi, Vec::new());
        }
        let mut routed = Vec::new();
        for i in 0..n {
            let (start, goal) = (problem.starts[i].position, problem.goals[i]);
            if !blockers.segment_blocked(&start, &goal) {
                continue;
            }
            if let Some(path) = route(&blockers, &start, &goal) {
                set_curve(&mut xi, &self.fitted_curve(&path, b, i, None), n, nx, i);
                routed.push(Routed::new(&blockers, i, path));
            }
        }
        (xi, routed)
    }

    /// The start of attempt `attempt` (from 1) of a restarted solve: the
    /// cold start with, under [`AmSettings::stall`], each routed robot
    /// passing its narrowest point at a seeded other time
    /// ([`Routed::shifted`]), and its interior coefficients perturbed
    /// ([`Self::perturb`]).
    ///
    /// [`AmSettings::stall`]: super::AmSettings::stall
    pub(super) fn restart(&self, prepared: &Prepared, attempt: usize) -> AmState {
        let mut state = self.cold_start(prepared);
        if self.settings.stall > 0 {
            let mut rng = ChaCha8Rng::seed_from_u64(attempt as u64);
            for r in &prepared.routed {
                let curve = self.fitted_curve(&r.path, &prepared.boundary, r.robot, Some(r.shifted(&mut rng)));
                set_curve(&mut state.xi, &curve, self.team.robots, self.n_xi, r.robot);
            }
        }
        self.perturb(&mut state.xi, attempt as u64);
        state
    }

    /// Breaks symmetric deadlocks (antipodal swaps, crossing lanes): every
    /// robot whose straight segment meets others head-on, at the same point
    /// at the same time (scaled distance below [`HEAD_ON`] along segments
    /// traversed with one timing), veers to the left of its motion in the
    /// middle of the horizon, all the same way round, like traffic in a
    /// roundabout. The detour is a bump on the interior coefficients, so the
    /// boundary conditions still hold; its size is that of a ring on which
    /// the robot and those it meets fit side by side (one separation for a
    /// pair, more for a swap), at most half its move.
    fn veer(&self, problem: &Problem, xi: &mut [f64]) {
        let (n, nx, dim) = (self.team.robots, self.n_xi, self.team.dim);
        let (a, b) = self.team.separation();
        let moves: Vec<Vector3<f64>> = (0..n).map(|i| problem.goals[i] - problem.starts[i].position).collect();
        let mut meets = vec![0usize; n];
        for i in 0..n {
            for j in i + 1..n {
                let d0 = problem.starts[i].position - problem.starts[j].position;
                let dd = moves[i] - moves[j];
                let t = if dd.norm_squared() > 0.0 { (-d0.dot(&dd) / dd.norm_squared()).clamp(0.0, 1.0) } else { 0.0 };
                if scaled_norm(dim, &(d0 + dd * t), a, b) < HEAD_ON {
                    meets[i] += 1;
                    meets[j] += 1;
                }
            }
        }
        if meets.iter().all(|&m| m == 0) {
            return;
        }
        // The bump, scaled to lift the middle of the horizon by 1.
        let bump = veer_bump(nx - 1);
        let middle = crate::basis::bernstein_row(nx - 1, 0, 0.5);
        let lift: f64 = middle.iter().zip(&bump).map(|(m, c)| m * c).sum();
        for i in (0..n).filter(|&i| meets[i] > 0) {
            let m = moves[i];
            let flat = Vector3::new(m.x, m.y, 0.0);
            let left = if flat.norm() > 1e-9 { Vector3::new(-m.y, m.x, 0.0) / flat.norm() } else { Vector3::x() };
            let ring = (meets[i] + 1) as f64 * VEER_SPACING * a / std::f64::consts::TAU;
            let amplitude = ring.max(a).min(VEER * m.norm());
            for ax in 0..dim.axes() {
                let row = &mut xi[(ax * n + i) * nx..(ax * n + i + 1) * nx];
                for (x, c) in row.iter_mut().zip(&bump) {
                    *x += amplitude * left[ax] * c / lift;
                }
            }
        }
    }

    /// The static obstacles of `problem` inflated by the robot size and the
    /// safety margin, for routing.
    fn blockers(&self, problem: &Problem) -> Blockers {
        Blockers::new(&self.team, &problem.obstacles, self.settings.margin, 0.0)
    }

    /// Robot `i`'s curve along a route around `blockers` meeting its
    /// boundary values (from `b`, [`Problem::boundary_values`]), `[axis][coef]`;
    /// `None` when its goal is walled off on the routing grid.
    fn routed_curve(&self, problem: &Problem, blockers: &Blockers, b: &[f64], i: usize) -> Option<Vec<f64>> {
        let path = route(blockers, &problem.starts[i].position, &problem.goals[i])?;
        Some(self.fitted_curve(&path, b, i, None))
    }

    /// Robot `i`'s curve (`[axis][coef]`) fitted to `path` under the
    /// quintic timing, its clock warped by `warp` where given, meeting its
    /// boundary values (from `b`).
    fn fitted_curve(&self, path: &[Vector3<f64>], b: &[f64], i: usize, warp: Option<Warp>) -> Vec<f64> {
        let (n, nx) = (self.team.robots, self.n_xi);
        let mut curve = vec![0.0; self.team.dim.axes() * nx];
        for (a, q) in self.fitter.timed_samples(path, self.team.dim.axes(), warp).iter().enumerate() {
            let row = a * n + i;
            self.fitter.fit(q, &b[row * BOUNDARY_ROWS..(row + 1) * BOUNDARY_ROWS], &mut curve[a * nx..(a + 1) * nx]);
        }
        curve
    }

    /// A [`Rerouter`] for `problem`, which must have the engine's team and
    /// obstacle count ([`EngineError::ShapeMismatch`] otherwise).
    pub fn rerouter<'e>(&'e self, problem: &'e Problem) -> Result<Rerouter<'e>, EngineError> {
        self.check_shape(problem)?;
        let blockers = self.blockers(problem);
        let pinned = problem
            .starts
            .iter()
            .zip(&problem.goals)
            .map(|(s, g)| blockers.blocks(&s.position) || blockers.blocks(g))
            .collect();
        Ok(Rerouter {
            engine: self,
            problem,
            blockers,
            boundary: problem.boundary_values(),
            pinned,
            routes: vec![None; problem.robots()],
        })
    }

    /// The cold start with a zero multiplier: for the optimiser see
    /// [`AmSettings::routed_start`], for the SF the sample itself.
    pub fn cold_start(&self, prepared: &Prepared) -> AmState {
        AmState { xi: prepared.cold.clone(), lambda: vec![0.0; self.coeff_len()] }
    }

    /// Seeded uniform perturbation of the interior coefficients (those the
    /// boundary rows do not touch), so the boundary conditions still hold.
    pub(super) fn perturb(&self, xi: &mut [f64], seed: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let amplitude = RESTART_AMPLITUDE * self.team.separation().0;
        let interior = BOUNDARY_ROWS / 2..self.n_xi - BOUNDARY_ROWS / 2;
        for row in xi.chunks_exact_mut(self.n_xi) {
            for x in &mut row[interior.clone()] {
                *x += amplitude * rng.random_range(-1.0..=1.0);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::am::{AmSettings, Objective};
    use crate::metrics::Metrics;

    use crate::problem::{Dim, Team};

    #[test]
    fn the_veering_bump_is_one_curve_at_every_degree() {
        let at = |c: &[f64], tau: f64| -> f64 {
            crate::basis::bernstein_row(c.len() - 1, 0, tau).iter().zip(c).map(|(b, x)| b * x).sum()
        };
        let lifted = |c: Vec<f64>| {
            let lift = at(&c, 0.5);
            c.into_iter().map(|x| x / lift).collect::<Vec<f64>>()
        };
        let base = lifted(veer_bump(10));
        for degree in [12, 16, 23] {
            let bump = lifted(veer_bump(degree));
            assert_eq!(bump.len(), degree + 1);
            // Rest at both ends: position, velocity and acceleration 0.
            assert!(bump[..3].iter().chain(&bump[degree - 2..]).all(|&c| c.abs() < 1e-15), "{bump:?}");
            for k in 0..=20 {
                let tau = k as f64 / 20.0;
                assert!((at(&bump, tau) - at(&base, tau)).abs() < 1e-12, "degree {degree} at {tau}");
            }
        }
        assert_eq!(veer_bump(10), [0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0]);
    }
    #[test]
    fn the_rerouter_moves_only_robots_that_cross_a_static_obstacle() {
        use crate::problem::{Obstacle, Spheroid, StartState};
        let team = Team::default_for(Dim::Two, 2);
        let at = |x: f64, y: f64| Vector3::new(x, y, 0.0);
        let problem = Problem {
            team: team.clone(),
            starts: vec![StartState::at_rest(at(-0.8, 0.0)), StartState::at_rest(at(-0.8, 0.7))],
            goals: vec![at(0.8, 0.0), at(0.8, 0.7)],
            obstacles: vec![Obstacle {
                position: at(0.0, 0.02),
                velocity: Vector3::zeros(),
                shape: Spheroid::ball(0.2),
            }],
        };
        let engine = Engine::new(&team, 1, Objective::filter(3.0), AmSettings::safety_filter()).unwrap();
        // Straight lines (the SF routes no cold start): robot 0 crosses the
        // obstacle, robot 1 passes above it.
        let (mut xi, _) = engine.smooth_start(&problem, &problem.boundary_values());
        let before = xi.clone();
        let mut rerouter = engine.rerouter(&problem).unwrap();
        assert_eq!(rerouter.apply(&mut xi), 1);
        let nx = team.degree + 1;
        for a in 0..2 {
            let row = (a * 2 + 1) * nx..(a * 2 + 2) * nx;
            assert_eq!(xi[row.clone()], before[row], "robot 1 keeps its curve");
        }
        let m = Metrics::measure(&problem, &JointPlan::new(&team, xi.clone()));
        assert!(m.boundary_error < 1e-9, "the route keeps the boundary conditions: {}", m.boundary_error);
        assert!(m.min_obstacle_clearance > 0.0, "the route clears the obstacle: {}", m.min_obstacle_clearance);
        let once = xi.clone();
        rerouter.apply(&mut xi);
        assert_eq!(xi, once, "rerouting twice changes nothing");
    }

    #[test]
    fn the_rerouter_leaves_near_contact_robots_and_refuses_other_teams() {
        use crate::problem::{Obstacle, Spheroid, StartState};
        let team = Team::default_for(Dim::Two, 1);
        let at = |x: f64, y: f64| Vector3::new(x, y, 0.0);
        let ball = Spheroid::ball(0.2);
        let engine = Engine::new(&team, 1, Objective::filter(3.0), AmSettings::safety_filter()).unwrap();
        // The start touches the obstacle within the safety margin (scaled
        // distance 1.02 < 1.05) and the straight line runs past it.
        let (a, _) = team.obstacle_separation(&ball);
        let problem = Problem {
            team: team.clone(),
            starts: vec![StartState::at_rest(at(-0.5, 0.0))],
            goals: vec![at(0.8, 0.0)],
            obstacles: vec![Obstacle { position: at(-0.5 - 1.02 * a, 0.0), velocity: Vector3::zeros(), shape: ball }],
        };
        let (mut xi, _) = engine.smooth_start(&problem, &problem.boundary_values());
        let before = xi.clone();
        assert_eq!(engine.rerouter(&problem).unwrap().apply(&mut xi), 0);
        assert_eq!(xi, before);
        let other = Problem { team: Team::default_for(Dim::Two, 2), ..problem };
        assert!(matches!(engine.rerouter(&other), Err(EngineError::ShapeMismatch { .. })));
    }
}
