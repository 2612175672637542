//! The daemon's configuration file (TOML); `config/default.toml` is the
//! commented default.

use std::collections::HashSet;
use std::path::Path;

use flowopt_client::messages::check_team_name;
use flowopt_client::{MAX_COEFFS, MAX_OBSTACLES, MAX_ROBOTS};
use flowopt_methods::PlannerSettings;
use flowopt_models::shipped::WeightsRef;
use flowopt_planner::problem::{Dim, ProblemError, Team};
use flowopt_planner::scenario::{FileBox, FileShape, default_degree, default_horizon, default_samples, file_team};

use crate::realtime::RealtimeConfig;

use serde::Deserialize;
use thiserror::Error;

/// Errors reading or checking a configuration.
#[derive(Debug, Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// File path.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// The file does not parse.
    #[error("cannot parse {path}: {message}")]
    Parse {
        /// File path.
        path: String,
        /// Parser message.
        message: String,
    },
    /// No `[[team]]` table.
    #[error("the configuration has no [[team]]")]
    NoTeams,
    /// Two teams share a name.
    #[error("team {0:?} is configured twice")]
    DuplicateTeam(String),
    /// The `[realtime]` section is invalid.
    #[error("{0}")]
    Realtime(String),
    /// A team that cannot be planned for.
    #[error("team {name:?}: {message}")]
    BadTeam {
        /// Team name.
        name: String,
        /// What is wrong.
        message: String,
    },
}

/// The whole configuration.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DaemonConfig {
    /// Service naming.
    #[serde(default)]
    pub ipc: IpcConfig,
    /// Scheduling and memory locking.
    #[serde(default)]
    pub realtime: RealtimeConfig,
    /// The teams served, one `[[team]]` table each.
    #[serde(rename = "team")]
    pub teams: Vec<TeamConfig>,
}

/// Service naming.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IpcConfig {
    /// Services are `<prefix>/<team>/state` and `<prefix>/<team>/plan`.
    #[serde(default = "default_prefix")]
    pub prefix: String,
}

impl Default for IpcConfig {
    fn default() -> Self {
        Self { prefix: default_prefix() }
    }
}

fn default_prefix() -> String {
    "flowopt".into()
}

