//! The clutter families: a lab's narrow passages, warehouse aisles and
//! pillar forests, at lab densities (passages of 1.5-2.5 robot diameters
//! between obstacle surfaces, seeded per scene).
//!
//! Obstacles are the problem's spheroids: a wall or a shelf is a row of
//! overlapping discs (columns in 3D, as tall as the workspace), through
//! which no robot fits.

use nalgebra::Vector3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::{Family, SPACING, Scene, block_half_width, fit, pillar_jitter, point, team_in};
use crate::problem::{Obstacle, Problem, Team, scaled_norm};
use crate::scenario::ScenarioError;

/// Radius of the discs walls and shelves are made of (m).
const WALL_RADIUS: f64 = 0.08;
/// Distance between neighbouring discs of a wall, in disc radii: they
/// overlap, and the gap a robot would need between two is never there.
const WALL_PITCH: f64 = 1.6;
/// Radius of a forest's pillars (m).
const FOREST_PILLAR_RADIUS: f64 = 0.08;
/// The narrowest and widest passage, in robot diameters.
const PASSAGE: (f64, f64) = (1.5, 2.5);
/// Room a start or goal keeps from an obstacle's surface beyond touching,
/// in robot radii.
const CLEARANCE: f64 = 0.5;
/// Draws of a free place before a scene is declared too dense.
const DRAWS: usize = 20_000;
/// The smallest team of a clutter scene: below, the rooms and aisles of a
/// workspace at the benchmark's density are narrower than the passages.
pub const MIN_ROBOTS: usize = 8;

/// A seeded passage width between obstacle surfaces (m).
fn passage(team: &Team, rng: &mut ChaCha8Rng) -> f64 {
    rng.random_range(PASSAGE.0..=PASSAGE.1) * team.separation().0
}

/// The discs of a wall along y at `x` from `y0` to `y1` (disc centres;
/// nothing when the segment is empty).
fn wall_y(scene: &Scene, x: f64, y0: f64, y1: f64, w: f64) -> Vec<Obstacle> {
    if y1 < y0 {
        return Vec::new();
    }
    let count = ((y1 - y0) / (WALL_PITCH * WALL_RADIUS)).ceil() as usize + 1;
    (0..count)
        .map(|k| {
            let y = if count == 1 { y0 } else { y0 + (y1 - y0) * k as f64 / (count - 1) as f64 };
            scene.column(x, y, WALL_RADIUS, w)
        })
        .collect()
}

/// `count` seeded places inside the workspace of `team`, clear of
/// `obstacles` and [`SPACING`] separations apart, each accepted by `keep`
/// (given its index).
fn free_places(
    team: &Team,
    obstacles: &[Obstacle],
    count: usize,
    what: &'static str,
    rng: &mut ChaCha8Rng,
    keep: impl Fn(usize, &Vector3<f64>) -> bool,
) -> Result<Vec<Vector3<f64>>, ScenarioError> {
    let (dim, (a, b)) = (team.dim, team.separation());
    let r = team.robot.radius;
    let (lo, hi) = (team.workspace.min, team.workspace.max);
    let mut places: Vec<Vector3<f64>> = Vec::with_capacity(count);
    for index in 0..count {
        let mut found = None;
        for _ in 0..DRAWS {
            let mut p = Vector3::zeros();
            for axis in 0..dim.axes() {
                let inset = if axis == 2 { team.robot.half_height } else { r };
                p[axis] = rng.random_range(lo[axis] + inset..=hi[axis] - inset);
            }
            let clear = obstacles.iter().all(|o| {
                let (ao, bo) = team.obstacle_separation(&o.shape);
                let grow = 1.0 + CLEARANCE * r / ao;
                scaled_norm(dim, &(p - o.position), ao * grow, bo * grow) >= 1.0
            });
            let spaced = places.iter().all(|q| scaled_norm(dim, &(p - q), a, b) >= SPACING);
            if clear && spaced && keep(index, &p) {
                found = Some(p);
                break;
            }
        }
        places.push(found.ok_or(ScenarioError::TooDense { what, index })?);
    }
    Ok(places)
}

impl Scene {
    /// [`ScenarioError::TooFewRobots`] below [`MIN_ROBOTS`].
    fn enough_for_clutter(&self, family: Family) -> Result<(), ScenarioError> {
        if self.robots < MIN_ROBOTS {
            return Err(ScenarioError::TooFewRobots { family: family.name(), least: MIN_ROBOTS });
        }
        Ok(())
    }

