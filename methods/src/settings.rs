//! [`PlannerSettings`]: the method and every planner's knobs, each with its
//! default declared once (by the planner that owns it:
//! [`AmSettings::optimiser`], [`AmSettings::safety_filter`],
//! [`PipelineSettings::default`]). A table that sets some keys keeps the
//! defaults of the rest: a daemon team's `[team.planner]`, a settings file
//! (`flowopt bench --config`), or `--set key=value` with a dotted key
//! (`--set learned.candidates=8`, `--set optimiser.rho.max=200`).

use std::path::Path;

use flowopt_models::pipeline::PipelineSettings;
use flowopt_planner::am::AmSettings;
use flowopt_planner::metrics::DENSE_FACTOR;
use flowopt_planner::problem::Team;
use serde::{Deserialize, Deserializer, Serialize};
use thiserror::Error;

use crate::method::Method;

/// Constraint inflation (relative to the separation) kept beyond the
/// tracking buffer, so that plans converge to the buffered verification
/// (the engines' default 5% inflation over their 0% verification).
const CONSTRAINT_HEADROOM: f64 = 0.03;

/// The largest team `auto` races the learned pipeline for, by default (the
/// largest the shipped weights were trained on). Above it the optimiser
/// plans alone: on crowds of 64 robots it won every race (seeds 11-30), and
/// at 128 the racing pipeline slowed it from 182 to 248 ms median
/// (docs/BENCHMARKS.md).
const RACE_MAX_ROBOTS: usize = 32;

/// Why settings could not be read or set.
#[derive(Debug, Error)]
pub enum SettingsError {
    /// A settings file could not be read.
    #[error("SettingsError::Io: {path}: {message}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        message: String,
    },
    /// Settings that do not parse, or a key or value that does not fit.
    #[error("SettingsError::Invalid: {0}")]
    Invalid(String),
}

/// How problems are planned: the method and every planner's settings.
/// Read it with [`PlannerSettings::from_table`] (or, in a serde struct,
/// `#[serde(deserialize_with = "PlannerSettings::merged")]`): keys left out
/// keep their defaults. Its own `Deserialize` wants every key.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlannerSettings {
    /// The method.
    pub method: Method,
    /// The from-scratch optimiser (default [`AmSettings::optimiser`]).
    pub optimiser: AmSettings,
    /// The learned pipeline's safety filter (default
    /// [`AmSettings::safety_filter`]).
    pub filter: AmSettings,
    /// The learned pipeline (default [`PipelineSettings::default`]).
    pub learned: PipelineSettings,
    /// The largest team `auto` races the learned pipeline for.
    pub race_max_robots: usize,
    /// `auto`'s optimiser, for a team with an acceleration limit, plans
    /// again with the limit as a constraint where its verified plan from
    /// motion is over it ([`crate::WithinLimits`]). The daemon turns it
    /// off (`flowopt_daemon`'s preload: a second run holds the cold lane
    /// from a start that is stale by then).
    pub retry_within_limits: bool,
    /// `auto` races the learned pipeline on problems whose robots are in
    /// motion too; off, the optimiser plans those alone
    /// ([`crate::FromRest`]: on two cores the race slowed it more than
    /// the pipeline's wins from motion saved). The daemon turns it on
    /// (`flowopt_daemon`'s preload: without the pipeline from motion, its
    /// 16-robot lab day reached 1.78-2.59 goals per robot-minute at seed 0
    /// against 2.66-2.72).
    pub race_from_motion: bool,
    /// Threads the optimiser iterates on, the calling one among them (teams
    /// of [`flowopt_planner::am::CREW_MIN_ROBOTS`] robots or more, one per
    /// block of 16 robots at most; the same plans for every count); 0: the
    /// machine's cores less one, left for the daemon's worker; never more
    /// than the machine's cores ([`Self::threads`]).
    pub threads: usize,
}

impl Default for PlannerSettings {
    fn default() -> Self {
        Self {
            method: Method::default(),
            optimiser: AmSettings::optimiser(),
            filter: AmSettings::safety_filter(),
            learned: PipelineSettings::default(),
            race_max_robots: RACE_MAX_ROBOTS,
            retry_within_limits: true,
            race_from_motion: false,
            threads: 0,
        }
    }
}

impl PlannerSettings {
    /// The threads the optimiser iterates on: [`Self::threads`], or where
    /// that is 0 the machine's cores less one, left for the daemon's worker
    /// and the controllers beside it (at least one). On this project's
    /// 2-core machine two threads for the 64-robot demo's replans took
    /// `Ok` beside a busy process from 75% to 0% of answers: a crew that
    /// spins between steps must not share its cores (docs/BENCHMARKS.md,
    /// "Threads"). A count above the machine's cores is cut to them: a
    /// crew's step waits for its slowest member, and members that wait for
    /// a core make every step wait for the scheduler (64 robots on this
    /// 2-core machine, 4 threads: 3.9 s a plan against 28 ms on one).
    pub fn threads(&self) -> usize {
        let cores = std::thread::available_parallelism().map_or(1, |c| c.get());
        match self.threads {
            0 => cores.saturating_sub(1).max(1),
            asked => asked.min(cores),
        }
    }