/// One team.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TeamConfig {
    /// Name: the `<team>` of the service names (1-32 bytes, no `/`).
    pub name: String,
    /// 2 or 3.
    pub dim: Dim,
    /// Robots in the team.
    pub robots: usize,
    /// Their size: a disc (2D) or a spheroid (3D, `half_height` defaults
    /// to the radius).
    pub robot: FileShape,
    /// The box robot centres stay in, one entry per axis per corner.
    pub workspace: FileBox,
    /// Planning horizon T (s).
    #[serde(default = "default_horizon")]
    pub horizon: f64,
    /// Bernstein degree (at most 15).
    #[serde(default = "default_degree")]
    pub degree: usize,
    /// Constraint samples K.
    #[serde(default = "default_samples")]
    pub samples: usize,
    /// Most obstacles a snapshot may carry (factorisations are preloaded
    /// for every count up to it).
    #[serde(default)]
    pub max_obstacles: usize,
    /// Time from a snapshot's arrival by which its plan is published (ms).
    #[serde(default = "default_deadline_ms")]
    pub deadline_ms: f64,
    /// 0: replan on every new snapshot; otherwise at most this often (Hz),
    /// always from the newest snapshot.
    #[serde(default)]
    pub replan_hz: f64,
    /// Report the state as stale when no snapshot arrives for this long
    /// (ms); a snapshot measured longer ago than this is rejected.
    #[serde(default = "default_stale_ms")]
    pub stale_after_ms: f64,
    /// How far ahead of the daemon's clock a snapshot's timestamp may be
    /// (ms): the controllers' clock skew.
    #[serde(default = "default_clock_skew_ms")]
    pub clock_skew_ms: f64,
    /// The robots' top speed (m/s): published plans stay within it.
    #[serde(default = "default_max_speed")]
    pub max_speed: f64,
    /// The robots' top acceleration (m/s^2): published plans stay within
    /// it, and a robot moving towards a side of the box faster than any
    /// plan within it stops before the side is recovered or rejected
    /// (`CannotBrake`; [`Team::max_acceleration`]); with
    /// `start_recovery_s = 0`, two robots closing on each other faster than
    /// both can brake or swerve are rejected too (`CannotAvoid`).
    #[serde(default = "default_max_acceleration")]
    pub max_acceleration: f64,
    /// A snapshot whose robot moves faster than this many times
    /// `max_speed` is rejected as implausible.
    #[serde(default = "default_implausible_factor")]
    pub implausible_factor: f64,
    /// A snapshot whose obstacle moves faster than this (m/s) is rejected
    /// as implausible.
    #[serde(default = "default_max_obstacle_speed")]
    pub max_obstacle_speed: f64,
    /// Robots within this distance (m) of the held plan are following it:
    /// it may be re-issued while no new plan verifies.
    #[serde(default = "default_follow_tolerance_m")]
    pub follow_tolerance_m: f64,
    /// Robots within this distance (m) of the previous plan are
    /// warm-started from it; farther, they get a cold plan.
    #[serde(default = "default_warm_tolerance_m")]
    pub warm_tolerance_m: f64,
    /// Longest a cold plan keeps running past its deadline (ms) before it
    /// is given up.
    #[serde(default = "default_cold_budget_ms")]
    pub cold_budget_ms: f64,
    /// How far ahead (s) a moving obstacle's motion is predicted from its
    /// snapshot: every plan keeps clear of it along its reported velocity
    /// over that long (at least the stopping horizon), of static obstacles
    /// always ([`Team::obstacle_prediction`]).
    #[serde(default = "default_obstacle_prediction_s")]
    pub obstacle_prediction_s: f64,
    /// Seconds a robot measured touching another robot or an obstacle, or
    /// outside the box (from where a plan brings it back within half the
    /// horizon, given longer where it needs it:
    /// `flowopt_planner::problem::StartViolation::return_time`), or moving towards a
    /// side faster than it can stop before it, has to clear it in
    /// the plans made from that snapshot: the team goes on being planned,
    /// the contact held to what the start allows until then
    /// ([`Team::start_recovery`]). 0: such snapshots' tasks are rejected
    /// (`StartsOverlap`, `StartInObstacle`, `StartOutsideWorkspace`,
    /// `CannotBrake`, and two robots that cannot keep apart: `CannotAvoid`)
    /// and the team stops.
    #[serde(default = "default_start_recovery_s")]
    pub start_recovery_s: f64,
    /// How cold plans are made (`[team.planner]`): the method (`auto` by
    /// default: the learned pipeline races the optimiser where the policy
    /// lets it) and every planner's knobs, defaults declared by the
    /// planners; `flowopt bench --config FILE` plans with the same.
    #[serde(default, deserialize_with = "PlannerSettings::merged")]
    pub planner: PlannerSettings,
}

fn default_deadline_ms() -> f64 {
    20.0
}
fn default_stale_ms() -> f64 {
    500.0
}
fn default_clock_skew_ms() -> f64 {
    50.0
}
fn default_max_speed() -> f64 {
    1.5
}
fn default_max_acceleration() -> f64 {
    3.0
}
fn default_implausible_factor() -> f64 {
    2.0
}
fn default_max_obstacle_speed() -> f64 {
    3.0
}
fn default_follow_tolerance_m() -> f64 {
    0.010
}
fn default_warm_tolerance_m() -> f64 {
    0.05
}
fn default_cold_budget_ms() -> f64 {
    2000.0
}
/// 3.5 s: on the fault schedule's walker crossing the 16-robot team, 2 s
/// left the plans too little warning (2 and 3 obstacle contacts in two
/// 100 s runs, the team without a plan for 1.9-2.7 s), 3.5 s and 5 s none
/// (Ok 549 and 548 of 550 answers in the window); below the 5 s horizon, a
/// goal the walker will cross is still reachable after it passed.
fn default_obstacle_prediction_s() -> f64 {
    3.5
}

