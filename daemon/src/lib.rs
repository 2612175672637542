//! The flowopt planning daemon.
//!
//! - [`config`]: the TOML configuration (teams, sizes, workspace, horizon,
//!   rates, deadlines);
//! - [`convert`]: a snapshot checked and turned into a planning problem, or a
//!   rejection with a reason code;
//! - [`planning`]: one team's planner, off the wire: warm start from the
//!   previous plan shifted in time, cold plans, deadlines;
//! - [`serve()`]: the service: preloading, a WaitSet on every team's
//!   snapshot events, one worker thread per team (the only code that reads
//!   snapshots and writes replies), graceful shutdown.

pub mod config;
pub mod convert;
pub mod planning;
mod serve;
mod worker;

pub use serve::{DaemonError, serve};
