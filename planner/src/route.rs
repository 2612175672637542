//! Obstacle-aware cold starts for the from-scratch optimiser.
//!
//! The AM iterations are local: started from a straight line that crosses an
//! obstacle on the side with no room (against a wall, into a cluster), the
//! radial projection pushes the path into the next obstacle and the
//! multiplier grows without resolving it. For a robot whose straight segment
//! crosses an inflated static obstacle, [`route`] finds a shortest path
//! around the static obstacles on a grid (ignoring the other robots, which the
//! AM handles), shortens it by line-of-sight, and times it with the
//! rest-to-rest quintic profile; [`Fitter`] fits the Bernstein coefficients
//! to those samples under the boundary conditions. Moving obstacles are left
//! to the AM.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use nalgebra::Vector3;

use crate::basis::{BOUNDARY_ROWS, Basis};
use crate::kkt::{KktError, SmallKkt};
use crate::problem::{Dim, Obstacle, Team, scaled_norm};

/// Grid cells along the longest workspace side.
const CELLS: usize = 48;

/// Static obstacles inflated for routing: centre, and the robot-obstacle
/// separations `(a_o, b_o)` grown by the margin and one grid cell.
pub struct Blockers {
    dim: Dim,
    obstacles: Vec<(Vector3<f64>, f64, f64)>,
}

impl Blockers {
    /// The static obstacles of a problem, each inflated by the robot size,
    /// `margin` (relative) and `pad` metres.
    pub fn new(team: &Team, obstacles: &[Obstacle], margin: f64, pad: f64) -> Self {
        let obstacles = obstacles
            .iter()
            .filter(|o| o.velocity.norm() == 0.0)
            .map(|o| {
                let (a, b) = team.obstacle_separation(&o.shape);
                (o.position, a * (1.0 + margin) + pad, b * (1.0 + margin) + pad)
            })
            .collect();
        Self { dim: team.dim, obstacles }
    }

    /// Whether any static obstacle is left.
    pub fn is_empty(&self) -> bool {
        self.obstacles.is_empty()
    }

    /// Whether `p` is inside an inflated obstacle.
    pub fn blocks(&self, p: &Vector3<f64>) -> bool {
        self.obstacles.iter().any(|(c, a, b)| scaled_norm(self.dim, &(p - c), *a, *b) < 1.0)
    }

    /// Whether the segment `p -> q` passes through an inflated obstacle
    /// (checked every quarter of the smallest obstacle size).
    pub fn segment_blocked(&self, p: &Vector3<f64>, q: &Vector3<f64>) -> bool {
        let smallest = self.obstacles.iter().map(|(_, a, b)| a.min(*b)).fold(f64::INFINITY, f64::min);
        let steps = ((q - p).norm() / (0.25 * smallest)).ceil().max(1.0) as usize;
        (0..=steps).any(|s| self.blocks(&(p + (q - p) * (s as f64 / steps as f64))))
    }
}