/// 1 s: the stopping horizon of the default speed and acceleration limits.
fn default_start_recovery_s() -> f64 {
    1.0
}

/// How much shorter (s) than a plan's obstacle prediction the check of a
/// followable answer against a newer snapshot is: a plan made to keep
/// clear of a walker's next `obstacle_prediction_s` stays followable while
/// the walker's next `obstacle_prediction_s - 1` clear it, so that the
/// window moving on with every snapshot does not reject every held plan
/// at its edge (a cliff the outside controller's walker found: held plans
/// 4-11 mm clear at the window's end, inside the buffer 20 ms later).
pub const FOLLOW_CHECK_SLACK_S: f64 = 1.0;

/// How much longer the second stopping horizon is than the first
/// ([`TeamConfig::stop_horizons`]). At the stopping horizon braking from
/// top speed already takes half the acceleration limit on average, so a
/// robot that must also step aside (a walker's track, a neighbour's
/// stopping point) is planned over the limit; twice as long asks a
/// quarter of the acceleration for the same step and half for the
/// braking. In ten 16-robot lab runs, 90 of 155 stopping plans refused at
/// the stopping horizon were made at twice it
/// (docs/experiments/2026-11-28-a-longer-stopping-horizon.md).
pub const LONG_STOP_FACTOR: f64 = 2.0;

impl TeamConfig {
    /// The stopping plans' horizon (s): `2 max_speed / max_acceleration`,
    /// at least 0.5 s.
    pub fn stop_horizon(&self) -> f64 {
        (2.0 * self.max_speed / self.max_acceleration).max(0.5)
    }

    /// The horizons (s) stopping plans are tried at, in turn: the
    /// stopping horizon, then [`LONG_STOP_FACTOR`] times it (at most
    /// `obstacle_prediction_s`, so that a stopping point is still stepped
    /// out of a walker's predicted track) where that is longer.
    pub fn stop_horizons(&self) -> Vec<f64> {
        let short = self.stop_horizon();
        let long = (LONG_STOP_FACTOR * short).min(self.obstacle_prediction_s);
        if long > short { vec![short, long] } else { vec![short] }
    }

    /// How far ahead (s) every followable answer is checked against the
    /// newest snapshot's moving obstacles, robots resting at the end of
    /// their plan: [`FOLLOW_CHECK_SLACK_S`] less than `obstacle_prediction_s`,
    /// at least the stopping horizon.
    pub fn obstacle_check_s(&self) -> f64 {
        (self.obstacle_prediction_s - FOLLOW_CHECK_SLACK_S).max(self.stop_horizon())
    }

    /// How this team's cold plans are made: its `[team.planner]` settings,
    /// every plan keeping the tracking buffer of `follow_tolerance_m`.
    pub fn planner_settings(&self, team: &Team) -> PlannerSettings {
        self.planner.clone().tracking(team, self.follow_tolerance_m)
    }

