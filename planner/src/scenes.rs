//! Scene families: the scenes labs fly, generated for any team size and
//! seed, with the workspace grown with the team to keep the density of the
//! 16-robot benchmark (half-width `w0 (n / 16)^(1/d)`, `w0` = 1 m in 2D and
//! 1.5 m in 3D).
//!
//! - [`Family::Random`]: the benchmark instances (uniform starts and goals
//!   in the default box, which does not grow);
//! - [`Family::Crowd`]: the same at constant density;
//! - [`Family::Swap`]: the antipodal swap on a circle (2D) or a sphere
//!   (3D), rotated by the seed, grown until the robots fit;
//! - [`Family::Crossing`]: two lanes of robots crossing at right angles in
//!   the middle;
//! - [`Family::ObstacleField`]: two groups in counterflow through a field of
//!   pillars (static obstacles);
//! - [`Family::Formation`]: from a grid to a ring (2D) or a sphere (3D),
//!   each robot to a seeded place of the other shape;
//! - clutter (`scenes/clutter.rs`), teams of at least 8: [`Family::Doorway`]
//!   (two rooms, one or two doors, the halves of the team swap rooms),
//!   [`Family::Aisles`] (warehouse shelves, robots to another aisle or a
//!   cross-aisle) and [`Family::PillarForest`] (pillars over the whole
//!   workspace), with passages of 1.5-2.5 robot diameters.
//!
//! ```
//! use flowopt_planner::problem::Dim;
//! use flowopt_planner::scenes::{Family, Scene};
//!
//! let scene = Scene::new(Family::Swap, Dim::Two, 32, 1);
//! let (problem, params) = scene.generate().unwrap();
//! assert_eq!(problem.robots(), 32);
//! assert!(params.half_width > 1.0, "grown with the team");
//! ```

use nalgebra::Vector3;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::problem::{Dim, Obstacle, Problem, Spheroid, StartState, Team, Workspace};
use crate::scenario::{RandomScenario, ScenarioError, ring_point};

mod clutter;

/// Spacing of robots placed in formations, in separations.
const SPACING: f64 = 1.4;
/// Radius of the obstacle field's pillars (m).
const PILLAR_RADIUS: f64 = 0.1;
/// Distance between neighbouring pillars of an obstacle field (m).
const PILLAR_PITCH: f64 = 0.7;
/// Most pillars of an obstacle field (what a snapshot carries).
const MAX_PILLARS: usize = 16;

/// A kind of scene.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Family {
    /// Uniform random starts and goals in the default box.
    #[default]
    Random,
    /// Uniform random starts and goals at constant density.
    Crowd,
    /// The antipodal swap.
    Swap,
    /// Two lanes crossing.
    Crossing,
    /// Counterflow through pillars.
    ObstacleField,
    /// Grid to ring (or sphere).
    Formation,
    /// Two rooms swapping through one or two doors.
    Doorway,
    /// Warehouse aisles.
    Aisles,
    /// A dense pillar forest.
    PillarForest,
}

impl Family {
    /// Every family, in report order.
    pub const ALL: [Family; 9] = [
        Family::Random,
        Family::Crowd,
        Family::Swap,
        Family::Crossing,
        Family::ObstacleField,
        Family::Formation,
        Family::Doorway,
        Family::Aisles,
        Family::PillarForest,
    ];

    /// Whether its scenes take [`Scene::obstacles`] random obstacles (the
    /// others place their own, or none).
    pub fn takes_random_obstacles(self) -> bool {
        matches!(self, Family::Random | Family::Crowd)
    }

    /// Its name in reports and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Family::Random => "random",
            Family::Crowd => "crowd",
            Family::Swap => "swap",
            Family::Crossing => "crossing",
            Family::ObstacleField => "obstacle-field",
            Family::Formation => "formation",
            Family::Doorway => "doorway",
            Family::Aisles => "aisles",
            Family::PillarForest => "pillar-forest",
        }
    }
}

/// One scene to generate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scene {
    /// The family.
    pub family: Family,
    /// 2D or 3D.
    pub dim: Dim,
    /// Robots.
    pub robots: usize,
    /// Seed.
    pub seed: u64,
    /// Random and crowd: random obstacles ([`RandomScenario`]).
    pub obstacles: usize,
    /// Random and crowd: largest obstacle speed (m/s).
    pub obstacle_speed: f64,
    /// Random and crowd: largest start speed (m/s).
    pub start_speed: f64,
}

