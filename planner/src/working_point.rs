//! The safety filter's benchmark working point, one definition shared by
//! the criterion benchmark (`benches/engine.rs`) and the machine-speed
//! calibration of `flowopt eval`, so that their per-iteration times compare.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use thiserror::Error;

use crate::am::{AmSettings, AmState, Engine, EngineError, Objective, Prepared};
use crate::problem::{Dim, Team};
use crate::reference::{ReferenceError, SmoothReference};
use crate::scenario::{RandomScenario, ScenarioError};
use crate::scenes::{Family, Scene};

/// Seed of the working point's instance.
const INSTANCE_SEED: u64 = 11;
/// Seed of its perturbation.
const NOISE_SEED: u64 = 5;
/// Perturbation per coefficient, as a fraction of the separation.
const NOISE: f64 = 0.1;

/// Why the working point could not be built.
#[derive(Debug, Error)]
pub enum WorkingPointError {
    /// The instance could not be generated.
    #[error("WorkingPointError::Scenario: {0}")]
    Scenario(#[from] ScenarioError),
    /// The optimiser or the filter failed.
    #[error("WorkingPointError::Engine: {0}")]
    Engine(#[from] EngineError),
    /// The straight curves could not be built.
    #[error("WorkingPointError::Reference: {0}")]
    Reference(#[from] ReferenceError),
}

/// A safety-filter engine, a prepared problem and the iterate every timed
/// iteration starts from.
pub struct WorkingPoint {
    /// The safety filter (plain projection, default settings).
    pub filter: Engine,
    /// The prepared problem.
    pub prepared: Prepared,
    /// The perturbed sample with a zero multiplier: the iterate with the
    /// most violations, not a converging one.
    pub start: AmState,
}

impl WorkingPoint {
    /// The optimiser's plan of a seeded random instance of `robots` robots in
    /// `dim`, perturbed by uniform noise of 10% of the separation on every
    /// coefficient, to be repaired by the safety filter.
    pub fn new(robots: usize, dim: Dim) -> Result<Self, WorkingPointError> {
        let team = Team::default_for(dim, robots);
        let problem = RandomScenario::new(team.clone()).generate(INSTANCE_SEED)?;
        let optimiser = Engine::new(&team, 0, Objective::smoothness(), AmSettings::optimiser())?;
        let solution = optimiser.solve(&problem)?.state.xi;
        let mut rng = ChaCha8Rng::seed_from_u64(NOISE_SEED);
        let noise = NOISE * team.separation().0;
        let sample: Vec<f64> = solution.iter().map(|x| x + noise * rng.random_range(-1.0..=1.0)).collect();
        let filter = Engine::new(&team, 0, Objective::Projection, AmSettings::safety_filter())?;
        let prepared = filter.prepare(&problem, Some(&sample))?;
        let start = filter.cold_start(&prepared);
        Ok(Self { filter, prepared, start })
    }

    /// A big team's working point: a seeded crowd of `robots` (random at
    /// constant density, [`crate::scenes`]) and the smoothest straight
    /// curves through it as the sample, which collide many times; the filter
    /// checks pairs with or without the `broad_phase`.
    pub fn crowd(robots: usize, dim: Dim, broad_phase: bool) -> Result<Self, WorkingPointError> {
        let (problem, _) = Scene::new(Family::Crowd, dim, robots, INSTANCE_SEED).generate()?;
        let team = problem.team.clone();
        let sample = SmoothReference::new(&team)?.coefficients(&problem);
        let settings = AmSettings { broad_phase, ..AmSettings::safety_filter() };
        let filter = Engine::new(&team, 0, Objective::Projection, settings)?;
        let prepared = filter.prepare(&problem, Some(&sample))?;
        let start = filter.cold_start(&prepared);
        Ok(Self { filter, prepared, start })
    }
}
