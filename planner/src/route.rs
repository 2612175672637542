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
use std::sync::OnceLock;

use nalgebra::Vector3;

use crate::basis::{BOUNDARY_ROWS, Basis};
use crate::kkt::{KktError, SmallKkt};
use crate::problem::{Dim, Obstacle, Team, scaled_norm};

/// Grid cells along the longest workspace side.
const CELLS: usize = 48;

/// Points along a path [`Blockers::narrowest`] reads.
const NARROWEST_READS: usize = 64;

/// Static obstacles inflated for routing: centre, and the robot-obstacle
/// separations `(a_o, b_o)` grown by the margin and one grid cell; with the
/// routing grid of the team they were built for.
pub struct Blockers {
    dim: Dim,
    obstacles: Vec<(Vector3<f64>, f64, f64)>,
    grid: Grid,
    /// Per grid cell, whether its centre is outside every obstacle: built
    /// by the first [`route`] and shared by the later ones (in 3D a grid of
    /// 10^5 cells, most of a route's time when built per route).
    free: OnceLock<Vec<bool>>,
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
        Self { dim: team.dim, obstacles, grid: Grid::new(team), free: OnceLock::new() }
    }

    /// Per cell of the grid, whether its centre is outside every obstacle
    /// (as [`Self::blocks`] finds, each obstacle tested only on the cells of
    /// its bounding box, the others being outside it).
    fn free_cells(&self) -> Vec<bool> {
        let grid = &self.grid;
        let mut free = vec![true; grid.total];
        for &(c, a, b) in &self.obstacles {
            let mut low = [0usize; 3];
            let mut high = [0usize; 3];
            for axis in 0..grid.axes {
                let half = if axis == 2 { b } else { a };
                let cell = |x: f64| ((x - grid.min[axis]) / grid.cell).clamp(0.0, (grid.dims[axis] - 1) as f64);
                low[axis] = cell(c[axis] - half).floor() as usize;
                high[axis] = cell(c[axis] + half).ceil() as usize;
            }
            for k in low[2]..=high[2] {
                for j in low[1]..=high[1] {
                    for i in low[0]..=high[0] {
                        let idx = (k * grid.dims[1] + j) * grid.dims[0] + i;
                        if free[idx] && self.inside(&grid.centre(idx), &c, a, b) {
                            free[idx] = false;
                        }
                    }
                }
            }
        }
        free
    }

    /// Whether any static obstacle is left.
    pub fn is_empty(&self) -> bool {
        self.obstacles.is_empty()
    }

    /// Whether `p` is inside an inflated obstacle.
    pub fn blocks(&self, p: &Vector3<f64>) -> bool {
        self.obstacles.iter().any(|(c, a, b)| self.inside(p, c, *a, *b))
    }

    /// How far `p` lies outside the nearest inflated obstacle, in that
    /// obstacle's scaled units (negative inside it; infinite with none).
    pub fn clearance(&self, p: &Vector3<f64>) -> f64 {
        self.obstacles
            .iter()
            .map(|(c, a, b)| scaled_norm(self.dim, &(p - c), *a, *b) - 1.0)
            .fold(f64::INFINITY, f64::min)
    }

    /// The arc-length fraction of `path` (in `(0, 1)`) at which it passes
    /// closest to an inflated obstacle: where robots routed through the
    /// same door or gap meet.
    pub fn narrowest(&self, path: &[Vector3<f64>]) -> f64 {
        (1..NARROWEST_READS)
            .map(|r| r as f64 / NARROWEST_READS as f64)
            .map(|s| (self.clearance(&along(path, s)), s))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map_or(0.5, |(_, s)| s)
    }

    /// Whether `p` is inside the inflated obstacle centred at `c` with
    /// separations `(a, b)`.
    fn inside(&self, p: &Vector3<f64>, c: &Vector3<f64>, a: f64, b: f64) -> bool {
        scaled_norm(self.dim, &(p - c), a, b) < 1.0
    }

    /// Whether the segment `p -> q` passes through an inflated obstacle
    /// (checked every quarter of the smallest obstacle size).
    pub fn segment_blocked(&self, p: &Vector3<f64>, q: &Vector3<f64>) -> bool {
        let smallest = self.obstacles.iter().map(|(_, a, b)| a.min(*b)).fold(f64::INFINITY, f64::min);
        let steps = ((q - p).norm() / (0.25 * smallest)).ceil().max(1.0) as usize;
        (0..=steps).any(|s| self.blocks(&(p + (q - p) * (s as f64 / steps as f64))))
    }
}