/// What a generated scene was made of (for reports).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneParams {
    /// The family.
    pub family: Family,
    /// Workspace dimension.
    pub dim: usize,
    /// Robots.
    pub robots: usize,
    /// Seed.
    pub seed: u64,
    /// Half-width of the (cubic) workspace (m).
    pub half_width: f64,
    /// Static obstacles.
    pub obstacles: usize,
    /// Swap: radius of the circle or sphere (m); 0 otherwise.
    pub radius: f64,
}

/// The half-width keeping the 16-robot benchmark's density for `robots`.
pub fn density_half_width(dim: Dim, robots: usize) -> f64 {
    let (w0, d) = match dim {
        Dim::Two => (1.0, 2.0),
        Dim::Three => (1.5, 3.0),
    };
    w0 * (robots.max(1) as f64 / 16.0).powf(1.0 / d)
}

/// The default team of `robots` in a cube of half-width `half`.
fn team_in(dim: Dim, robots: usize, half: f64) -> Team {
    Team { workspace: Workspace::centred(half), ..Team::default_for(dim, robots) }.resolved_for_workspace()
}

/// How far a pillar of `radius` is moved from its place on each axis at
/// most ([`Scene::pillar`]): a tenth of its radius.
fn pillar_jitter(radius: f64) -> f64 {
    0.1 * radius
}

/// How far the outer columns of [`Scene::block`]'s square of `count`
/// robots `pitch` apart lie from its middle (m).
fn block_half_width(count: usize, pitch: f64) -> f64 {
    ((count as f64).sqrt().ceil() - 1.0) / 2.0 * pitch
}

/// A 2D or 3D point.
fn point(dim: Dim, x: f64, y: f64, z: f64) -> Vector3<f64> {
    Vector3::new(x, y, if dim == Dim::Three { z } else { 0.0 })
}

impl Scene {
    /// A scene of `family` with no random obstacles, from rest.
    pub fn new(family: Family, dim: Dim, robots: usize, seed: u64) -> Self {
        Self { family, dim, robots, seed, obstacles: 0, obstacle_speed: 0.0, start_speed: 0.0 }
    }

    /// The random instances of `team` with this scene's options.
    fn random(&self, team: Team) -> RandomScenario {
        RandomScenario::new(team)
            .with_obstacles(self.obstacles)
            .with_obstacle_speed(self.obstacle_speed)
            .with_start_speed(self.start_speed)
    }

    /// The problem and its parameters.
    pub fn generate(&self) -> Result<(Problem, SceneParams), ScenarioError> {
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let w = density_half_width(self.dim, self.robots);
        let (problem, radius) = match self.family {
            Family::Random => (self.random(Team::default_for(self.dim, self.robots)).generate(self.seed)?, 0.0),
            Family::Crowd => (self.random(team_in(self.dim, self.robots, w)).generate(self.seed)?, 0.0),
            Family::Swap => self.swap(w, &mut rng)?,
            Family::Crossing => (self.crossing(w, &mut rng)?, 0.0),
            Family::ObstacleField => (self.obstacle_field(w, &mut rng)?, 0.0),
            Family::Formation => (self.formation(w, &mut rng)?, 0.0),
            Family::Doorway => (self.doorway(w, &mut rng)?, 0.0),
            Family::Aisles => (self.aisles(w, &mut rng)?, 0.0),
            Family::PillarForest => (self.pillar_forest(w, &mut rng)?, 0.0),
        };
        problem.validate()?;
        let params = SceneParams {
            family: self.family,
            dim: self.dim.axes(),
            robots: self.robots,
            seed: self.seed,
            half_width: problem.team.workspace.max.x,
            obstacles: problem.obstacles.len(),
            radius,
        };
        Ok((problem, params))
    }

    /// The antipodal swap, rotated by a seeded angle, on the smallest
    /// circle or sphere (at least 90% of the density half-width) where
    /// neighbours keep [`SPACING`] separations.
    fn swap(&self, w: f64, rng: &mut ChaCha8Rng) -> Result<(Problem, f64), ScenarioError> {
        let (dim, n) = (self.dim, self.robots);
        let turn = rng.random_range(0.0..std::f64::consts::TAU);
        let mut radius = 0.9 * w;
        loop {
            let team = team_in(dim, n, radius / 0.9);
            let (a, b) = team.separation();
            let offsets: Vec<Vector3<f64>> = (0..n).map(|i| ring_point(dim, i, n, turn) * radius).collect();
            let spaced = (0..n).all(|i| {
                (i + 1..n).all(|j| crate::problem::scaled_norm(dim, &(offsets[i] - offsets[j]), a, b) >= SPACING)
            });
            if spaced {
                let problem = Problem {
                    starts: offsets.iter().map(|o| StartState::at_rest(*o)).collect(),
                    goals: offsets.iter().map(|o| -o).collect(),
                    team,
                    obstacles: Vec::new(),
                };
                return Ok((problem, radius));
            }
            radius *= 1.05;
        }
    }

