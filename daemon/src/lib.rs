//! The flowopt planning daemon.
//!
//! - [`config`]: the TOML configuration (teams, sizes, workspace, horizon,
//!   rates, deadlines);
//! - [`convert`]: a snapshot checked and turned into a planning problem, or a
//!   rejection with a reason code; [`admission`]: the checks that need the
//!   daemon's state (clock window, increasing sequences);
//! - [`lock`]: one daemon per team;
//! - [`planning`]: one team's planner and the followability contract, off
//!   the wire: held plans checked against the newest world, warm starts
//!   only from a plan the robots are on, cold plans (the race of
//!   `flowopt_methods`), stopping plans; [`answer`] and [`held`]: what it
//!   answers and holds; `preload`: building it; `repair`: the safety
//!   filter's repairs and the limits it keeps; `stops`: the stopping
//!   plans' engines, one set per stopping horizon;
//! - [`http`]: the small HTTP server of the metrics and the live view's
//!   page;
//! - [`realtime`]: worker priority, memory locking and CPU pinning, each
//!   reported when refused;
//! - [`serve()`]: the service: preloading, a WaitSet on every team's
//!   snapshot events, one worker thread per team (the only code that reads
//!   snapshots and writes replies), graceful shutdown.

pub mod admission;
pub mod answer;
pub mod config;
pub mod convert;
pub mod held;
pub mod http;
pub mod lock;
pub mod metrics;
pub mod planning;
mod preload;
pub mod realtime;
mod repair;
mod serve;
mod stops;
mod worker;

pub use preload::PreloadError;
pub use serve::{DaemonError, serve};
