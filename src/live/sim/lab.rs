//! A lab's day for the simulated team: goals changed mid-flight (per
//! robot, at a rate), gusts (a robot's velocity kicked), a controller that
//! tracks late, and walkers (people crossing the workspace, reported in the
//! snapshots as moving obstacles). `--lab` turns on a preset; each option
//! overrides it. Every draw comes from the run's seed.

use clap::Args;
use flowopt_planner::problem::Team;
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::robots::Robots;
use super::world::{RADIUS, SimObstacle, WALKING_SPEED, World};

/// The preset's goal changes per robot-minute.
const PRESET_GOAL_CHANGES: f64 = 2.0;
/// The preset's gusts per robot-minute.
const PRESET_GUSTS: f64 = 2.0;
/// The preset's gust strength (m/s).
const PRESET_GUST_SPEED: f64 = 0.3;
/// The preset's walkers.
const PRESET_WALKERS: usize = 2;
/// A new goal keeps this many separations from every other goal.
const GOAL_SPACING: f64 = 1.5;
/// A walker enters this far (m) outside the workspace, beyond its radius.
const ENTRY_MARGIN: f64 = 0.5;

/// Options of a lab's day (`flowopt demo` and `flowopt sim`).
#[derive(Debug, Clone, Default, Args)]
pub struct LabArgs {
    /// A lab's day: goals changed mid-flight (2 per robot-minute), gusts (2
    /// per robot-minute, 0.3 m/s) and 2 walkers; the options below override
    /// it one by one
    #[arg(long)]
    pub lab: bool,
    /// Each robot's goal changes mid-flight at this rate (per robot-minute,
    /// at random instants) [default: 0, with --lab 2]
    #[arg(long, value_name = "PER_ROBOT_MINUTE")]
    pub goal_changes: Option<f64>,
    /// A gust kicks a robot's velocity by --gust-speed in a random direction
    /// at this rate (per robot-minute) [default: 0, with --lab 2]
    #[arg(long, value_name = "PER_ROBOT_MINUTE")]
    pub gusts: Option<f64>,
    /// A gust's strength (m/s) [default: 0.3]
    #[arg(long, value_name = "M_PER_S")]
    pub gust_speed: Option<f64>,
    /// The robots act on their controllers' commands this late (ms): an
    /// actuation delay [default: 0]
    #[arg(long, value_name = "MS")]
    pub tracking_lag_ms: Option<f64>,
    /// Walkers crossing the workspace at walking speed, as many at every
    /// moment (a new one enters when one has left) [default: 0, with --lab 2]
    #[arg(long, value_name = "N")]
    pub walkers: Option<usize>,
}

/// The day `LabArgs` describe.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LabDay {
    /// Goal changes per robot-minute.
    pub goal_changes: f64,
    /// Gusts per robot-minute.
    pub gusts: f64,
    /// Gust strength (m/s).
    pub gust_speed: f64,
    /// Tracking lag (ms).
    pub tracking_lag_ms: f64,
    /// Walkers at every moment.
    pub walkers: usize,
}

impl LabArgs {
    /// The day: the preset's values (with `--lab`) or none, each option
    /// given overriding it.
    pub fn day(&self) -> LabDay {
        let preset = |value: f64| if self.lab { value } else { 0.0 };
        LabDay {
            goal_changes: self.goal_changes.unwrap_or(preset(PRESET_GOAL_CHANGES)),
            gusts: self.gusts.unwrap_or(preset(PRESET_GUSTS)),
            gust_speed: self.gust_speed.unwrap_or(PRESET_GUST_SPEED),
            tracking_lag_ms: self.tracking_lag_ms.unwrap_or(0.0),
            walkers: self.walkers.unwrap_or(if self.lab { PRESET_WALKERS } else { 0 }),
        }
    }