    /// The optimiser's settings, on [`Self::threads`] threads.
    pub fn optimiser(&self) -> AmSettings {
        AmSettings { threads: self.threads(), ..self.optimiser }
    }

    /// The learned pipeline's settings, its threads (1 without obstacles,
    /// 2 with, [`PipelineSettings::threads_for`]) at most [`Self::threads`].
    pub fn learned(&self) -> PipelineSettings {
        let cap = self.threads();
        PipelineSettings {
            threads: self.learned.threads.min(cap),
            obstacle_threads: self.learned.obstacle_threads.min(cap),
            ..self.learned.clone()
        }
    }

    /// The defaults with `table`'s keys set (nested tables set nested keys).
    pub fn from_table(table: toml::Table) -> Result<Self, SettingsError> {
        let mut merged = Self::default().to_table()?;
        merge(&mut merged, table);
        toml::Value::Table(merged).try_into().map_err(|e: toml::de::Error| SettingsError::Invalid(e.to_string()))
    }

    /// The settings of a TOML file of these keys (`method`, `[optimiser]`,
    /// `[learned]`, ...).
    pub fn from_file(path: &Path) -> Result<Self, SettingsError> {
        let shown = path.display().to_string();
        let text = std::fs::read_to_string(path)
            .map_err(|e| SettingsError::Io { path: shown.clone(), message: e.to_string() })?;
        let table: toml::Table = toml::from_str(&text).map_err(|e| SettingsError::Invalid(format!("{shown}: {e}")))?;
        Self::from_table(table).map_err(|e| SettingsError::Invalid(format!("{shown}: {e}")))
    }

    /// Sets one knob: `key=value`, the key dotted (`learned.candidates=8`),
    /// the value a TOML value (`true`, `0.5`, `"path"`; a bare word is a
    /// string).
    pub fn set(&mut self, assignment: &str) -> Result<(), SettingsError> {
        let invalid = |message: String| SettingsError::Invalid(format!("--set {assignment}: {message}"));
        let (key, text) = assignment.split_once('=').ok_or_else(|| invalid("expected key=value".into()))?;
        let value = parse_value(text.trim());
        let mut table = toml::Table::new();
        let mut keys = key.trim().split('.').rev();
        let last = keys.next().filter(|k| !k.is_empty()).ok_or_else(|| invalid("no key".into()))?;
        let mut nested = toml::Value::Table(toml::Table::from_iter([(last.to_string(), value)]));
        for k in keys {
            nested = toml::Value::Table(toml::Table::from_iter([(k.to_string(), nested)]));
        }
        if let toml::Value::Table(t) = nested {
            table = t;
        }
        let mut merged = self.to_table()?;
        merge(&mut merged, table);
        *self = toml::Value::Table(merged).try_into().map_err(|e: toml::de::Error| invalid(e.message().to_string()))?;
        Ok(())
    }

    /// The defaults with the keys of a serde value set: for
    /// `#[serde(deserialize_with = "PlannerSettings::merged")]`.
    pub fn merged<'de, D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let table = toml::Table::deserialize(deserializer)?;
        PlannerSettings::from_table(table).map_err(serde::de::Error::custom)
    }

    /// These settings as a TOML table (every key).
    pub fn to_table(&self) -> Result<toml::Table, SettingsError> {
        toml::Table::try_from(self).map_err(|e| SettingsError::Invalid(e.to_string()))
    }

    /// The same settings for robots that follow their plans within
    /// `follow_tolerance` (m) of `team`: every plan keeps the tracking
    /// buffer ([`tracking_buffer`]) on its dense verification, its
    /// constraints a little more ([`buffered`]). The daemon plans so.
    pub fn tracking(mut self, team: &Team, follow_tolerance: f64) -> Self {
        let buffer = tracking_buffer(team, follow_tolerance);
        self.optimiser = buffered(self.optimiser, buffer);
        self.filter = buffered(self.filter, buffer);
        self
    }
}

/// The relative buffer every plan keeps beyond the robots' separation on the
/// dense verification grid: twice `follow_tolerance` over the smallest
/// separation. Two robots that each follow their plan within the tolerance
/// (the condition for re-issuing a held plan) then cannot touch. Within the
/// first constraint interval after the (measured, possibly near-contact)
/// start the buffer is not required.
pub fn tracking_buffer(team: &Team, follow_tolerance: f64) -> f64 {
    let (a, b) = team.separation();
    2.0 * follow_tolerance / a.min(b)
}