    /// Two rooms and the wall between them, with one or two doors (seeded):
    /// the two halves of the team swap rooms, each robot to the mirror of
    /// its start across the wall.
    pub(super) fn doorway(&self, w: f64, rng: &mut ChaCha8Rng) -> Result<Problem, ScenarioError> {
        self.enough_for_clutter(Family::Doorway)?;
        let (dim, n) = (self.dim, self.robots);
        let half = n / 2;
        let team = team_in(dim, n, w);
        let pitch = SPACING * team.separation().0;
        let extent = block_half_width(n - half, pitch);
        let off = (0.55 * w).max(extent + WALL_RADIUS + team.robot.radius * (2.0 + CLEARANCE));
        let mut starts = self.block(half, point(dim, -off, 0.0, 0.0), 1, rng);
        let right = self.block(n - half, point(dim, off, 0.0, 0.0), 1, rng);
        let mirror = |p: &Vector3<f64>| Vector3::new(-p.x, p.y, p.z);
        let mut goals: Vec<Vector3<f64>> = starts.iter().map(mirror).collect();
        goals.extend(right.iter().map(mirror));
        starts.extend(right);
        let mut problem = fit(team, starts, goals, Vec::new())?;
        // The wall spans the workspace as it was fitted to the robots.
        let w = problem.team.workspace.max.y;
        let widths = [passage(&problem.team, rng), passage(&problem.team, rng)];
        let two = rng.random_bool(0.5) && w > 0.9;
        let gaps: Vec<(f64, f64)> = if two {
            let centres = widths.map(|width| (width / 2.0 + 2.0 * WALL_RADIUS).max(rng.random_range(0.35..=0.55) * w));
            vec![
                (-centres[0] - widths[0] / 2.0 - WALL_RADIUS, -centres[0] + widths[0] / 2.0 + WALL_RADIUS),
                (centres[1] - widths[1] / 2.0 - WALL_RADIUS, centres[1] + widths[1] / 2.0 + WALL_RADIUS),
            ]
        } else {
            let centre = rng.random_range(-0.3..=0.3) * w;
            vec![(centre - widths[0] / 2.0 - WALL_RADIUS, centre + widths[0] / 2.0 + WALL_RADIUS)]
        };
        let mut from = -w;
        for (below, above) in &gaps {
            problem.obstacles.extend(wall_y(self, 0.0, from, *below, w));
            from = *above;
        }
        problem.obstacles.extend(wall_y(self, 0.0, from, w, w));
        Ok(problem)
    }

    /// Warehouse aisles: two to four shelves (rows of discs along x,
    /// seeded) with aisles between them and cross-aisles as wide at both
    /// ends; each robot goes from a seeded place to one in another aisle
    /// (or beyond the outer shelves), or to one in a cross-aisle.
    pub(super) fn aisles(&self, w: f64, rng: &mut ChaCha8Rng) -> Result<Problem, ScenarioError> {
        self.enough_for_clutter(Family::Aisles)?;
        let (dim, n) = (self.dim, self.robots);
        // Shelves take room: the workspace is 15% wider than the
        // density's.
        let w = 1.15 * w;
        let team = team_in(dim, n, w);
        let aisle = passage(&team, rng);
        let shelf_pitch = aisle + 2.0 * WALL_RADIUS;
        let shelves = ((2.0 * w / shelf_pitch) as usize).saturating_sub(1).clamp(2, 4);
        // Cross-aisles as wide as the aisles at both ends.
        let length = (w - aisle - WALL_RADIUS).max(WALL_RADIUS);
        let mut obstacles = Vec::new();
        let shelf_y = |s: usize| (s as f64 - (shelves - 1) as f64 / 2.0) * shelf_pitch;
        for s in 0..shelves {
            let y = shelf_y(s);
            let count = (2.0 * length / (WALL_PITCH * WALL_RADIUS)).ceil() as usize + 1;
            for k in 0..count {
                let x = -length + 2.0 * length * k as f64 / (count - 1) as f64;
                obstacles.push(self.column(x, y, WALL_RADIUS, w));
            }
        }
        // The band (aisle, or beyond the outer shelves) a place is in.
        let band = |p: &Vector3<f64>| (0..shelves).filter(|&s| p.y > shelf_y(s)).count();
        let starts = free_places(&team, &obstacles, n, "start", rng, |_, _| true)?;
        let goals =
            free_places(&team, &obstacles, n, "goal", rng, |i, p| band(p) != band(&starts[i]) || p.x.abs() > length)?;
        Ok(Problem {
            team,
            starts: starts.into_iter().map(crate::problem::StartState::at_rest).collect(),
            goals,
            obstacles,
        })
    }

