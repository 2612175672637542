//! The alternating-minimisation (AM) engine: one iteration, two uses.
//!
//! Every iteration (METHOD.md section 2) projects the current positions onto
//! the non-convex constraint set ([`projection`]: inter-robot and obstacle
//! spheroids, the workspace box), updates the multiplier, and solves the
//! pre-factored xi-step ([`crate::kkt::TeamKkt`]). The cost decides the use:
//! - [`Objective::Projection`], the safety filter (SF): stay close to a given
//!   sample `xi`, `c = 1/2 ||xi_bar - xi||^2`;
//! - [`Objective::Smoothness`], the from-scratch optimiser: minimise squared
//!   acceleration from a cold start ([`AmSettings::routed_start`]).
//!
//! Working in position space keeps the iteration cheap: the multiplier and
//! right-hand side only change through `P^T (e - F xi)`, which is non-zero
//! only at violated samples, and `F^T F xi` has the Laplacian structure.
//!
//! Constraints are imposed at samples `1..K` (and, for the optimiser, at
//! the cuts of [`AmSettings::start_refine`] between samples 1 and 3): sample
//! 0 is the measured start, which no plan can change. Every separation is inflated by the safety
//! `margin` (and the box shrunk by it) so that a plan meeting them at the
//! samples also clears the true sizes between samples; the dense
//! verification ([`AmSettings`]) checks exactly that.
//!
//! ```
//! use flowopt_planner::am::{AmSettings, Engine, Objective, Stop};
//! use flowopt_planner::problem::{Dim, Team};
//! use flowopt_planner::scenario::RandomScenario;
//!
//! let team = Team::default_for(Dim::Two, 4);
//! let problem = RandomScenario::new(team.clone()).generate(7).unwrap();
//! let engine = Engine::new(&team, 0, Objective::smoothness(), AmSettings::optimiser()).unwrap();
//! let outcome = engine.solve(&problem).unwrap();
//! assert_ne!(outcome.stop, Stop::IterationCap);
//! ```

mod engine;
mod pairs;
mod passages;
mod prepare;
mod projection;
mod rates;
mod recheck;
mod run;
mod set;
mod settings;
mod start;
mod step;

pub use engine::{AmOutcome, AmState, Engine, EngineError, FIRST_CONSTRAINED_SAMPLE, Objective, Residuals};
pub use prepare::Prepared;
pub use projection::Limits;
pub use recheck::Recheck;
pub use run::{ATTEMPT_ITERATIONS_PER_ROBOT, Budget, CREW_MIN_ROBOTS, STALL_PROGRESS};
pub use set::EngineSet;
pub use settings::{AmSettings, RhoSchedule, Stop};
pub use start::Rerouter;
pub use step::{StepOperators, Stepper};
