//! The simulated team: double-integrator robots tracking a trajectory with
//! a PD controller plus its acceleration as feedforward, braking when there
//! is none, disturbed by seeded noise; contacts counted on the executed
//! motion at every integration substep, between robots and between robots
//! and the obstacles.

use flowopt_client::Followed;
use flowopt_planner::problem::{Obstacle, Problem, StartState, Team, scaled_norm};
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// Position gain (1/s^2): with `KD` a critically damped 5 rad/s loop.
const KP: f64 = 25.0;
/// Velocity gain (1/s).
const KD: f64 = 10.0;
/// Integration substeps per control period (2 ms at 50 Hz).
pub const SUBSTEPS: usize = 10;
/// A robot is at its goal within this distance (m) and at rest.
const ARRIVED_DISTANCE: f64 = 0.02;
/// Speed (m/s) below which a robot is at rest.
const REST_SPEED: f64 = 0.05;
/// Standard deviation of the mocap position noise on published states (m).
const POSITION_NOISE: f64 = 0.001;
/// Standard deviation of the velocity-estimate noise (m/s).
const VELOCITY_NOISE: f64 = 0.005;
/// Standard deviation of the unmodelled acceleration disturbance, drawn per
/// robot once per control period (m/s^2).
const DISTURBANCE: f64 = 0.2;

/// What one control period of motion showed.
#[derive(Debug, Clone, Default)]
pub struct Motion {
    /// Closest robot-robot scaled distance in the period.
    pub closest: f64,
    /// Closest robot-obstacle scaled distance in the period (infinite
    /// without obstacles).
    pub closest_obstacle: f64,
    /// Farthest any robot was outside the workspace (m).
    pub workspace_excess: f64,
    /// Mean and largest distance from the desired positions at the end (m;
    /// 0 without a trajectory).
    pub tracking: (f64, f64),
    /// Each contact begun in the period, as it began.
    pub began: Vec<Touch>,
}

impl Motion {
    /// Robot-robot contacts begun in the period.
    pub fn contacts(&self) -> u64 {
        self.began.iter().filter(|t| matches!(t.other, Touched::Robot(_))).count() as u64
    }

    /// Robot-obstacle contacts begun in the period.
    pub fn obstacle_contacts(&self) -> u64 {
        self.began.len() as u64 - self.contacts()
    }
}

/// A contact as it began, at an integration substep.
#[derive(Debug, Clone, Copy)]
pub struct Touch {
    /// The substep's instant (ns, [`flowopt_client::clock::monotonic_ns`]).
    pub at_ns: u64,
    /// The robot (of a pair, the lower index).
    pub robot: usize,
    /// What it touched.
    pub other: Touched,
    /// The robot's speed (m/s).
    pub speed: f64,
    /// The other robot's or the obstacle's speed (m/s).
    pub other_speed: f64,
    /// Where the robot was (m).
    pub position: Vector3<f64>,
    /// Where the other robot or the obstacle was (m).
    pub other_position: Vector3<f64>,
}

/// What a robot touched.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Touched {
    /// Another robot, by index.
    Robot(usize),
    /// An obstacle, by index into the period's list.
    Obstacle(usize),
}

/// The simulated team.
pub struct Robots {
    /// The team.
    pub team: Team,
    /// Positions (m).
    pub position: Vec<Vector3<f64>>,
    /// Velocities (m/s).
    pub velocity: Vec<Vector3<f64>>,
    /// Goals.
    pub goal: Vec<Vector3<f64>>,
    touching: Vec<bool>,
    /// Per robot, the obstacles (by index into the period's list) it touched.
    touching_obstacle: Vec<Vec<bool>>,
    rng: ChaCha8Rng,
    disturbance: Vec<Vector3<f64>>,
    /// How late the robots act on their controllers' commands (ns): an
    /// actuation delay.
    pub lag_ns: u64,
    /// Commands issued and not yet acted on, oldest first, with when they
    /// act (ns).
    pending: std::collections::VecDeque<(u64, Vec<Vector3<f64>>)>,
}

impl Robots {
    /// The team at rest at `problem`'s starts with its goals; `seed` seeds
    /// the noise.
    pub fn new(problem: &Problem, seed: u64) -> Self {
        let n = problem.robots();
        Self {
            team: problem.team.clone(),
            position: problem.starts.iter().map(|s| s.position).collect(),
            velocity: vec![Vector3::zeros(); n],
            goal: problem.goals.clone(),
            touching: vec![false; n * n.saturating_sub(1) / 2],
            touching_obstacle: vec![Vec::new(); n],
            rng: ChaCha8Rng::seed_from_u64(seed),
            disturbance: vec![Vector3::zeros(); n],
            lag_ns: 0,
            pending: std::collections::VecDeque::new(),
        }
    }