    /// The planner's description of this team.
    pub fn team(&self) -> Result<Team, ConfigError> {
        let bad = |message: String| ConfigError::BadTeam { name: self.name.clone(), message };
        let team =
            file_team(self.dim, self.robots, &self.robot, &self.workspace, self.horizon, self.degree, self.samples)
                .map_err(|e| bad(e.to_string()))?;
        team.validate().map_err(|e: ProblemError| bad(e.to_string()))?;
        if self.robots > MAX_ROBOTS || self.degree + 1 > MAX_COEFFS || self.max_obstacles > MAX_OBSTACLES {
            return Err(bad(format!(
                "messages carry at most {MAX_ROBOTS} robots, degree {} and {MAX_OBSTACLES} obstacles",
                MAX_COEFFS - 1
            )));
        }
        check_team_name(&self.name).map_err(|e| bad(e.to_string()))?;
        let positive = |v: f64| v.is_finite() && v > 0.0;
        let named = [
            ("deadline_ms", self.deadline_ms),
            ("stale_after_ms", self.stale_after_ms),
            ("clock_skew_ms", self.clock_skew_ms),
            ("max_speed", self.max_speed),
            ("max_acceleration", self.max_acceleration),
            ("max_obstacle_speed", self.max_obstacle_speed),
            ("follow_tolerance_m", self.follow_tolerance_m),
            ("warm_tolerance_m", self.warm_tolerance_m),
            ("cold_budget_ms", self.cold_budget_ms),
        ];
        if let Some((name, _)) = named.iter().find(|(_, v)| !positive(*v)) {
            return Err(bad(format!("{name} must be positive")));
        }
        if !(self.implausible_factor.is_finite() && self.implausible_factor >= 1.0) {
            return Err(bad("implausible_factor must be at least 1".into()));
        }
        if !(self.replan_hz.is_finite() && self.replan_hz >= 0.0) {
            return Err(bad("replan_hz must be 0 or positive".into()));
        }
        if !(self.obstacle_prediction_s.is_finite() && self.obstacle_prediction_s >= self.stop_horizon()) {
            return Err(bad(format!(
                "obstacle_prediction_s must be at least the stopping horizon ({:.2} s)",
                self.stop_horizon()
            )));
        }
        if !(self.start_recovery_s.is_finite() && (0.0..=self.horizon).contains(&self.start_recovery_s)) {
            return Err(bad("start_recovery_s must be 0 or positive, at most the horizon".into()));
        }
        Ok(Team {
            obstacle_prediction: Some(self.obstacle_prediction_s),
            start_recovery: (self.start_recovery_s > 0.0).then_some(self.start_recovery_s),
            max_acceleration: Some(self.max_acceleration),
            max_speed: Some(self.max_speed),
            ..team
        })
    }
}