/// The routing grid: [`CELLS`] cells along the workspace's longest side.
struct Grid {
    axes: usize,
    min: Vector3<f64>,
    max: Vector3<f64>,
    cell: f64,
    dims: [usize; 3],
    total: usize,
    /// The 8 (2D) or 26 (3D) neighbours of a cell, in the search's order.
    steps: Vec<Neighbour>,
}

impl Grid {
    fn new(team: &Team) -> Self {
        let axes = team.dim.axes();
        let ws = &team.workspace;
        let longest = (0..axes).map(|a| ws.max[a] - ws.min[a]).fold(0.0, f64::max);
        let cell = longest / CELLS as f64;
        let mut dims = [1; 3];
        for (a, d) in dims.iter_mut().enumerate().take(axes) {
            *d = ((ws.max[a] - ws.min[a]) / cell).ceil() as usize + 1;
        }
        let steps = neighbours(axes, &dims);
        Self { axes, min: ws.min, max: ws.max, cell, dims, total: dims.iter().product(), steps }
    }

    /// The centre of cell `idx` (clamped to the workspace).
    fn centre(&self, idx: usize) -> Vector3<f64> {
        let mut p = Vector3::zeros();
        let mut rest = idx;
        for a in 0..self.axes {
            p[a] = (self.min[a] + (rest % self.dims[a]) as f64 * self.cell).min(self.max[a]);
            rest /= self.dims[a];
        }
        p
    }

    /// The cell nearest to `p`.
    fn index_of(&self, p: &Vector3<f64>) -> usize {
        let mut idx = 0;
        for a in (0..self.axes).rev() {
            let i = (((p[a] - self.min[a]) / self.cell).round().max(0.0) as usize).min(self.dims[a] - 1);
            idx = idx * self.dims[a] + i;
        }
        idx
    }

    /// The coordinates of cell `idx`.
    fn coordinates(&self, idx: usize) -> [usize; 3] {
        let mut coord = [0; 3];
        let mut rest = idx;
        for a in 0..self.axes {
            coord[a] = rest % self.dims[a];
            rest /= self.dims[a];
        }
        coord
    }
}

/// A neighbour of a grid cell: its offset per axis, the change of the
/// cell index, and the step's length in cells.
struct Neighbour {
    offset: [i64; 3],
    delta: i64,
    length: f64,
}

/// The 8 (2D) or 26 (3D) neighbours of a cell of a grid of `dims` cells
/// per axis, in the search's order.
fn neighbours(axes: usize, dims: &[usize; 3]) -> Vec<Neighbour> {
    let count = 3usize.pow(axes as u32);
    let mut out = Vec::with_capacity(count - 1);
    for code in 0..count {
        let mut rest = code;
        let mut offset = [0i64; 3];
        for o in offset.iter_mut().take(axes) {
            *o = (rest % 3) as i64 - 1;
            rest /= 3;
        }
        if offset.iter().all(|&v| v == 0) {
            continue;
        }
        let mut delta = 0i64;
        for a in (0..axes).rev() {
            delta = delta * dims[a] as i64 + offset[a];
        }
        let length = offset.iter().map(|o| (o * o) as f64).sum::<f64>().sqrt();
        out.push(Neighbour { offset, delta, length });
    }
    out
}

