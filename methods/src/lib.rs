//! The one home for how a problem is planned: every method, its settings
//! and the race between them. The daemon's cold plans, `flowopt solve`,
//! `bench`, `eval` and `datagen` all build their planners here.
//!
//! - [`Method`]: the methods a user picks (`auto`, `baseline`, `flowopt`,
//!   `flow-no-init`, `safety-filter`);
//! - [`PlannerSettings`]: one settings struct (each planner's knobs with
//!   their defaults declared once), read from a daemon team's
//!   `[team.planner]` table, a settings file or `--set key=value`;
//! - [`build`]: the planners a method runs for a team, and the policy of
//!   who races ([`build::members`]);
//! - [`Race`]: the portfolio race: every member plans every request on a
//!   thread of its own, the first verified plan wins and the others are
//!   cancelled; anytime for the daemon, or one call for the command line
//!   (it is itself a [`Planner`]);
//! - [`PerturbedFilter`]: the safety filter's benchmark (the optimiser's
//!   plan perturbed and repaired);
//! - [`FromRest`]: `auto`'s learned member outside the daemon, which
//!   declines problems from motion.
//!
//! ```
//! use flowopt_methods::{Method, PlannerSettings, build};
//! use flowopt_planner::am::Budget;
//! use flowopt_planner::problem::{Dim, Team};
//! use flowopt_planner::scenario::RandomScenario;
//!
//! let team = Team::default_for(Dim::Two, 8);
//! let problem = RandomScenario::new(team.clone()).generate(3).unwrap();
//! let mut settings = PlannerSettings::default();
//! settings.set("method=baseline").unwrap();
//! let mut planner = build::planner(&settings, &team).unwrap();
//! let planned = planner.plan(&problem, &Budget::unlimited(), 0).unwrap();
//! assert!(planned.verified() && planned.by == "optimiser");
//! ```

pub mod build;
mod filter_bench;
mod from_rest;
mod method;
mod race;
pub mod settings;
mod within_limits;

pub use filter_bench::PerturbedFilter;
pub use flowopt_planner::method::{PlanError, Planned, Planner, Stages};
pub use from_rest::FromRest;
pub use method::Method;
pub use race::{Race, RaceResult, Request};
pub use settings::{PlannerSettings, SettingsError};
pub use within_limits::WithinLimits;