impl DaemonConfig {
    /// Reads and checks a configuration file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let shown = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io { path: shown.clone(), source })?;
        let mut config: Self =
            toml::from_str(&text).map_err(|e| ConfigError::Parse { path: shown, message: e.to_string() })?;
        config.check()?;
        let dir = path.parent().unwrap_or(Path::new(""));
        let relative = |w: &WeightsRef| match w {
            WeightsRef::File(p) => WeightsRef::File(dir.join(p)),
            shipped => shipped.clone(),
        };
        for learned in config.teams.iter_mut().map(|t| &mut t.planner.learned) {
            learned.flow = relative(&learned.flow);
            learned.init = learned.init.as_ref().map(relative);
        }
        Ok(config)
    }

    /// Checks every team and that names are unique.
    pub fn check(&self) -> Result<(), ConfigError> {
        if self.teams.is_empty() {
            return Err(ConfigError::NoTeams);
        }
        self.realtime.check().map_err(ConfigError::Realtime)?;
        let mut names = HashSet::new();
        for t in &self.teams {
            t.team()?;
            if !names.insert(&t.name) {
                return Err(ConfigError::DuplicateTeam(t.name.clone()));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = r#"
        [[team]]
        name = "a"
        dim = 2
        robots = 4
        robot = { radius = 0.1 }
        workspace = { min = [-1.0, -1.0], max = [1.0, 1.0] }
    "#;

    /// The shipped configuration `name` (in the repository's `config/`).
    fn shipped(name: &str) -> DaemonConfig {
        DaemonConfig::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../config").join(name)).unwrap()
    }

    /// The learned planner's weights of `team` are the shipped ones, built in.
    fn assert_weights_found(team: &TeamConfig) {
        let learned = &team.planner.learned;
        assert_eq!(learned.flow, WeightsRef::Shipped);
        assert!(learned.init.is_none(), "no initialiser");
    }

    #[test]
    fn the_shipped_default_config_loads() {
        let config = shipped("default.toml");
        assert_eq!(config.ipc.prefix, "flowopt");
        let team = config.teams[0].team().unwrap();
        assert_eq!((team.robots, team.dim), (16, Dim::Two));
        assert_weights_found(&config.teams[0]);
    }

    #[test]
    fn the_shipped_big_team_config_loads() {
        let config = shipped("team64.toml");
        let team = config.teams[0].team().unwrap();
        assert_eq!((team.robots, team.dim), (64, Dim::Two));
        assert_eq!(config.teams[0].planner.method, flowopt_methods::Method::Auto);
    }

    #[test]
    fn the_shipped_big_teams_fit_their_box_in_time_and_resolution() {
        for (file, robots) in [("team64.toml", 64), ("team128.toml", 128)] {
            let config = shipped(file);
            let cfg = &config.teams[0];
            let team = cfg.team().unwrap();
            assert_eq!(team.robots, robots, "{file}");
            // The farthest trip, the box's diagonal, within max_speed.
            let diagonal = team.workspace_diagonal();
            assert!(team.horizon * cfg.max_speed >= diagonal, "{file}: {} s for {diagonal} m", team.horizon);
            // The degree and K the optimiser gives that box.
            let resolved = team.clone().resolved_for_workspace();
            assert_eq!((team.degree, team.samples), (resolved.degree, resolved.samples), "{file}");
        }
    }

    #[test]
    fn the_shipped_3d_config_loads_with_3d_weights() {
        let config = shipped("team3d.toml");
        let team = config.teams[0].team().unwrap();
        assert_eq!((team.robots, team.dim), (16, Dim::Three));
        assert_weights_found(&config.teams[0]);
    }

    #[test]
    fn defaults_fill_what_a_team_leaves_out() {
        let config: DaemonConfig = toml::from_str(MINIMAL).unwrap();
        config.check().unwrap();
        let t = &config.teams[0];
        assert_eq!((t.horizon, t.degree, t.samples, t.max_obstacles), (5.0, 10, 50, 0));
        assert_eq!((t.deadline_ms, t.replan_hz, t.stale_after_ms), (20.0, 0.0, 500.0));
        assert_eq!((t.max_speed, t.max_acceleration, t.implausible_factor), (1.5, 3.0, 2.0));
        assert_eq!((t.clock_skew_ms, t.follow_tolerance_m, t.warm_tolerance_m), (50.0, 0.010, 0.05));
        assert_eq!((t.max_obstacle_speed, t.obstacle_prediction_s), (3.0, 3.5));
        assert_eq!(t.planner, PlannerSettings::default());
        assert_eq!(t.team().unwrap().obstacle_prediction, Some(3.5));
        assert_eq!((t.start_recovery_s, t.team().unwrap().start_recovery), (1.0, Some(1.0)));
        let off: DaemonConfig =
            toml::from_str(&MINIMAL.replace("robots = 4", "robots = 4\nstart_recovery_s = 0.0")).unwrap();
        assert_eq!(off.teams[0].team().unwrap().start_recovery, None);
    }

    #[test]
    fn bad_teams_are_refused_with_the_team_named() {
        let bad = |from: &str, to: &str| {
            let config: DaemonConfig = toml::from_str(&MINIMAL.replace(from, to)).unwrap();
            config.check().unwrap_err().to_string()
        };
        assert!(bad("robots = 4", "robots = 257").contains("at most 256 robots"));
        assert!(bad("robots = 4", "robots = 4\nmax_speed = -1.0").contains("max_speed must be positive"));
        assert!(bad("robots = 4", "robots = 4\nimplausible_factor = 0.5").contains("implausible_factor"));
        assert!(bad("robots = 4", "robots = 4\nstart_recovery_s = -1.0").contains("start_recovery_s"));
        assert!(bad("robots = 4", "robots = 4\nstart_recovery_s = 6.0").contains("start_recovery_s"));
        assert!(bad("radius = 0.1", "radius = -0.1").contains("team \"a\""));
        assert!(bad("min = [-1.0, -1.0]", "min = [-1.0]").contains("workspace.min"));
        assert!(bad("name = \"a\"", "name = \"a/b\"").contains("name"));
        let twice: DaemonConfig = toml::from_str(&format!("{MINIMAL}{MINIMAL}")).unwrap();
        assert!(matches!(twice.check(), Err(ConfigError::DuplicateTeam(_))));
        assert!(toml::from_str::<DaemonConfig>(&MINIMAL.replace("robots = 4", "robots = 4\nspeed = 1")).is_err());
    }
}
