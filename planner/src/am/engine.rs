//! The engine itself: built once per team shape, obstacle count, objective
//! and settings (basis, sample grids, one KKT factorisation pair per penalty
//! level), its objectives, errors, iterates and outcomes.

use thiserror::Error;

use super::projection::SampleGrid;
use super::rates::RateLimits;
use super::settings::{AmSettings, Stop};
use crate::basis::Basis;
use crate::kkt::{KktError, TeamKkt};
use crate::metrics::DENSE_FACTOR;
use crate::plan::JointPlan;
use crate::problem::{ProblemError, Team};
use crate::reference::{ReferenceError, SmoothReference};
use crate::route::Fitter;

/// First sample the constraints are imposed at (sample 0 is the start state).
pub const FIRST_CONSTRAINED_SAMPLE: usize = 1;

/// Sample intervals [`AmSettings::start_refine`] cuts: this many after
/// the first constrained sample (the interval before it, where a measured
/// start may be in near-contact, keeps no instant).
pub const START_INTERVALS: usize = 2;

/// The rate limits' instants before the first constrained one: that
/// interval cut into this many.
const START_CUTS: usize = 4;

/// The most parts [`AmSettings::start_refine`] cuts an interval into.
pub const MAX_START_REFINE: usize = 16;

/// What the AM iterations minimise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Objective {
    /// The safety filter: `c = 1/2 ||xi_bar - xi||^2` for a given sample `xi`.
    Projection,
    /// The safety filter in a smoothness-weighted metric:
    /// `c = 1/2 (xi_bar - xi)^T (I + weight Q) (xi_bar - xi)` with `Q` the
    /// per-robot Gram matrix of the squared accelerations at the K samples
    /// (physical units), so repairs prefer smooth detours to sharp ones.
    /// `weight = 0` is [`Objective::Projection`].
    SmoothProjection {
        /// Weight of the smoothness of the correction against its size.
        weight: f64,
    },
    /// The from-scratch optimiser: `c = 1/2 weight * sum ||p''(t_k)||^2`
    /// (physical units).
    Smoothness {
        /// Weight of the smoothness cost against the penalty `rho`.
        weight: f64,
    },
}

impl Objective {
    /// The optimiser's objective with the default weight.
    pub fn smoothness() -> Self {
        Objective::Smoothness { weight: 1.0 }
    }

    /// The safety filter's objective for a smoothing weight: the plain
    /// projection at 0, [`Objective::SmoothProjection`] above it. Callers
    /// validate the weight (finite, 0 or more); anything else not above 0,
    /// NaN included, gives the plain projection.
    pub fn filter(smoothing: f64) -> Self {
        if smoothing > 0.0 { Objective::SmoothProjection { weight: smoothing } } else { Objective::Projection }
    }
}

/// Why the engine could not be built or run.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum EngineError {
    /// The problem failed validation.
    #[error("EngineError::Problem: {0}")]
    Problem(#[from] ProblemError),
    /// A KKT system could not be factored.
    #[error("EngineError::Kkt: {0}")]
    Kkt(#[from] KktError),
    /// The problem does not have the shape the engine was built for.
    #[error("EngineError::ShapeMismatch: engine built for {expected}, problem has {got}")]
    ShapeMismatch {
        /// What the engine expects.
        expected: String,
        /// What was given.
        got: String,
    },
    /// A sample or initial state has the wrong length.
    #[error("EngineError::BadLength: {got} values, expected {expected}")]
    BadLength {
        /// Required length.
        expected: usize,
        /// Given length.
        got: usize,
    },
}

/// Residuals of one iteration.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Residuals {
    /// `||F xi - e|| + ||G xi - h + s||` at the iterate (m).
    pub primal: f64,
    /// `||xi^{l+1} - xi^l|| + ||lambda^{l+1} - lambda^l||` of the update
    /// from it (NaN for an iterate that was not updated).
    pub fixed_point: f64,
}

/// An AM iterate: coefficients and multiplier, both `[axis][robot][coef]`.
#[derive(Debug, Clone, PartialEq)]
pub struct AmState {
    /// Coefficients `xi_bar`.
    pub xi: Vec<f64>,
    /// Multiplier `lambda`.
    pub lambda: Vec<f64>,
}