/// `settings` verified with the relative `buffer` beyond the true sizes
/// (except the dense instants of the first constraint interval), its
/// constraints inflated by at least the buffer and a headroom.
pub fn buffered(settings: AmSettings, buffer: f64) -> AmSettings {
    AmSettings {
        margin: settings.margin.max(buffer + CONSTRAINT_HEADROOM),
        verify_margin: buffer,
        verify_skip: DENSE_FACTOR,
        ..settings
    }
}

/// A TOML value from a command line: `true`, `8`, `0.5`, `"x"`, `[1, 2]`;
/// anything else is a string.
fn parse_value(text: &str) -> toml::Value {
    toml::from_str::<toml::Table>(&format!("v = {text}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(text.to_string()))
}

/// Sets `over`'s keys in `into`, tables key by key.
fn merge(into: &mut toml::Table, over: toml::Table) {
    for (key, value) in over {
        match (into.get_mut(&key), value) {
            (Some(toml::Value::Table(inner)), toml::Value::Table(more)) => merge(inner, more),
            (_, value) => {
                into.insert(key, value);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_models::shipped::WeightsRef;
    use flowopt_planner::problem::Dim;

    #[test]
    fn keys_left_out_keep_the_defaults_of_their_planner() {
        let text = "method = \"baseline\"\n[optimiser]\nmax_iterations = 5\n[learned]\ncandidates = 2\n";
        let settings = PlannerSettings::from_table(toml::from_str(text).unwrap()).unwrap();
        assert_eq!(settings.method, Method::Baseline);
        assert_eq!(settings.optimiser, AmSettings { max_iterations: 5, ..AmSettings::optimiser() });
        assert_eq!(settings.filter, AmSettings::safety_filter());
        assert_eq!(settings.learned, PipelineSettings { candidates: 2, ..PipelineSettings::default() });
        assert_eq!(PlannerSettings::from_table(toml::Table::new()).unwrap(), PlannerSettings::default());
        assert!(PlannerSettings::from_table(toml::from_str("[learned]\nsteps = 3").unwrap()).is_err(), "unknown key");
    }

    #[test]
    fn any_knob_can_be_set_by_name_and_a_wrong_one_is_an_error() {
        let mut s = PlannerSettings::default();
        s.set("learned.candidates=8").unwrap();
        s.set("optimiser.rho.max = 200.0").unwrap();
        s.set("optimiser.chord=false").unwrap();
        s.set("learned.flow=models/weights/flow.safetensors").unwrap();
        s.set("learned.settle=\"smoothest\"").unwrap();
        s.set("method=flow-no-init").unwrap();
        assert_eq!(s.learned.candidates, 8);
        assert_eq!((s.optimiser.rho.max, s.optimiser.chord), (200.0, false));
        assert_eq!(s.learned.flow, WeightsRef::File("models/weights/flow.safetensors".into()));
        assert_eq!(s.method, Method::FlowNoInit);
        for bad in ["learned.candidatez=8", "learned.candidates=many", "optimiser", "method=fastest", "=3"] {
            let before = s.clone();
            assert!(s.set(bad).is_err(), "{bad}");
            assert_eq!(s, before, "a refused assignment changes nothing");
        }
    }

    #[test]
    fn threads_are_the_cores_less_one_by_default_and_never_more_than_the_cores() {
        let cores = std::thread::available_parallelism().map_or(1, |c| c.get());
        let with = |threads| PlannerSettings { threads, ..PlannerSettings::default() }.threads();
        assert_eq!(with(0), cores.saturating_sub(1).max(1));
        assert_eq!(with(1), 1);
        assert_eq!(with(cores + 7), cores, "cut to the machine's cores");
        assert_eq!(with(cores), cores);
        // The learned pipeline's threads are capped by them too.
        let one = PlannerSettings { threads: 1, ..PlannerSettings::default() }.learned();
        assert_eq!((one.threads_for(0), one.threads_for(3)), (1, 1));
        let defaults = PipelineSettings::default();
        assert_eq!((defaults.threads_for(0), defaults.threads_for(3)), (1, 2));
        assert!(PlannerSettings::from_table(toml::from_str("[learned]\nobstacle_threads = 3").unwrap()).is_err());
    }

    #[test]
    fn tracking_keeps_the_buffer_on_every_plan() {
        let team = Team::default_for(Dim::Two, 4);
        let s = PlannerSettings::default().tracking(&team, 0.005);
        assert!((s.optimiser.verify_margin - 0.05).abs() < 1e-12);
        assert_eq!((s.filter.verify_skip, s.filter.verify_margin), (DENSE_FACTOR, s.optimiser.verify_margin));
        assert!((s.optimiser.margin - 0.08).abs() < 1e-12);
    }
}