    /// Places for `count` robots in a block of columns along `across`
    /// (rows along the other horizontal axis and, in 3D, layers in z)
    /// centred at `centre`, with a seeded jitter of a tenth of a separation.
    fn block(&self, count: usize, centre: Vector3<f64>, across: usize, rng: &mut ChaCha8Rng) -> Vec<Vector3<f64>> {
        if count == 0 {
            return Vec::new();
        }
        let team = Team::default_for(self.dim, 1);
        let (a, b) = team.separation();
        let (pitch, lift) = (SPACING * a, SPACING * b);
        let layers = if self.dim == Dim::Three { (count as f64).cbrt().ceil() as usize } else { 1 };
        let per_layer = count.div_ceil(layers);
        let cols = (per_layer as f64).sqrt().ceil() as usize;
        let rows = per_layer.div_ceil(cols);
        (0..count)
            .map(|k| {
                let (layer, rest) = (k / per_layer, k % per_layer);
                let (c, r) = ((rest % cols) as f64, (rest / cols) as f64);
                let u = (c - (cols - 1) as f64 / 2.0) * pitch;
                let v = (r - (rows - 1) as f64 / 2.0) * pitch;
                let z = (layer as f64 - (layers - 1) as f64 / 2.0) * lift;
                let jitter = |rng: &mut ChaCha8Rng| rng.random_range(-0.05..=0.05) * a;
                let (x, y) = if across == 0 { (u, v) } else { (v, u) };
                centre + point(self.dim, x + jitter(rng), y + jitter(rng), z)
            })
            .collect()
    }

    /// Two groups crossing at right angles: one from the left going right,
    /// one from the bottom going up, both through the middle.
    fn crossing(&self, w: f64, rng: &mut ChaCha8Rng) -> Result<Problem, ScenarioError> {
        let (dim, n) = (self.dim, self.robots);
        let half = n / 2;
        let team = team_in(dim, n, w);
        // Far enough out that the two blocks keep clear of each other.
        let pitch = SPACING * team.separation().0;
        let extent = block_half_width(half, pitch);
        let off = (0.55 * w).max(2.0 * extent + pitch);
        let mut starts = self.block(half, point(dim, -off, 0.0, 0.0), 0, rng);
        let mut goals: Vec<Vector3<f64>> = starts.iter().map(|p| point(dim, p.x + 2.0 * off, p.y, p.z)).collect();
        let up = self.block(n - half, point(dim, 0.0, -off, 0.0), 1, rng);
        goals.extend(up.iter().map(|p| point(dim, p.x, p.y + 2.0 * off, p.z)));
        starts.extend(up);
        fit(team, starts, goals, Vec::new())
    }

    /// Two groups in counterflow through a seeded field of pillars in the
    /// middle third.
    fn obstacle_field(&self, w: f64, rng: &mut ChaCha8Rng) -> Result<Problem, ScenarioError> {
        let (dim, n) = (self.dim, self.robots);
        let half = n / 2;
        let team = team_in(dim, n, w);
        // A staggered field of pillars, PILLAR_PITCH apart: the passages
        // between two pillars are wider than a robot with room to spare.
        let pillars = ((3 * n).div_ceil(4)).clamp(1, MAX_PILLARS);
        let cols = ((pillars as f64) / 2.0).sqrt().ceil() as usize;
        let rows = pillars.div_ceil(cols);
        let centre = |k: usize| {
            let (c, r) = ((k % cols) as f64, (k / cols) as f64);
            let stagger = if (k / cols) % 2 == 1 { PILLAR_PITCH / 2.0 } else { 0.0 };
            let x = (c - (cols - 1) as f64 / 2.0) * PILLAR_PITCH + stagger - PILLAR_PITCH / 4.0;
            let y = (r - (rows - 1) as f64 / 2.0) * PILLAR_PITCH;
            (x, y)
        };
        let field = (0..pillars).map(|k| centre(k).0.abs()).fold(0.0, f64::max) + PILLAR_RADIUS;
        // The groups start clear of the field, facing each other across it.
        let pitch = SPACING * team.separation().0;
        let extent = block_half_width(n - half, pitch);
        let off = (0.7 * w).max(field + team.robot.radius + 0.05 + extent + pitch / 2.0);
        let mut starts = self.block(half, point(dim, -off, 0.0, 0.0), 1, rng);
        let right = self.block(n - half, point(dim, off, 0.0, 0.0), 1, rng);
        let mut goals: Vec<Vector3<f64>> = right.clone();
        goals.extend(starts.iter().copied());
        starts.extend(right);
        let obstacles = (0..pillars)
            .map(|k| {
                let (x, y) = centre(k);
                self.pillar(x, y, PILLAR_RADIUS, w, rng)
            })
            .collect();
        fit(team, starts, goals, obstacles)
    }

