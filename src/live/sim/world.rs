//! The simulated lab's obstacles: static ones that appear and moving ones
//! that cross the workspace, each present over a window of the run. The
//! controller reports the present ones in every snapshot, at their
//! positions then and with their velocities.

use flowopt_client::Followed;
use flowopt_planner::problem::{Obstacle, Spheroid, Team};
use nalgebra::Vector3;

/// Radius of the simulated obstacles (m): a person's leg, a stool.
pub const RADIUS: f64 = 0.1;
/// Speed of a crossing obstacle (m/s): a person walking slowly.
pub const WALKING_SPEED: f64 = 0.4;
/// How far ahead on a moving robot's plan an appearing obstacle is put (s).
const AHEAD_S: f64 = 1.2;
/// How far an appearing obstacle stays from every robot and goal (m).
const KEEP_CLEAR: f64 = 0.35;

/// An obstacle over a window of the run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimObstacle {
    /// Where it is at `from_s`.
    pub position: Vector3<f64>,
    /// Its constant velocity (m/s).
    pub velocity: Vector3<f64>,
    /// Seconds into the run it appears.
    pub from_s: f64,
    /// Seconds into the run it is gone.
    pub until_s: f64,
}

impl SimObstacle {
    /// Whether it is there `t` s into the run.
    pub fn present(&self, t: f64) -> bool {
        t >= self.from_s && t < self.until_s
    }

    /// It as the planner sees it `t` s into the run.
    pub fn at(&self, t: f64) -> Obstacle {
        Obstacle {
            position: self.position + self.velocity * (t - self.from_s),
            velocity: self.velocity,
            shape: Spheroid::ball(RADIUS),
        }
    }
}

/// The obstacles of a run.
#[derive(Debug, Clone, Default)]
pub struct World {
    obstacles: Vec<SimObstacle>,
}

impl World {
    /// Adds `obstacle`.
    pub fn add(&mut self, obstacle: SimObstacle) {
        self.obstacles.push(obstacle);
    }

    /// The obstacles present `t` s into the run, as reported then.
    pub fn present(&self, t: f64) -> Vec<Obstacle> {
        self.obstacles.iter().filter(|o| o.present(t)).map(|o| o.at(t)).collect()
    }

    /// Whether `p` is at least `clearance` (m, beyond the obstacle's
    /// radius) from every obstacle present `t` s into the run.
    pub fn clear_of(&self, t: f64, p: &Vector3<f64>, clearance: f64) -> bool {
        self.present(t).iter().all(|o| (o.position - p).xy().norm() >= RADIUS + clearance)
    }
}

/// Where to put an obstacle ahead of the moving robots: on the followed
/// plan of the fastest robot whose position `AHEAD_S` ahead is at least
/// `KEEP_CLEAR` from every robot now and every goal; `None` if none is.
pub fn ahead_of_moving(
    followed: &Followed,
    now_ns: u64,
    positions: &[Vector3<f64>],
    velocities: &[Vector3<f64>],
    goals: &[Vector3<f64>],
) -> Option<Vector3<f64>> {
    let ahead = followed.at(now_ns + (AHEAD_S * 1e9) as u64);
    let mut order: Vec<usize> = (0..positions.len()).collect();
    order.sort_by(|&a, &b| velocities[b].norm().total_cmp(&velocities[a].norm()));
    order
        .into_iter()
        .filter(|&i| velocities[i].norm() > 0.1)
        .map(|i| ahead[i].position)
        .find(|p| positions.iter().chain(goals).all(|q| (q - p).xy().norm() >= KEEP_CLEAR + RADIUS))
}

/// An obstacle that walks across `team`'s workspace at [`WALKING_SPEED`]
/// along x, through `through` (the team's centre), from `t` s into the run
/// until it has left the box.
pub fn crossing(team: &Team, through: Vector3<f64>, t: f64) -> SimObstacle {
    let (lo, hi) = (team.workspace.min.x - RADIUS, team.workspace.max.x + RADIUS);
    SimObstacle {
        position: Vector3::new(lo, through.y, 0.0),
        velocity: Vector3::new(WALKING_SPEED, 0.0, 0.0),
        from_s: t,
        until_s: t + (hi - lo) / WALKING_SPEED,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_planner::problem::Dim;

    #[test]
    fn a_crossing_obstacle_is_present_while_it_crosses_and_moves_at_walking_speed() {
        let team = Team::default_for(Dim::Two, 4);
        let o = crossing(&team, Vector3::new(0.0, 0.3, 0.0), 10.0);
        let mut world = World::default();
        world.add(o);
        assert!(world.present(9.9).is_empty());
        let mid = world.present(10.0 + 1.1 / WALKING_SPEED);
        assert_eq!(mid.len(), 1);
        assert!((mid[0].position - Vector3::new(0.0, 0.3, 0.0)).norm() < 1e-9);
        assert!(world.present(o.until_s).is_empty());
        assert!(!world.clear_of(10.0 + 1.1 / WALKING_SPEED, &Vector3::new(0.05, 0.3, 0.0), 0.0));
    }
}
