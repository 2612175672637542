//! flowopt's planner core: the math, no I/O.
//!
//! - [`basis`]: the Bernstein basis trajectories are written in;
//! - [`problem`]: teams, instances, validation;
//! - [`braking`]: how far a robot moving towards a side of the box must
//!   go at the least (the certificate of a start that cannot stay inside);
//! - [`closing`]: how close two robots moving towards each other come at
//!   the least (the certificate of a pair that cannot keep apart);
//! - [`scenario`]: seeded random instances, antipodal swaps, scenario files;
//! - [`scenes`]: scene families (random, crowd, swap, crossing, obstacle
//!   field, formation) at any team size, at constant density;
//! - [`kkt`]: the structured (mean/difference-mode) KKT solve and its dense
//!   reference;
//! - [`linalg`]: the dense products they run on;
//! - [`lp`]: small dense linear programs (the certificates' programs);
//! - [`crew`]: the threads a run's parallel steps share, and the fixed
//!   blocks that keep its numbers independent of their count;
//! - [`am`]: the alternating-minimisation engine, used as the safety filter
//!   and as the from-scratch optimiser;
//! - [`method`]: the one planner interface ([`method::Planner`]: a problem
//!   within a budget), its outcome and stage times;
//! - [`optimiser`]: the from-scratch optimiser as a planner;
//! - [`route`]: obstacle-aware cold starts for the optimiser;
//! - [`reference`]: the smoothest curves through the boundary values;
//! - [`plan`]: a joint plan, its evaluation, its warm-start shift and time
//!   scaling;
//! - [`stopping`]: the problem of bringing robots to rest along their motion;
//! - [`metrics`]: smoothness, arc length, clearances, the success verdict,
//!   time scaling;
//! - [`working_point`]: the safety filter's benchmark working point, shared
//!   by the criterion benchmark and `flowopt eval`'s machine-speed line.

pub mod am;
pub mod basis;
pub mod braking;
pub mod closing;
pub mod crew;
pub mod kkt;
pub mod linalg;
pub mod lp;
pub mod method;
pub mod metrics;
pub mod optimiser;
pub mod plan;
pub mod problem;
mod problem_error;
pub mod recovery;
pub mod reference;
pub mod route;
pub mod scenario;
pub mod scenes;
mod start_violation;
pub mod stopping;
pub mod working_point;