    /// A [`Self::column`] of `radius` at `(x, y)` moved by up to
    /// [`pillar_jitter`] on each axis (seeded).
    fn pillar(&self, x: f64, y: f64, radius: f64, w: f64, rng: &mut ChaCha8Rng) -> Obstacle {
        let jitter = pillar_jitter(radius);
        let (x, y) = (x + rng.random_range(-jitter..=jitter), y + rng.random_range(-jitter..=jitter));
        self.column(x, y, radius, w)
    }

    /// A static column of `radius` at `(x, y)` (a disc in 2D), as tall as
    /// the workspace of half-width `w` in 3D.
    fn column(&self, x: f64, y: f64, radius: f64, w: f64) -> Obstacle {
        Obstacle {
            position: point(self.dim, x, y, 0.0),
            velocity: Vector3::zeros(),
            shape: Spheroid { radius, half_height: 2.0 * w },
        }
    }

    /// From a grid in the middle to a ring (sphere) around it, each robot
    /// to a seeded place.
    fn formation(&self, w: f64, rng: &mut ChaCha8Rng) -> Result<Problem, ScenarioError> {
        let (dim, n) = (self.dim, self.robots);
        let team = team_in(dim, n, w);
        let (a, _) = team.separation();
        let starts = self.block(n, Vector3::zeros(), 0, rng);
        let radius = (0.8 * w).max(n as f64 * SPACING * a / std::f64::consts::TAU);
        let mut goals: Vec<Vector3<f64>> = (0..n).map(|i| ring_point(dim, i, n, 0.0) * radius).collect();
        goals.shuffle(rng);
        fit(team, starts, goals, Vec::new())
    }
}

/// The problem of `team` from rest at `starts` to `goals` among
/// `obstacles`, its workspace grown (if needed) to hold every start and
/// goal with half a separation to spare.
fn fit(
    mut team: Team,
    starts: Vec<Vector3<f64>>,
    goals: Vec<Vector3<f64>>,
    obstacles: Vec<Obstacle>,
) -> Result<Problem, ScenarioError> {
    let reach =
        starts.iter().chain(&goals).flat_map(|p| (0..team.dim.axes()).map(move |a| p[a].abs())).fold(0.0, f64::max);
    let half = team.workspace.max.x.max(reach + team.robot.radius);
    team.workspace = Workspace::centred(half);
    Ok(Problem { team, starts: starts.into_iter().map(StartState::at_rest).collect(), goals, obstacles })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_family_generates_valid_seeded_scenes_that_grow_with_the_team() {
        for dim in [Dim::Two, Dim::Three] {
            for family in Family::ALL {
                for robots in [8, 16, 64] {
                    if family == Family::Random && robots > 32 {
                        // The default box does not grow: that is the crowd.
                        continue;
                    }
                    let scene = Scene::new(family, dim, robots, 3);
                    let (problem, params) = scene.generate().unwrap();
                    assert_eq!((problem.robots(), params.robots, params.family), (robots, robots, family));
                    assert_eq!(scene.generate().unwrap().0, problem, "{family:?} is seeded");
                    if family != Family::Random {
                        assert!(params.half_width >= 0.99 * density_half_width(dim, robots), "{family:?}");
                    }
                }
            }
        }
        let (field, params) = Scene::new(Family::ObstacleField, Dim::Two, 16, 0).generate().unwrap();
        assert_eq!((field.obstacles.len(), params.obstacles), (12, 12));
        let (swap, _) = Scene::new(Family::Swap, Dim::Two, 16, 0).generate().unwrap();
        assert!(swap.starts.iter().zip(&swap.goals).all(|(s, g)| (s.position + g).norm() < 1e-12), "antipodal");
    }
}