    /// The same options for a child `flowopt sim`.
    pub fn child_args(&self) -> Vec<String> {
        let mut args = Vec::new();
        if self.lab {
            args.push("--lab".to_string());
        }
        let mut option = |name: &str, value: Option<String>| {
            if let Some(v) = value {
                args.extend([format!("--{name}"), v]);
            }
        };
        option("goal-changes", self.goal_changes.map(|v| v.to_string()));
        option("gusts", self.gusts.map(|v| v.to_string()));
        option("gust-speed", self.gust_speed.map(|v| v.to_string()));
        option("tracking-lag-ms", self.tracking_lag_ms.map(|v| v.to_string()));
        option("walkers", self.walkers.map(|v| v.to_string()));
        args
    }
}

impl LabDay {
    /// Whether anything happens on this day.
    pub fn is_quiet(&self) -> bool {
        self.goal_changes <= 0.0 && self.gusts <= 0.0 && self.tracking_lag_ms <= 0.0 && self.walkers == 0
    }

    /// Checks the values: one line saying what is wrong.
    pub fn check(&self) -> Result<(), String> {
        let rates = [self.goal_changes, self.gusts, self.gust_speed, self.tracking_lag_ms];
        if rates.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
            return Err("--goal-changes, --gusts, --gust-speed and --tracking-lag-ms must be finite and not negative"
                .to_string());
        }
        Ok(())
    }
}

/// What a lab's day did and what the robots achieved.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct LabReport {
    /// The day.
    pub day: Option<LabDay>,
    /// Goals changed mid-flight (a robot not at its goal given another).
    pub goal_changes: u64,
    /// Gusts.
    pub gusts: u64,
    /// Walkers that entered.
    pub walkers: u64,
    /// Goals reached, robot by robot (each goal once).
    pub goals_reached: u64,
    /// Goals reached per robot-minute.
    pub goals_per_robot_minute: f64,
}

/// The day's events as the run goes.
pub struct Lab {
    day: LabDay,
    rng: ChaCha8Rng,
    reached: Vec<bool>,
    walkers: Vec<SimObstacle>,
    report: LabReport,
}

impl Lab {
    /// The day for a team of `robots`, its draws seeded by `seed`.
    pub fn new(day: LabDay, robots: usize, seed: u64) -> Self {
        Self {
            day,
            rng: ChaCha8Rng::seed_from_u64(seed ^ 0x1ab_da7),
            reached: vec![false; robots],
            walkers: Vec::new(),
            report: LabReport { day: Some(day), ..LabReport::default() },
        }
    }

    /// How late the controllers track (ns).
    pub fn lag_ns(&self) -> u64 {
        (self.day.tracking_lag_ms * 1e6) as u64
    }

    /// One control period of `dt` s ending `t` s into the run: counts the
    /// robots at their goals, changes goals, kicks robots and sends
    /// walkers in.
    pub fn tick(&mut self, t: f64, dt: f64, robots: &mut Robots, world: &mut World) {
        let team = robots.team.clone();
        for i in 0..team.robots {
            if !self.reached[i] && robots.at_goal(i) {
                self.reached[i] = true;
                self.report.goals_reached += 1;
            }
        }
        let per_robot = |rate: f64| rate * dt / 60.0;
        for i in 0..team.robots {
            if self.rng.random::<f64>() < per_robot(self.day.goal_changes)
                && let Some(goal) = self.free_goal(&team, &robots.goal, i, world, t)
            {
                self.report.goal_changes += u64::from(!self.reached[i]);
                robots.goal[i] = goal;
                self.reached[i] = false;
            }
            if self.rng.random::<f64>() < per_robot(self.day.gusts) {
                robots.velocity[i] += self.direction(&team) * self.day.gust_speed;
                self.report.gusts += 1;
            }
        }
        self.walkers.retain(|w| w.present(t));
        while self.walkers.len() < self.day.walkers {
            let walker = self.walker(&team, t);
            world.add(walker);
            self.walkers.push(walker);
            self.report.walkers += 1;
        }
    }

    /// A new team goal set was drawn: every robot is on its way again.
    pub fn new_goal_set(&mut self) {
        self.reached.iter_mut().for_each(|r| *r = false);
    }

