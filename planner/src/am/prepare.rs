//! Preparing a problem for the iterations: validation against the engine's
//! shape, the boundary part of the xi-step per penalty level, the cost's
//! linear term, and the limits the projection and the verification check.

use super::engine::{Engine, EngineError, Objective};
use super::passages::Routed;
use super::projection::Limits;
use crate::basis::BOUNDARY_ROWS;
use crate::kkt::TeamKkt;
use crate::linalg::{Accum, dot, gemm};
use crate::problem::{FEASIBILITY_TOLERANCE, Problem};
use crate::recovery::Recovery;

/// How exactly a start must meet the boundary conditions to be returned
/// without an update (normalised time units).
const BOUNDARY_EXACTNESS: f64 = 1e-9;

/// Per-problem data the iterations read.
#[derive(Debug, Clone)]
pub struct Prepared {
    /// Per level: `K12_diff (b_i - b_mean) + K12_mean b_mean`, `[axis][robot][n_xi]`.
    pub(super) beta: Vec<Vec<f64>>,
    /// Linear cost term (the SF sample, or `C` times it for
    /// [`Objective::SmoothProjection`]), `[axis][robot][coef]`; empty for the optimiser.
    pub(super) target: Vec<f64>,
    /// The cold-start coefficients (the sample for the SF).
    pub(super) cold: Vec<f64>,
    /// Inflated sizes and shrunk box at the constrained samples.
    pub(super) constraint: Limits,
    /// True sizes and box on the dense grid.
    pub(super) verify: Limits,
    /// Sizes and box within the feasibility tolerance on the dense instants
    /// right after the start.
    pub(super) verify_start: Limits,
    /// Boundary values `[axis][robot][6]` (normalised time).
    pub(super) boundary: Vec<f64>,
    /// The robots the cold start routed around static obstacles, for the
    /// restarts ([`super::passages`]).
    pub(super) routed: Vec<Routed>,
}

impl Prepared {
    /// The boundary part `beta` of the xi-step at penalty level `level`
    /// (clamped), `[axis][robot][coef]`.
    pub fn beta(&self, level: usize) -> &[f64] {
        &self.beta[level.min(self.beta.len() - 1)]
    }

    /// The cost's linear term: the SF sample, or `C` times it for
    /// [`Objective::SmoothProjection`] (empty for the optimiser), `[axis][robot][coef]`.
    pub fn target(&self) -> &[f64] {
        &self.target
    }

    /// The cold-start coefficients, `[axis][robot][coef]`: the safety
    /// filter's sample.
    pub fn cold(&self) -> &[f64] {
        &self.cold
    }

    /// The inflated sizes and shrunk box the iterations project onto.
    pub fn constraint(&self) -> &Limits {
        &self.constraint
    }
}

impl Engine {
    /// Validates `problem` against the engine and precomputes what the
    /// iterations read. `sample` is the SF sample (ignored by the optimiser).
    pub fn prepare(&self, problem: &Problem, sample: Option<&[f64]>) -> Result<Prepared, EngineError> {
        problem.validate()?;
        self.check_shape(problem)?;
        let t = &problem.team;
        let dim = t.dim.axes();
        let n = t.robots;
        let b = problem.boundary_values();
        let beta = self
            .levels
            .iter()
            .map(|level| {
                let mut out = vec![0.0; dim * n * self.n_xi];
                for a in 0..dim {
                    self.boundary_part(
                        &level.kkt,
                        &b[a * n * BOUNDARY_ROWS..(a + 1) * n * BOUNDARY_ROWS],
                        &mut out[a * n * self.n_xi..(a + 1) * n * self.n_xi],
                    );
                }
                out
            })
            .collect();
        let sample = match (self.objective, sample) {
            (Objective::Smoothness { .. }, _) => None,
            (_, Some(x)) if x.len() == self.coeff_len() => Some(x),
            (_, x) => {
                return Err(EngineError::BadLength { expected: self.coeff_len(), got: x.map_or(0, <[f64]>::len) });
            }
        };
        // The cost's linear term: `C xi` per robot and axis (`xi` itself
        // for the plain projection).
        let target = match (self.objective, sample) {
            (Objective::SmoothProjection { .. }, Some(x)) => {
                let mut linear = vec![0.0; x.len()];
                gemm(&mut linear, x, &self.cost, x.len() / self.n_xi, self.n_xi, self.n_xi, Accum::Replace);
                linear
            }
            (_, Some(x)) => x.to_vec(),
            (_, None) => Vec::new(),
        };
        let (cold, routed) = match sample {
            Some(x) => (x.to_vec(), Vec::new()),
            None => self.smooth_start(problem, &b),
        };
        let margin = self.settings.margin;
        let (chord, broad) = (self.settings.chord, self.settings.broad_phase);
        let shrink = [t.robot.radius, t.robot.radius, t.robot.half_height].map(|r| margin * r);
        let recovery = Recovery::of(problem);
        Ok(Prepared {
            beta,
            target,
            cold,
            constraint: Limits::new(problem, &self.grid, 1.0 + margin, shrink)
                .with_rules(chord, broad)
                .with_recovery(problem, &recovery, &self.grid),
            verify: Limits::new(problem, &self.dense, 1.0 + self.settings.verify_margin, [0.0; 3])
                .with_rules(chord, broad)
                .with_recovery(problem, &recovery, &self.dense),
            verify_start: Limits::new(problem, &self.dense_start, 1.0 - FEASIBILITY_TOLERANCE, [-t.box_tolerance(); 3])
                .with_rules(chord, broad)
                .with_recovery(problem, &recovery, &self.dense_start),
            boundary: b,
            routed,
        })
    }