    /// Advances from `from_ns` to `to_ns` tracking `desired` (braking
    /// without one); `frozen` robots do not move at all. `obstacles` are
    /// where they are at `from_ns` and how they move (the same ones, in
    /// the same order, from one period to the next while they last).
    pub fn step(
        &mut self,
        desired: Option<&Followed>,
        frozen: bool,
        from_ns: u64,
        to_ns: u64,
        obstacles: &[Obstacle],
    ) -> Motion {
        let n = self.team.robots;
        let axes = self.team.dim.axes();
        let h = to_ns.saturating_sub(from_ns) as f64 * 1e-9 / SUBSTEPS as f64;
        for w in &mut self.disturbance {
            for a in 0..axes {
                w[a] = DISTURBANCE * self.rng.sample::<f64, _>(StandardNormal);
            }
        }
        let mut motion = Motion { closest: f64::INFINITY, closest_obstacle: f64::INFINITY, ..Motion::default() };
        for touched in &mut self.touching_obstacle {
            touched.resize(obstacles.len(), false);
        }
        for sub in 0..SUBSTEPS {
            let at = from_ns + ((sub as f64) * h * 1e9) as u64;
            if frozen {
                self.velocity.iter_mut().for_each(|v| *v = Vector3::zeros());
            } else {
                let target = desired.map(|f| f.at(at));
                let command: Vec<Vector3<f64>> = (0..n)
                    .map(|i| match &target {
                        Some(d) => {
                            d[i].acceleration
                                + KP * (d[i].position - self.position[i])
                                + KD * (d[i].velocity - self.velocity[i])
                        }
                        None => -KD * self.velocity[i],
                    })
                    .collect();
                let u = self.acting(at, command);
                for i in 0..n {
                    self.velocity[i] += (u[i] + self.disturbance[i]) * h;
                    self.position[i] += self.velocity[i] * h;
                }
            }
            self.count(at, &mut motion);
            let moved: Vec<Obstacle> =
                obstacles.iter().map(|o| Obstacle { position: o.at((at - from_ns) as f64 * 1e-9 + h), ..*o }).collect();
            self.count_obstacles(at, &moved, &mut motion);
        }
        if let Some(f) = desired.filter(|_| !frozen) {
            let errors: Vec<f64> =
                f.at(to_ns).iter().zip(&self.position).map(|(d, x)| (d.position - x).norm()).collect();
            motion.tracking = (errors.iter().sum::<f64>() / n as f64, errors.iter().copied().fold(0.0, f64::max));
        }
        motion
    }

    fn count(&mut self, at_ns: u64, motion: &mut Motion) {
        let n = self.team.robots;
        let (a, b) = self.team.separation();
        let mut pair = 0;
        for i in 0..n {
            for j in i + 1..n {
                let d = scaled_norm(self.team.dim, &(self.position[i] - self.position[j]), a, b);
                motion.closest = motion.closest.min(d);
                let touching = d < 1.0;
                if touching && !self.touching[pair] {
                    motion.began.push(Touch {
                        at_ns,
                        robot: i,
                        other: Touched::Robot(j),
                        speed: self.velocity[i].norm(),
                        other_speed: self.velocity[j].norm(),
                        position: self.position[i],
                        other_position: self.position[j],
                    });
                }
                self.touching[pair] = touching;
                pair += 1;
            }
            let ws = &self.team.workspace;
            for ax in 0..self.team.dim.axes() {
                let out = (ws.min[ax] - self.position[i][ax]).max(self.position[i][ax] - ws.max[ax]);
                motion.workspace_excess = motion.workspace_excess.max(out);
            }
        }
    }

    fn count_obstacles(&mut self, at_ns: u64, obstacles: &[Obstacle], motion: &mut Motion) {
        for (i, touched) in self.touching_obstacle.iter_mut().enumerate() {
            for (m, o) in obstacles.iter().enumerate() {
                let (a, b) = self.team.obstacle_separation(&o.shape);
                let d = scaled_norm(self.team.dim, &(self.position[i] - o.position), a, b);
                motion.closest_obstacle = motion.closest_obstacle.min(d);
                let touching = d < 1.0;
                if touching && !touched[m] {
                    motion.began.push(Touch {
                        at_ns,
                        robot: i,
                        other: Touched::Obstacle(m),
                        speed: self.velocity[i].norm(),
                        other_speed: o.velocity.norm(),
                        position: self.position[i],
                        other_position: o.position,
                    });
                }
                touched[m] = touching;
            }
        }
    }

    /// Forgets which obstacles the robots touch (the list changed).
    pub fn obstacles_changed(&mut self) {
        self.touching_obstacle.iter_mut().for_each(Vec::clear);
    }