    /// What the day did over `seconds` of a team of `robots`.
    pub fn report(mut self, seconds: f64) -> LabReport {
        let robot_minutes = self.reached.len() as f64 * seconds / 60.0;
        self.report.goals_per_robot_minute =
            if robot_minutes > 0.0 { self.report.goals_reached as f64 / robot_minutes } else { 0.0 };
        self.report
    }

    /// A random unit direction in the team's axes.
    fn direction(&mut self, team: &Team) -> Vector3<f64> {
        loop {
            let mut v = Vector3::zeros();
            for a in 0..team.dim.axes() {
                v[a] = self.rng.random_range(-1.0..1.0);
            }
            let n = v.norm();
            if n > 1e-3 && n <= 1.0 {
                return v / n;
            }
        }
    }

    /// A goal for robot `i` inside the workspace (inset by a radius and a
    /// half), `GOAL_SPACING` separations from every other robot's goal and
    /// clear of the obstacles present; `None` after a few tries.
    fn free_goal(
        &mut self,
        team: &Team,
        goals: &[Vector3<f64>],
        i: usize,
        world: &World,
        t: f64,
    ) -> Option<Vector3<f64>> {
        let inset = team.robot.radius * 1.5;
        let (a, _) = team.separation();
        for _ in 0..32 {
            let mut g = Vector3::zeros();
            for ax in 0..team.dim.axes() {
                g[ax] = self.rng.random_range(team.workspace.min[ax] + inset..team.workspace.max[ax] - inset);
            }
            let apart = goals.iter().enumerate().all(|(j, o)| j == i || (o - g).norm() >= GOAL_SPACING * a);
            if apart && world.clear_of(t, &g, inset) {
                return Some(g);
            }
        }
        None
    }

    /// A walker crossing the workspace at walking speed through a random
    /// point inside it, from `t`: it appears where its edge is
    /// `ENTRY_MARGIN` from the box (the mocap volume sees people before
    /// they step in) and is gone once it is as far out on the far side.
    fn walker(&mut self, team: &Team, t: f64) -> SimObstacle {
        let (lo, hi) = (team.workspace.min, team.workspace.max);
        let centre = (lo + hi) / 2.0;
        let half = (hi - lo) / 2.0;
        let through = Vector3::new(
            centre.x + self.rng.random_range(-0.8..0.8) * half.x,
            centre.y + self.rng.random_range(-0.8..0.8) * half.y,
            0.0,
        );
        let heading = Vector3::new(self.rng.random_range(-1.0..1.0), self.rng.random_range(-1.0..1.0), 0.0);
        let heading = if heading.norm() > 1e-3 { heading.normalize() } else { Vector3::x() };
        let out = RADIUS + ENTRY_MARGIN;
        let back = distance_out(through, -heading, team, out);
        let ahead = distance_out(through, heading, team, out);
        SimObstacle {
            position: through - heading * back,
            velocity: heading * WALKING_SPEED,
            from_s: t,
            until_s: t + (back + ahead) / WALKING_SPEED,
        }
    }
}

/// How far from `from` (inside `team`'s box) along the unit `direction` a
/// point first lies `out` (m) from the box, in the plane.
fn distance_out(from: Vector3<f64>, direction: Vector3<f64>, team: &Team, out: f64) -> f64 {
    // The distance to a convex set grows along a ray leaving it: bisect.
    let (mut inside, mut outside) = (0.0, (team.workspace.max - team.workspace.min).xy().norm() + out);
    for _ in 0..60 {
        let mid = 0.5 * (inside + outside);
        if planar_distance_to_box(from + direction * mid, team) >= out {
            outside = mid;
        } else {
            inside = mid;
        }
    }
    outside
}