/// A shortest path from `start` to `goal` around `blockers` on the routing
/// grid of the team they were built for (within its workspace), shortened
/// by line of sight. `None` when the goal is walled off on the grid.
pub fn route(blockers: &Blockers, start: &Vector3<f64>, goal: &Vector3<f64>) -> Option<Vec<Vector3<f64>>> {
    let grid = &blockers.grid;
    let from = grid.index_of(start);
    let to = grid.index_of(goal);
    let free = blockers.free.get_or_init(|| blockers.free_cells());
    let open = |v: usize| v == from || v == to || free[v];
    // Dijkstra over the 8- (2D) or 26- (3D) neighbourhood.
    let mut dist = vec![f64::INFINITY; grid.total];
    let mut prev = vec![usize::MAX; grid.total];
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
        let coord = grid.coordinates(u);
        for step in &grid.steps {
            let inside = (0..grid.axes).all(|a| {
                let c = coord[a] as i64 + step.offset[a];
                c >= 0 && c < grid.dims[a] as i64
            });
            if !inside {
                continue;
            }
            let v = (u as i64 + step.delta) as usize;
            if !open(v) {
                continue;
            }
            let next = d + step.length * grid.cell;
            if next < dist[v] {
                dist[v] = next;
                prev[v] = u;
                heap.push(Reverse((Ordered(next), v)));
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
    let mut raw: Vec<Vector3<f64>> = cells.iter().map(|&c| grid.centre(c)).collect();
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
pub(crate) fn along(path: &[Vector3<f64>], s: f64) -> Vector3<f64> {
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

/// The rest-to-rest quintic timing: the fraction of a path covered at
/// normalised time `tau`, `10 tau^3 - 15 tau^4 + 6 tau^5`.
pub fn quintic(tau: f64) -> f64 {
    tau * tau * tau * (10.0 - 15.0 * tau + 6.0 * tau * tau)
}

/// The normalised time at which [`quintic`] covers `s` of a path.
pub fn quintic_inverse(s: f64) -> f64 {
    // The quintic rises monotonically on [0, 1]: bisection to 2^-40.
    let (mut lo, mut hi) = (0.0, 1.0);
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if quintic(mid) < s {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// A warp of a timing's clock: the timing read at `to` at normalised time
/// `at`, linearly in between from 0 and to 1 (rest at both ends is kept).
/// It moves when a robot passes a point of its path and nothing else.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Warp {
    /// When (normalised time, in `(0, 1)`).
    pub at: f64,
    /// The unwarped clock's reading then (in `(0, 1)`).
    pub to: f64,
}

impl Warp {
    /// The warped clock at `tau`.
    pub fn clock(&self, tau: f64) -> f64 {
        if tau <= self.at {
            tau / self.at * self.to
        } else {
            self.to + (tau - self.at) / (1.0 - self.at) * (1.0 - self.to)
        }
    }
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
    /// quintic timing `s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5` ([`quintic`]),
    /// its clock warped by `warp` where given: one series per axis.
    pub fn timed_samples(&self, path: &[Vector3<f64>], axes: usize, warp: Option<Warp>) -> Vec<Vec<f64>> {
        let mut series = vec![vec![0.0; self.samples]; axes];
        for k in 0..self.samples {
            let tau = k as f64 / (self.samples - 1) as f64;
            let s = quintic(warp.map_or(tau, |w| w.clock(tau)));
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
        let path = route(&blockers, &start, &goal).unwrap();
        assert!(path.len() >= 3);
        for w in path.windows(2) {
            assert!(!blockers.segment_blocked(&w[0], &w[1]), "segment {:?} -> {:?}", w[0], w[1]);
        }
        assert_eq!((path[0], path[path.len() - 1]), (start, goal));
    }

    #[test]
    fn the_free_cells_are_those_outside_every_obstacle() {
        // Obstacles of every shape, at the workspace's faces and corners
        // too, in 2D and 3D: the mask built from their bounding boxes is
        // the test of every cell.
        for dim in [Dim::Two, Dim::Three] {
            let team = Team::default_for(dim, 4);
            let (lo, hi) = (team.workspace.min, team.workspace.max);
            let mut obstacles = Vec::new();
            for (k, f) in [0.0, 0.13, 0.5, 0.77, 1.0].into_iter().enumerate() {
                let at = lo + (hi - lo) * f;
                let shape = Spheroid { radius: 0.05 + 0.07 * k as f64, half_height: 0.3 - 0.05 * k as f64 };
                obstacles.push(Obstacle { position: at, velocity: Vector3::zeros(), shape });
            }
            let blockers = Blockers::new(&team, &obstacles, 0.05, 0.02);
            let grid = &blockers.grid;
            let every: Vec<bool> = (0..grid.total).map(|i| !blockers.blocks(&grid.centre(i))).collect();
            let mask = blockers.free_cells();
            assert_eq!(mask, every, "{dim:?}");
            assert!(mask.iter().any(|f| !f), "{dim:?}: some cells are blocked");
        }
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
        assert!(route(&blockers, &Vector3::new(-0.8, 0.0, 0.0), &Vector3::new(0.5, 0.0, 0.0)).is_none());
    }

    #[test]
    fn fitting_meets_the_boundary_and_follows_a_straight_path() {
        let basis = Basis::new(10, 50).unwrap();
        let fitter = Fitter::new(&basis).unwrap();
        let path = [Vector3::new(0.0, 0.0, 0.0), Vector3::new(1.0, 0.0, 0.0)];
        let q = fitter.timed_samples(&path, 2, None);
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