    /// `K12_diff (b_i - b_mean) + K12_mean b_mean` for one axis.
    fn boundary_part(&self, kkt: &TeamKkt, b: &[f64], out: &mut [f64]) {
        let n = self.team.robots;
        let nx = self.n_xi;
        let mut b_mean = [0.0; BOUNDARY_ROWS];
        for row in b.chunks_exact(BOUNDARY_ROWS) {
            for (m, v) in b_mean.iter_mut().zip(row) {
                *m += v / n as f64;
            }
        }
        let mut mean_part = vec![0.0; nx];
        kkt.mean().apply_boundary(&b_mean, &mut mean_part);
        let mut db = [0.0; BOUNDARY_ROWS];
        for (row, o) in b.chunks_exact(BOUNDARY_ROWS).zip(out.chunks_exact_mut(nx)) {
            for c in 0..BOUNDARY_ROWS {
                db[c] = row[c] - b_mean[c];
            }
            kkt.diff().apply_boundary(&db, o);
            for (x, m) in o.iter_mut().zip(&mean_part) {
                *x += m;
            }
        }
    }

    /// Whether `problem` has the engine's team and obstacle count
    /// ([`EngineError::ShapeMismatch`] otherwise).
    pub(super) fn check_shape(&self, problem: &Problem) -> Result<(), EngineError> {
        if problem.team != self.team || problem.obstacles.len() != self.obstacles {
            return Err(EngineError::ShapeMismatch {
                expected: format!("{:?} with {} obstacles", self.team, self.obstacles),
                got: format!("{:?} with {} obstacles", problem.team, problem.obstacles.len()),
            });
        }
        Ok(())
    }

    /// Whether `xi` meets the boundary conditions (to 1e-9 in normalised time).
    pub(super) fn meets_boundary(&self, prepared: &Prepared, xi: &[f64]) -> bool {
        let rows = &self.boundary_rows;
        xi.chunks_exact(self.n_xi).zip(prepared.boundary.chunks_exact(BOUNDARY_ROWS)).all(|(x, b)| {
            rows.chunks_exact(self.n_xi).zip(b).all(|(row, bv)| (dot(row, x) - bv).abs() <= BOUNDARY_EXACTNESS)
        })
    }
}

#[cfg(test)]
mod tests {
    use crate::am::{AmSettings, Engine, EngineError, Objective};
    use crate::problem::{Dim, Team};
    use crate::scenario::RandomScenario;

    #[test]
    fn a_problem_of_another_shape_is_rejected() {
        let team = Team::default_for(Dim::Two, 4);
        let engine = Engine::new(&team, 0, Objective::smoothness(), AmSettings::optimiser()).unwrap();
        let other = RandomScenario::new(team.clone()).with_obstacles(1).generate(1).unwrap();
        assert!(matches!(engine.solve(&other), Err(EngineError::ShapeMismatch { .. })));
        let sf = Engine::new(&team, 0, Objective::Projection, AmSettings::safety_filter()).unwrap();
        let problem = RandomScenario::new(team).generate(1).unwrap();
        assert!(matches!(sf.filter(&problem, &[0.0; 3], None), Err(EngineError::BadLength { expected: 88, got: 3 })));
    }
}