/// The planar distance (m) from `p` to `team`'s box (0 inside).
fn planar_distance_to_box(p: Vector3<f64>, team: &Team) -> f64 {
    let (lo, hi) = (team.workspace.min, team.workspace.max);
    let gap = |ax: usize| (lo[ax] - p[ax]).max(p[ax] - hi[ax]).max(0.0);
    gap(0).hypot(gap(1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_planner::problem::Dim;
    use flowopt_planner::scenario::RandomScenario;

    #[test]
    fn the_preset_turns_the_day_on_and_options_override_it() {
        let quiet = LabArgs::default().day();
        assert!(quiet.is_quiet());
        let preset = LabArgs { lab: true, ..LabArgs::default() }.day();
        assert_eq!((preset.goal_changes, preset.gusts, preset.walkers), (2.0, 2.0, 2));
        let fewer = LabArgs { lab: true, walkers: Some(0), ..LabArgs::default() };
        assert_eq!(fewer.day().walkers, 0);
        assert_eq!(fewer.child_args(), ["--lab", "--walkers", "0"]);
        assert!(LabArgs { gusts: Some(-1.0), ..LabArgs::default() }.day().check().is_err());
    }

    #[test]
    fn a_day_changes_goals_kicks_robots_and_keeps_walkers_crossing() {
        let team = Team::default_for(Dim::Two, 8);
        let problem = RandomScenario::new(team.clone()).generate(3).unwrap();
        let mut robots = Robots::new(&problem, 3);
        let mut world = World::default();
        let day = LabDay { goal_changes: 60.0, gusts: 60.0, gust_speed: 0.3, tracking_lag_ms: 0.0, walkers: 2 };
        let mut lab = Lab::new(day, team.robots, 3);
        let goals = robots.goal.clone();
        for k in 0..100 {
            lab.tick(k as f64 * 0.02, 0.02, &mut robots, &mut world);
            assert_eq!(world.present(k as f64 * 0.02).len(), 2, "two walkers at every moment");
        }
        let report = lab.report(2.0);
        // 8 robots, 2 s at 60 per robot-minute: about 16 of each.
        assert!((4..40).contains(&report.gusts), "{report:?}");
        assert!(robots.goal != goals, "goals changed");
        assert!(robots.velocity.iter().any(|v| v.norm() > 0.2), "kicked");
        assert_eq!(report.walkers, 2, "both still crossing after 2 s");
    }

    #[test]
    fn a_new_goal_keeps_its_spacing_from_the_others_and_the_walkers() {
        let team = Team::default_for(Dim::Two, 8);
        let problem = RandomScenario::new(team.clone()).generate(4).unwrap();
        let mut world = World::default();
        let day = LabDay { goal_changes: 0.0, gusts: 0.0, gust_speed: 0.3, tracking_lag_ms: 0.0, walkers: 1 };
        let mut lab = Lab::new(day, team.robots, 4);
        let walker = lab.walker(&team, 0.0);
        world.add(walker);
        let t = 3.0;
        let (a, _) = team.separation();
        for _ in 0..50 {
            let g = lab.free_goal(&team, &problem.goals, 2, &world, t).expect("room for a goal");
            for (j, o) in problem.goals.iter().enumerate().filter(|&(j, _)| j != 2) {
                assert!((o - g).norm() >= GOAL_SPACING * a, "goal {j} too close");
            }
            assert!(world.clear_of(t, &g, team.robot.radius * 1.5));
            for ax in 0..2 {
                assert!(g[ax] > team.workspace.min[ax] && g[ax] < team.workspace.max[ax]);
            }
        }
    }

    #[test]
    fn walkers_appear_and_leave_their_margin_outside_the_box_and_cross_it() {
        let team = Team::default_for(Dim::Two, 16);
        let mut lab = Lab::new(LabDay { walkers: 1, ..LabArgs::default().day() }, team.robots, 5);
        for _ in 0..200 {
            let walker = lab.walker(&team, 1.0);
            let (first, last) = (walker.at(walker.from_s).position, walker.at(walker.until_s).position);
            for (p, what) in [(first, "appears"), (last, "leaves")] {
                let d = planar_distance_to_box(p, &team);
                assert!((d - RADIUS - ENTRY_MARGIN).abs() < 1e-9, "{what} {d:.3} m from the box");
            }
            let along = |k: usize| walker.at(walker.from_s + (walker.until_s - walker.from_s) * k as f64 / 100.0);
            assert!((0..=100).any(|k| team.workspace.contains(team.dim, &along(k).position, 0.0)), "crosses");
            assert!((walker.velocity.norm() - WALKING_SPEED).abs() < 1e-12);
        }
    }
}