    /// The commands acting at `at_ns`, `command` just issued: itself
    /// without a lag, else the newest one issued at least `lag_ns` ago
    /// (none yet: no acceleration).
    fn acting(&mut self, at_ns: u64, command: Vec<Vector3<f64>>) -> Vec<Vector3<f64>> {
        if self.lag_ns == 0 {
            return command;
        }
        let n = command.len();
        self.pending.push_back((at_ns + self.lag_ns, command));
        let mut acting = None;
        while self.pending.front().is_some_and(|(due, _)| *due <= at_ns) {
            acting = self.pending.pop_front().map(|(_, u)| u);
        }
        let acting = acting.unwrap_or_else(|| vec![Vector3::zeros(); n]);
        // The newest command due keeps acting until a later one is due.
        self.pending.push_front((at_ns, acting.clone()));
        acting
    }

    /// Whether every robot is at its goal and stopped.
    pub fn arrived(&self) -> bool {
        (0..self.team.robots).all(|i| self.at_goal(i))
    }

    /// Whether robot `i` is at its goal and stopped.
    pub fn at_goal(&self, i: usize) -> bool {
        (self.position[i] - self.goal[i]).norm() < ARRIVED_DISTANCE && self.velocity[i].norm() < REST_SPEED
    }

    /// Whether every robot is at rest.
    pub fn at_rest(&self) -> bool {
        self.velocity.iter().all(|v| v.norm() < REST_SPEED)
    }

    /// The state as the mocap measures it (with noise), with `obstacles`:
    /// the problem a snapshot describes.
    pub fn measured(&mut self, obstacles: Vec<Obstacle>) -> Problem {
        let axes = self.team.dim.axes();
        let mut noise = |sd: f64| {
            let mut v = Vector3::zeros();
            for a in 0..axes {
                v[a] = sd * self.rng.sample::<f64, _>(StandardNormal);
            }
            v
        };
        let starts = (0..self.team.robots)
            .map(|i| StartState {
                position: self.position[i] + noise(POSITION_NOISE),
                velocity: self.velocity[i] + noise(VELOCITY_NOISE),
                acceleration: Vector3::zeros(),
            })
            .collect();
        Problem { team: self.team.clone(), starts, goals: self.goal.clone(), obstacles }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_planner::problem::Dim;
    use flowopt_planner::scenario::RandomScenario;

    #[test]
    fn a_lagging_robot_acts_on_each_command_that_much_later() {
        let problem = RandomScenario::new(Team::default_for(Dim::Two, 2)).generate(1).unwrap();
        let mut robots = Robots::new(&problem, 1);
        let push = |x: f64| vec![Vector3::new(x, 0.0, 0.0); 2];
        assert_eq!(robots.acting(0, push(1.0)), push(1.0), "no lag: at once");
        robots.lag_ns = 10;
        assert_eq!(robots.acting(0, push(1.0)), push(0.0), "nothing issued 10 ns ago");
        assert_eq!(robots.acting(5, push(2.0)), push(0.0));
        assert_eq!(robots.acting(10, push(3.0)), push(1.0), "the command of 10 ns ago");
        assert_eq!(robots.acting(12, push(4.0)), push(1.0), "acting until the next is due");
        assert_eq!(robots.acting(16, push(5.0)), push(2.0));
    }

    #[test]
    fn each_contact_is_logged_once_as_it_begins_with_what_touched() {
        let problem = RandomScenario::new(Team::default_for(Dim::Two, 2)).generate(1).unwrap();
        let mut robots = Robots::new(&problem, 1);
        let (a, _) = robots.team.separation();
        // Robot 1 just clear of robot 0 and moving into it; robot 0 at rest,
        // with an obstacle walking into it from the other side.
        robots.position = vec![Vector3::zeros(), Vector3::new(1.05 * a, 0.0, 0.0)];
        robots.velocity = vec![Vector3::zeros(), Vector3::new(-1.0, 0.0, 0.0)];
        let (b, _) = robots.team.obstacle_separation(&robots.team.robot);
        let walker = Obstacle {
            position: Vector3::new(0.0, 1.05 * b, 0.0),
            velocity: Vector3::new(0.0, -1.0, 0.0),
            shape: robots.team.robot,
        };
        let first = robots.step(None, false, 0, 20_000_000, &[walker]);
        let walked = Obstacle { position: walker.at(0.02), ..walker };
        let second = robots.step(None, false, 20_000_000, 40_000_000, &[walked]);
        assert_eq!((first.contacts(), first.obstacle_contacts()), (1, 1));
        assert_eq!(first.began.len(), 2, "{:?}", first.began);
        let pair = first.began.iter().find(|t| t.other == Touched::Robot(1)).expect("the pair");
        assert_eq!(pair.robot, 0);
        assert!(pair.other_speed > 0.5 && pair.speed < 0.5, "{pair:?}");
        let hit = first.began.iter().find(|t| t.other == Touched::Obstacle(0)).expect("the walker");
        assert_eq!(hit.robot, 0);
        assert!((hit.other_speed - 1.0).abs() < 1e-12 && hit.at_ns > 0 && hit.at_ns < 20_000_000, "{hit:?}");
        assert!(second.began.is_empty(), "still touching, not begun again: {:?}", second.began);
    }
}