/// A grid shortest path from `start` to `goal` around `blockers` within the
/// workspace, shortened by line of sight. `None` when the goal is walled off
/// on the grid.
pub fn route(team: &Team, blockers: &Blockers, start: &Vector3<f64>, goal: &Vector3<f64>) -> Option<Vec<Vector3<f64>>> {
    let axes = team.dim.axes();
    let ws = &team.workspace;
    let longest = (0..axes).map(|a| ws.max[a] - ws.min[a]).fold(0.0, f64::max);
    let cell = longest / CELLS as f64;
    let dims: Vec<usize> = (0..axes).map(|a| ((ws.max[a] - ws.min[a]) / cell).ceil() as usize + 1).collect();
    let total: usize = dims.iter().product();
    let centre = |idx: usize| -> Vector3<f64> {
        let mut p = Vector3::zeros();
        let mut rest = idx;
        for a in 0..axes {
            p[a] = (ws.min[a] + (rest % dims[a]) as f64 * cell).min(ws.max[a]);
            rest /= dims[a];
        }
        p
    };
    let index_of = |p: &Vector3<f64>| -> usize {
        let mut idx = 0;
        for a in (0..axes).rev() {
            let i = (((p[a] - ws.min[a]) / cell).round().max(0.0) as usize).min(dims[a] - 1);
            idx = idx * dims[a] + i;
        }
        idx
    };
    let from = index_of(start);
    let to = index_of(goal);
    let free: Vec<bool> = (0..total).map(|i| i == from || i == to || !blockers.blocks(&centre(i))).collect();
    // Dijkstra over the 8- (2D) or 26- (3D) neighbourhood.
    let offsets: Vec<Vec<i64>> = neighbour_offsets(axes);
    let mut dist = vec![f64::INFINITY; total];
    let mut prev = vec![usize::MAX; total];
    let mut heap = BinaryHeap::new();
    dist[from] = 0.0;
    heap.push(Reverse((Ordered(0.0), from)));
    while let Some(Reverse((Ordered(d), u))) = heap.pop() {
        if u == to {
            break;
        }
        if d > dist[u] {
            continue;
        }
        let mut coord = [0i64; 3];
        let mut rest = u;
        for a in 0..axes {
            coord[a] = (rest % dims[a]) as i64;
            rest /= dims[a];
        }
        for off in &offsets {
            let mut v = 0usize;
            let mut inside = true;
            for a in (0..axes).rev() {
                let c = coord[a] + off[a];
                if c < 0 || c >= dims[a] as i64 {
                    inside = false;
                    break;
                }
                v = v * dims[a] + c as usize;
            }
            if !inside || !free[v] {
                continue;
            }
            let step = off.iter().map(|o| (o * o) as f64).sum::<f64>().sqrt() * cell;
            if d + step < dist[v] {
                dist[v] = d + step;
                prev[v] = u;
                heap.push(Reverse((Ordered(d + step), v)));
            }
        }
    }
    if !dist[to].is_finite() {
        return None;
    }
    let mut cells = vec![to];
    while let Some(&last) = cells.last() {
        if last == from {
            break;
        }
        cells.push(prev[last]);
    }
    cells.reverse();
    let mut raw: Vec<Vector3<f64>> = cells.iter().map(|&c| centre(c)).collect();
    raw[0] = *start;
    if let Some(last) = raw.last_mut() {
        *last = *goal;
    }
    // Line-of-sight shortening.
    let mut path = vec![raw[0]];
    let mut at = 0;
    while at + 1 < raw.len() {
        let mut next = at + 1;
        for j in (at + 2..raw.len()).rev() {
            if !blockers.segment_blocked(&raw[at], &raw[j]) {
                next = j;
                break;
            }
        }
        path.push(raw[next]);
        at = next;
    }
    Some(path)
}

fn neighbour_offsets(axes: usize) -> Vec<Vec<i64>> {
    let mut out = Vec::new();
    let count = 3usize.pow(axes as u32);
    for code in 0..count {
        let mut rest = code;
        let off: Vec<i64> = (0..axes)
            .map(|_| {
                let v = (rest % 3) as i64 - 1;
                rest /= 3;
                v
            })
            .collect();
        if off.iter().any(|&v| v != 0) {
            out.push(off);
        }
    }
    out
}

/// Total order on the distances of the search.
#[derive(Debug, Clone, Copy)]
struct Ordered(f64);
impl PartialEq for Ordered {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other).is_eq()
    }
}
impl Eq for Ordered {}
impl PartialOrd for Ordered {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Ordered {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&other.0)
    }
}

/// The point at arc-length fraction `s` in `[0, 1]` along a polyline.
fn along(path: &[Vector3<f64>], s: f64) -> Vector3<f64> {
    let lengths: Vec<f64> = path.windows(2).map(|w| (w[1] - w[0]).norm()).collect();
    let total: f64 = lengths.iter().sum();
    let mut left = s.clamp(0.0, 1.0) * total;
    for (w, len) in path.windows(2).zip(&lengths) {
        if left <= *len && *len > 0.0 {
            return w[0] + (w[1] - w[0]) * (left / len);
        }
        left -= len;
    }
    path[path.len() - 1]
}

/// Least-squares fit of Bernstein coefficients to sampled positions under
/// the boundary conditions: `min sum_k (P_k xi - q_k)^2  s.t.  A_1 xi = b`.
#[derive(Debug, Clone)]
pub struct Fitter {
    kkt: SmallKkt,
    p: Vec<f64>,
    n_xi: usize,
    samples: usize,
}

