//! The flowopt planning daemon.
//!
//! - [`config`]: the TOML configuration (teams, sizes, workspace, horizon,
//!   rates, deadlines);
//! - [`convert`]: a snapshot checked and turned into a planning problem, or a
//!   rejection with a reason code; [`admission`]: the checks that need the
//!   daemon's state (clock window, increasing sequences);
//! - `cold`: cold plans racing on their own threads, anytime;
//! - [`lock`]: one daemon per team;
//! - [`planning`]: one team's planner and the followability contract, off
//!   the wire: held plans, warm starts only from a plan the robots are on,
//!   cold plans, stopping plans, limits;
//! - [`realtime`]: worker priority, memory locking and CPU pinning, each
//!   reported when refused;
//! - [`serve()`]: the service: preloading, a WaitSet on every team's
//!   snapshot events, one worker thread per team (the only code that reads
//!   snapshots and writes replies), graceful shutdown.

pub mod admission;
mod cold;
pub mod config;
pub mod convert;
pub mod lock;
pub mod planning;
pub mod realtime;
mod serve;
mod worker;

pub use serve::{DaemonError, serve};