/// The result of a run.
#[derive(Debug, Clone)]
pub struct AmOutcome {
    /// Final iterate.
    pub state: AmState,
    /// xi-updates performed (all attempts together).
    pub iterations: usize,
    /// Attempts started (1 without restarts).
    pub attempts: usize,
    /// Why it stopped.
    pub stop: Stop,
    /// Primal residual of the final iterate.
    pub primal: f64,
    /// Per-iterate residuals of every attempt, in order (if recorded).
    pub history: Vec<Residuals>,
}

/// Per-penalty precomputation.
#[derive(Debug, Clone)]
pub(super) struct Level {
    pub(super) rho: f64,
    pub(super) kkt: TeamKkt,
    /// `K11_mean - K11_diff`, `n_xi x n_xi`.
    pub(super) mean_minus_diff: Vec<f64>,
    /// `rho P^T P` over the constrained samples.
    pub(super) rho_gram: Vec<f64>,
    /// `rho w D^T D` of the rate limits (empty without them).
    pub(super) rho_rates: Vec<f64>,
}

/// The engine for one team shape, obstacle count and objective: holds the
/// basis, the sample grids and the KKT factorisations for every penalty level.
#[derive(Debug, Clone)]
pub struct Engine {
    pub(super) team: Team,
    pub(super) obstacles: usize,
    pub(super) objective: Objective,
    pub(super) settings: AmSettings,
    pub(super) basis: Basis,
    pub(super) n_xi: usize,
    /// The constrained instants: samples `1..K`, and between samples 1 and
    /// 3 the cuts of [`AmSettings::start_refine`].
    pub(super) grid: SampleGrid,
    /// The dense verification grid `1 + verify_skip..DENSE_FACTOR K` (of
    /// `DENSE_FACTOR K`).
    pub(super) dense: SampleGrid,
    /// The dense instants `1..=verify_skip` right after the start, checked
    /// to the feasibility tolerance only.
    pub(super) dense_start: SampleGrid,
    pub(super) levels: Vec<Level>,
    /// The smoothest curves through the boundary values (optimiser cold start).
    pub(super) reference: SmoothReference,
    /// Fits routed cold starts to the basis.
    pub(super) fitter: Fitter,
    /// The six boundary rows, `6 x n_xi`.
    pub(super) boundary_rows: Vec<f64>,
    /// The per-robot cost Hessian `C`, `n_xi x n_xi`.
    pub(super) cost: Vec<f64>,
    /// The speed and acceleration limits ([`AmSettings::limit_speed`],
    /// [`AmSettings::limit_acceleration`], and the team's `max_speed` and
    /// `max_acceleration`).
    pub(super) rates: Option<RateLimits>,
}