    /// A pillar forest: pillars on a jittered square grid over the whole
    /// workspace with passages of 1.5-2.5 robot diameters between them
    /// (seeded; up to 0.16 diameters wider with the jitter, and the strips
    /// between the outer pillars and the workspace's sides from half a
    /// passage up), robots from seeded places to seeded places among them
    /// at least a half-width away; the team at the resolution for its
    /// pillars ([`Team::resolved_for_obstacles`]).
    pub(super) fn pillar_forest(&self, w: f64, rng: &mut ChaCha8Rng) -> Result<Problem, ScenarioError> {
        self.enough_for_clutter(Family::PillarForest)?;
        let (dim, n) = (self.dim, self.robots);
        let team = team_in(dim, n, w);
        // Jittered pillars keep the passage drawn between them.
        let pitch = passage(&team, rng) + 2.0 * (FOREST_PILLAR_RADIUS + pillar_jitter(FOREST_PILLAR_RADIUS));
        let team = team.resolved_for_obstacles(pitch);
        let per_axis = ((2.0 * w / pitch) as usize).max(1);
        let mut obstacles = Vec::new();
        for i in 0..per_axis {
            for j in 0..per_axis {
                let at = |k: usize| (k as f64 - (per_axis - 1) as f64 / 2.0) * pitch;
                obstacles.push(self.pillar(at(i), at(j), FOREST_PILLAR_RADIUS, w, rng));
            }
        }
        let starts = free_places(&team, &obstacles, n, "start", rng, |_, _| true)?;
        // Goals at least half the workspace away from their starts.
        let goals = free_places(&team, &obstacles, n, "goal", rng, |i, p| (p - starts[i]).norm() >= w)?;
        Ok(Problem {
            team,
            starts: starts.into_iter().map(crate::problem::StartState::at_rest).collect(),
            goals,
            obstacles,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::Family;
    use super::*;
    use crate::problem::Dim;

    /// The narrowest free width between two obstacles of `problem` (in
    /// robot diameters), over pairs whose surfaces are apart with no third
    /// obstacle in the middle of the gap.
    fn narrowest_passage(problem: &Problem) -> f64 {
        let d = problem.team.separation().0;
        let mut narrowest = f64::INFINITY;
        for (i, o) in problem.obstacles.iter().enumerate() {
            for q in &problem.obstacles[i + 1..] {
                let apart = (q.position - o.position).xy();
                let gap = apart.norm() - o.shape.radius - q.shape.radius;
                // The middle of the gap, unless a third obstacle fills it.
                let middle = o.position.xy() + apart.normalize() * (o.shape.radius + gap / 2.0);
                let open = problem.obstacles.iter().all(|x| (x.position.xy() - middle).norm() > x.shape.radius);
                if gap > 0.0 && open {
                    narrowest = narrowest.min(gap / d);
                }
            }
        }
        narrowest
    }

    #[test]
    fn clutter_scenes_have_lab_passages_and_free_starts_and_goals() {
        for family in [Family::Doorway, Family::Aisles, Family::PillarForest] {
            for dim in [Dim::Two, Dim::Three] {
                for robots in [8, 16, 32] {
                    for seed in 0..4 {
                        let (problem, _) = Scene::new(family, dim, robots, seed).generate().unwrap();
                        assert!(!problem.obstacles.is_empty(), "{family:?}");
                        let narrowest = narrowest_passage(&problem);
                        // Passages where robots must go are 1.5-2.5
                        // diameters; wall discs leave none.
                        assert!(narrowest >= PASSAGE.0 - 1e-9, "{family:?} {robots}: {narrowest}");
                    }
                }
            }
        }
    }

    #[test]
    fn a_doorway_wall_spans_the_workspace_and_is_closed_but_for_its_doors() {
        for dim in [Dim::Two, Dim::Three] {
            for seed in 0..8 {
                let (problem, _) = Scene::new(Family::Doorway, dim, 16, seed).generate().unwrap();
                let (d, w) = (problem.team.separation().0, problem.team.workspace.max.y);
                let mut ys: Vec<f64> = problem.obstacles.iter().map(|o| o.position.y).collect();
                ys.sort_by(f64::total_cmp);
                assert!(problem.obstacles.iter().all(|o| o.position.x == 0.0), "one wall");
                assert_eq!((ys[0], ys[ys.len() - 1]), (-w, w), "from side to side");
                // Along the wall, the free gaps a robot could pass are the
                // doors, 1.5-2.5 diameters each.
                let doors: Vec<f64> =
                    ys.windows(2).map(|p| (p[1] - p[0] - 2.0 * WALL_RADIUS) / d).filter(|g| *g > 0.0).collect();
                assert!((1..=2).contains(&doors.len()), "{doors:?}");
                assert!(doors.iter().all(|g| (PASSAGE.0 - 1e-9..=PASSAGE.1 + 1e-9).contains(g)), "{doors:?}");
                // Every robot crosses it.
                assert!(problem.starts.iter().zip(&problem.goals).all(|(s, g)| s.position.x * g.x < 0.0));
            }
        }
    }

    #[test]
    fn starts_and_goals_keep_their_room_from_obstacles_and_small_teams_are_refused() {
        for family in [Family::Doorway, Family::Aisles, Family::PillarForest] {
            let (problem, _) = Scene::new(family, Dim::Two, 16, 1).generate().unwrap();
            let r = problem.team.robot.radius;
            for p in problem.starts.iter().map(|s| s.position).chain(problem.goals.iter().copied()) {
                for o in &problem.obstacles {
                    let gap = (p - o.position).xy().norm() - o.shape.radius - r;
                    assert!(gap >= CLEARANCE * r - 1e-9, "{family:?}: {gap}");
                }
            }
            let small = Scene::new(family, Dim::Two, MIN_ROBOTS - 1, 1).generate();
            assert!(matches!(small, Err(ScenarioError::TooFewRobots { least: MIN_ROBOTS, .. })), "{family:?}");
        }
    }
}
