//! The engines of stopping plans at one horizon ([`Stops`]); the daemon
//! keeps one set per horizon of [`crate::config::TeamConfig::stop_horizons`],
//! tried in turn by [`crate::planning::TeamPlanner`]'s stopping plan.

use flowopt_planner::am::EngineSet;
use flowopt_planner::reference::SmoothReference;

/// The engines of stopping plans at one horizon: the safety filter for
/// each obstacle count and the smooth reference it repairs.
#[derive(Debug)]
pub(crate) struct Stops {
    /// The safety filters, one per obstacle count.
    pub(crate) engines: EngineSet,
    /// The reference they repair: each robot brought smoothly to its
    /// stopping point.
    pub(crate) reference: SmoothReference,
}