impl Engine {
    /// Builds the engine: basis, grids, Gram matrices and one factorisation
    /// pair per penalty level.
    pub fn new(team: &Team, obstacles: usize, objective: Objective, settings: AmSettings) -> Result<Self, EngineError> {
        team.validate()?;
        let settings = AmSettings { rho: settings.rho.for_team(team.robots), ..settings };
        let basis = team.basis().map_err(ProblemError::from)?;
        let n_xi = basis.n_xi();
        let k = basis.samples();
        let grid = SampleGrid::new(team.degree, constrained_taus(&basis, settings.start_refine));
        let dense_count = DENSE_FACTOR * k;
        let dense = SampleGrid::new(
            team.degree,
            (1 + settings.verify_skip..dense_count).map(|s| s as f64 / (dense_count - 1) as f64).collect(),
        );
        let dense_start = SampleGrid::new(
            team.degree,
            (1..(1 + settings.verify_skip).min(dense_count)).map(|s| s as f64 / (dense_count - 1) as f64).collect(),
        );
        let gram = grid.gram();
        let boundary = basis.boundary_rows();
        let identity = (0..n_xi * n_xi).map(|i| f64::from(i % (n_xi + 1) == 0));
        let smoothness = |weight: f64| {
            let scale = weight / team.horizon.powi(4);
            basis.acceleration_gram().into_iter().map(move |v| v * scale)
        };
        let cost: Vec<f64> = match objective {
            Objective::Projection => identity.collect(),
            Objective::SmoothProjection { weight } => identity.zip(smoothness(weight)).map(|(i, q)| i + q).collect(),
            Objective::Smoothness { weight } => smoothness(weight).collect(),
        };
        let rates = {
            let dense_taus: Vec<f64> = dense_start.taus.iter().chain(&dense.taus).copied().collect();
            // The constrained instants, and cuts of the interval before
            // the first (the rates there are free of the start's).
            let first = grid.taus.first().copied().unwrap_or(1.0);
            let cuts = (1..START_CUTS).map(|j| first * j as f64 / START_CUTS as f64);
            let taus: Vec<f64> = cuts.chain(grid.taus.iter().copied()).collect();
            RateLimits::new(team, (settings.limit_speed, settings.limit_acceleration), &taus, &dense_taus)
        };
        let rates_gram = rates.as_ref().map(RateLimits::gram);
        let levels = settings
            .rho
            .levels()
            .into_iter()
            .map(|rho| {
                // The rate rows join the cost Hessian of both systems.
                let rho_rates: Vec<f64> = rates_gram.iter().flatten().map(|g| rho * g).collect();
                let level_cost: Vec<f64> = if rho_rates.is_empty() {
                    cost.clone()
                } else {
                    cost.iter().zip(&rho_rates).map(|(c, a)| c + a).collect()
                };
                let kkt = TeamKkt::new(&level_cost, &gram, &boundary, team.robots, obstacles, rho)?;
                let mean_minus_diff = kkt.mean().k11().iter().zip(kkt.diff().k11()).map(|(m, d)| m - d).collect();
                Ok(Level { rho, kkt, mean_minus_diff, rho_gram: gram.iter().map(|g| rho * g).collect(), rho_rates })
            })
            .collect::<Result<Vec<_>, KktError>>()?;
        let reference = SmoothReference::new(team).map_err(|e| match e {
            ReferenceError::Basis(b) => EngineError::Problem(b.into()),
            ReferenceError::Kkt(k) => EngineError::Kkt(k),
        })?;
        let fitter = Fitter::new(&basis)?;
        Ok(Self {
            team: team.clone(),
            obstacles,
            objective,
            settings,
            basis,
            n_xi,
            grid,
            dense,
            dense_start,
            levels,
            reference,
            fitter,
            boundary_rows: boundary,
            cost,
            rates,
        })
    }

    /// The team this engine plans for.
    pub fn team(&self) -> &Team {
        &self.team
    }

    /// The settings it runs with.
    pub fn settings(&self) -> &AmSettings {
        &self.settings
    }

    /// Number of obstacles it was built for.
    pub fn obstacles(&self) -> usize {
        self.obstacles
    }

    /// The basis.
    pub fn basis(&self) -> &Basis {
        &self.basis
    }

    /// The penalty values of the schedule.
    pub fn rho_levels(&self) -> Vec<f64> {
        self.levels.iter().map(|l| l.rho).collect()
    }

    /// Length of a coefficient (or multiplier) vector.
    pub fn coeff_len(&self) -> usize {
        self.team.dim.axes() * self.team.robots * self.n_xi
    }

    /// The plan a coefficient vector describes.
    pub fn plan(&self, xi: Vec<f64>) -> JointPlan {
        JointPlan::new(&self.team, xi)
    }
}

/// The constrained instants: samples `FIRST_CONSTRAINED_SAMPLE..K`, each of
/// the [`START_INTERVALS`] intervals after the first of them cut into
/// `refine` parts (at most [`MAX_START_REFINE`]).
fn constrained_taus(basis: &Basis, refine: usize) -> Vec<f64> {
    let refine = refine.clamp(1, MAX_START_REFINE);
    let step = basis.tau(1);
    let mut taus = Vec::with_capacity(basis.samples() + START_INTERVALS * refine);
    for s in FIRST_CONSTRAINED_SAMPLE..basis.samples() {
        if s > FIRST_CONSTRAINED_SAMPLE && s <= FIRST_CONSTRAINED_SAMPLE + START_INTERVALS {
            taus.extend((1..refine).map(|j| basis.tau(s - 1) + step * j as f64 / refine as f64));
        }
        taus.push(basis.tau(s));
    }
    taus
}