impl Fitter {
    /// The fitter for `basis`.
    pub fn new(basis: &Basis) -> Result<Self, KktError> {
        Ok(Self {
            kkt: SmallKkt::new(&basis.gram(0), &basis.boundary_rows(), basis.n_xi())?,
            p: basis.position().to_vec(),
            n_xi: basis.n_xi(),
            samples: basis.samples(),
        })
    }

    /// Coefficients of one axis fitted to `q` (one value per sample) with
    /// boundary values `b` (normalised time).
    pub fn fit(&self, q: &[f64], b: &[f64], out: &mut [f64]) {
        debug_assert_eq!(b.len(), BOUNDARY_ROWS);
        let mut r = vec![0.0; self.n_xi];
        for (k, &qk) in q.iter().enumerate().take(self.samples) {
            for (c, rv) in r.iter_mut().enumerate() {
                *rv += self.p[k * self.n_xi + c] * qk;
            }
        }
        self.kkt.apply(&r, b, out);
    }

    /// Samples along `path` at the basis instants with the rest-to-rest
    /// quintic timing `s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5`: one series
    /// per axis.
    pub fn timed_samples(&self, path: &[Vector3<f64>], axes: usize) -> Vec<Vec<f64>> {
        let mut series = vec![vec![0.0; self.samples]; axes];
        for k in 0..self.samples {
            let tau = k as f64 / (self.samples - 1) as f64;
            let s = tau * tau * tau * (10.0 - 15.0 * tau + 6.0 * tau * tau);
            let p = along(path, s);
            for (a, ser) in series.iter_mut().enumerate() {
                ser[k] = p[a];
            }
        }
        series
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::problem::Spheroid;

    #[test]
    fn a_blocked_straight_line_is_routed_around_the_obstacle() {
        let team = Team::default_for(Dim::Two, 1);
        let wall =
            Obstacle { position: Vector3::new(0.0, 0.0, 0.0), velocity: Vector3::zeros(), shape: Spheroid::ball(0.3) };
        let blockers = Blockers::new(&team, &[wall], 0.05, 0.0);
        let (start, goal) = (Vector3::new(-0.8, 0.01, 0.0), Vector3::new(0.8, 0.01, 0.0));
        assert!(blockers.segment_blocked(&start, &goal));
        let path = route(&team, &blockers, &start, &goal).unwrap();
        assert!(path.len() >= 3);
        for w in path.windows(2) {
            assert!(!blockers.segment_blocked(&w[0], &w[1]), "segment {:?} -> {:?}", w[0], w[1]);
        }
        assert_eq!((path[0], path[path.len() - 1]), (start, goal));
    }

    #[test]
    fn a_walled_off_goal_has_no_route() {
        let team = Team::default_for(Dim::Two, 1);
        // A ring of obstacles around the goal.
        let ring: Vec<Obstacle> = (0..12)
            .map(|i| {
                let a = std::f64::consts::TAU * i as f64 / 12.0;
                Obstacle {
                    position: Vector3::new(0.5 + 0.4 * a.cos(), 0.4 * a.sin(), 0.0),
                    velocity: Vector3::zeros(),
                    shape: Spheroid::ball(0.15),
                }
            })
            .collect();
        let blockers = Blockers::new(&team, &ring, 0.05, 0.0);
        assert!(route(&team, &blockers, &Vector3::new(-0.8, 0.0, 0.0), &Vector3::new(0.5, 0.0, 0.0)).is_none());
    }

    #[test]
    fn fitting_meets_the_boundary_and_follows_a_straight_path() {
        let basis = Basis::new(10, 50).unwrap();
        let fitter = Fitter::new(&basis).unwrap();
        let path = [Vector3::new(0.0, 0.0, 0.0), Vector3::new(1.0, 0.0, 0.0)];
        let q = fitter.timed_samples(&path, 2);
        let mut xi = vec![0.0; 11];
        fitter.fit(&q[0], &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0], &mut xi);
        assert!((xi[0]).abs() < 1e-12 && (xi[10] - 1.0).abs() < 1e-12);
        // The quintic profile is a degree-5 polynomial: fitted exactly.
        for (k, &qk) in q[0].iter().enumerate() {
            let p: f64 = basis.position_row(k).iter().zip(&xi).map(|(a, b)| a * b).sum();
            assert!((p - qk).abs() < 1e-9);
        }
    }
}
