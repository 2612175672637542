//! The projection step: positions at a grid of instants, and the push
//! `e - F xi` that moves every violating robot to the constraint surface.
//!
//! With `d` the offset between two robots (or a robot and an obstacle) and
//! `r = ||diag(a, a, b)^-1 d||` its scaled length, the projected offset is
//! `e = d max(1, 1/r)`: non-violating rows are left alone, violating ones are
//! pushed radially onto the spheroid (the normalised difference, no angles).
//! The box clamps positions. Corrections are summed per robot (`+c` to `i`,
//! `-c` to `j` for a pair row) in position space, and their squared norms give
//! the primal residual `||F xi - e|| + ||G xi - h + s||`.
//!
//! The same code checks feasibility: on the dense grid with the true sizes
//! shrunk by the tolerance, a plan is feasible exactly when no correction is
//! needed.

use crate::basis::bernstein_row;
use crate::linalg::{Accum, gemm};
use crate::problem::{Dim, Problem};

/// Squared scaled distance below which two centres count as coincident and
/// the push direction is chosen deterministically instead of normalised.
const COINCIDENT: f64 = 1e-18;

/// Instants the constraints are evaluated at, with the basis there.
#[derive(Debug, Clone)]
pub(crate) struct SampleGrid {
    /// Normalised times.
    pub taus: Vec<f64>,
    /// `P^T`, `n_xi x count`, row-major.
    pub pt: Vec<f64>,
    /// `P`, `count x n_xi`, row-major.
    pub p: Vec<f64>,
}

impl SampleGrid {
    /// The basis of `degree` at `taus`.
    pub fn new(degree: usize, taus: Vec<f64>) -> Self {
        let n_xi = degree + 1;
        let count = taus.len();
        let p: Vec<f64> = taus.iter().flat_map(|&t| bernstein_row(degree, 0, t)).collect();
        let mut pt = vec![0.0; n_xi * count];
        for r in 0..count {
            for c in 0..n_xi {
                pt[c * count + r] = p[r * n_xi + c];
            }
        }
        Self { taus, pt, p }
    }

    /// Number of instants.
    pub fn count(&self) -> usize {
        self.taus.len()
    }
}

/// Sizes, box and obstacle tracks one projection checks against.
#[derive(Debug, Clone)]
pub struct Limits {
    /// Robot-robot separations per axis.
    robot_sep: [f64; 3],
    /// Per obstacle: robot-obstacle separations per axis.
    obstacle_sep: Vec<[f64; 3]>,
    /// Box per axis.
    lo: [f64; 3],
    hi: [f64; 3],
    /// Obstacle centres at the grid instants, `[obstacle][axis][count]`.
    tracks: Vec<f64>,
}

impl Limits {
    /// Robot-robot separations per axis (m).
    pub fn robot_separation(&self) -> [f64; 3] {
        self.robot_sep
    }

    /// Robot-obstacle separations per axis, per obstacle (m).
    pub fn obstacle_separations(&self) -> &[[f64; 3]] {
        &self.obstacle_sep
    }

    /// The box positions are clamped into, `(lower, upper)` per axis (m).
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        (self.lo, self.hi)
    }

    /// Obstacle centres at the grid's instants, `[obstacle][axis][sample]` (m).
    pub fn tracks(&self) -> &[f64] {
        &self.tracks
    }

    /// The limits of `problem` on `grid`: every separation scaled by
    /// `scale`, the box moved inwards by `inset` (per axis; negative grows it).
    pub(crate) fn new(problem: &Problem, grid: &SampleGrid, scale: f64, inset: [f64; 3]) -> Self {
        let team = &problem.team;
        let dim = team.dim.axes();
        let (a, b) = team.separation();
        let count = grid.count();
        let mut tracks = vec![0.0; problem.obstacles.len() * dim * count];
        let mut obstacle_sep = Vec::with_capacity(problem.obstacles.len());
        for (m, o) in problem.obstacles.iter().enumerate() {
            for ax in 0..dim {
                for (k, tau) in grid.taus.iter().enumerate() {
                    tracks[(m * dim + ax) * count + k] = o.position[ax] + o.velocity[ax] * tau * team.horizon;
                }
            }
            let (ao, bo) = team.obstacle_separation(&o.shape);
            obstacle_sep.push([ao * scale, ao * scale, bo * scale]);
        }
        Self {
            robot_sep: [a * scale, a * scale, b * scale],
            obstacle_sep,
            lo: [0, 1, 2].map(|ax| team.workspace.min[ax] + inset[ax]),
            hi: [0, 1, 2].map(|ax| team.workspace.max[ax] - inset[ax]),
            tracks,
        }
    }
}

/// Positions and corrections at a grid: the projection's working memory.
#[derive(Debug, Clone)]
pub(crate) struct Projection {
    /// Positions `[axis][robot][count]`.
    pub pos: Vec<f64>,
    /// Corrections `e - F xi` summed per robot, `[axis][robot][count]`.
    pub corr: Vec<f64>,
    /// Robots with any non-zero correction.
    pub touched: Vec<bool>,
}

impl Projection {
    /// Buffers for `robots` robots in `dim` on `grid`.
    pub fn new(dim: Dim, robots: usize, grid: &SampleGrid) -> Self {
        let len = dim.axes() * robots * grid.count();
        Self { pos: vec![0.0; len], corr: vec![0.0; len], touched: vec![false; robots] }
    }

    /// Evaluates `xi` (`[axis][robot][coef]`) on `grid`, computes every
    /// correction against `limits` and returns the primal residual.
    pub fn run(&mut self, dim: Dim, robots: usize, grid: &SampleGrid, limits: &Limits, xi: &[f64]) -> f64 {
        let count = grid.count();
        let n_xi = grid.pt.len() / count;
        let rows = dim.axes() * robots;
        gemm(&mut self.pos, xi, &grid.pt, rows, n_xi, count, Accum::Replace);
        self.corr.fill(0.0);
        self.touched.fill(false);
        let collisions = match dim {
            Dim::Two => self.pairs::<2>(robots, count, limits.robot_sep) + self.obstacles::<2>(robots, count, limits),
            Dim::Three => self.pairs::<3>(robots, count, limits.robot_sep) + self.obstacles::<3>(robots, count, limits),
        };
        let mut box_sq = 0.0;
        for ax in 0..dim.axes() {
            let (lo, hi) = (limits.lo[ax], limits.hi[ax]);
            for i in 0..robots {
                let range = (ax * robots + i) * count..(ax * robots + i + 1) * count;
                let mut any = false;
                for (p, c) in self.pos[range.clone()].iter().zip(&mut self.corr[range]) {
                    let d = p.clamp(lo, hi) - p;
                    *c += d;
                    box_sq += d * d;
                    any |= d != 0.0;
                }
                self.touched[i] |= any;
            }
        }
        collisions.sqrt() + box_sq.sqrt()
    }

    /// Inter-robot corrections for every pair `i < j`: where `r < 1` the
    /// offset is pushed to the surface, `c = d (1/r - 1)`, added to `i` and
    /// taken from `j`. Returns the sum of `||c||^2`.
    fn pairs<const D: usize>(&mut self, n: usize, count: usize, sep: [f64; 3]) -> f64 {
        let inv = sep.map(|s| 1.0 / (s * s));
        let stride = n * count;
        let pos = &self.pos;
        let mut sum = 0.0;
        for i in 0..n {
            let pi: [&[f64]; D] = std::array::from_fn(|a| &pos[a * stride + i * count..a * stride + (i + 1) * count]);
            for j in i + 1..n {
                let pj: [&[f64]; D] =
                    std::array::from_fn(|a| &pos[a * stride + j * count..a * stride + (j + 1) * count]);
                if !any_inside::<D>(&pi, &pj, &inv, count) {
                    continue;
                }
                self.touched[i] = true;
                self.touched[j] = true;
                for k in 0..count {
                    let Some(c) = push::<D>(&pi, &pj, k, &inv, &sep, (i, j)) else {
                        continue;
                    };
                    for a in 0..D {
                        self.corr[a * stride + i * count + k] += c[a];
                        self.corr[a * stride + j * count + k] -= c[a];
                        sum += c[a] * c[a];
                    }
                }
            }
        }
        sum
    }

    /// Robot-obstacle corrections: where robot `i` is inside the (scaled)
    /// obstacle `m` at an instant, its position is pushed to the surface.
    fn obstacles<const D: usize>(&mut self, n: usize, count: usize, limits: &Limits) -> f64 {
        let stride = n * count;
        let pos = &self.pos;
        let mut sum = 0.0;
        for (m, sep) in limits.obstacle_sep.iter().enumerate() {
            let inv = sep.map(|s| 1.0 / (s * s));
            let track: [&[f64]; D] =
                std::array::from_fn(|a| &limits.tracks[(m * D + a) * count..(m * D + a + 1) * count]);
            for i in 0..n {
                let pi: [&[f64]; D] =
                    std::array::from_fn(|a| &pos[a * stride + i * count..a * stride + (i + 1) * count]);
                if !any_inside::<D>(&pi, &track, &inv, count) {
                    continue;
                }
                self.touched[i] = true;
                for k in 0..count {
                    let Some(c) = push::<D>(&pi, &track, k, &inv, sep, (i, m)) else {
                        continue;
                    };
                    for a in 0..D {
                        self.corr[a * stride + i * count + k] += c[a];
                        sum += c[a] * c[a];
                    }
                }
            }
        }
        sum
    }
}

/// Whether `p` and `q` come closer than the separation at any instant
/// (the cheap screen every pair goes through; vectorises over instants).
fn any_inside<const D: usize>(p: &[&[f64]; D], q: &[&[f64]; D], inv: &[f64; 3], count: usize) -> bool {
    let mut any = false;
    for k in 0..count {
        let mut s = 0.0;
        for a in 0..D {
            let d = p[a][k] - q[a][k];
            s += d * d * inv[a];
        }
        any |= s < 1.0;
    }
    any
}

/// The correction `e - d` for offset `d = p(k) - q(k)` if it violates the
/// separation. Coincident centres get a deterministic direction derived
/// from `ids` and `k`.
fn push<const D: usize>(
    p: &[&[f64]; D],
    q: &[&[f64]; D],
    k: usize,
    inv: &[f64; 3],
    sep: &[f64; 3],
    ids: (usize, usize),
) -> Option<[f64; D]> {
    let mut d = [0.0; D];
    let mut s = 0.0;
    for a in 0..D {
        d[a] = p[a][k] - q[a][k];
        s += d[a] * d[a] * inv[a];
    }
    if s >= 1.0 {
        return None;
    }
    let mut c = [0.0; D];
    if s < COINCIDENT {
        // Golden-angle spread so that coincident pairs part in different directions.
        let angle = ((ids.0 * 31 + ids.1 * 17 + k * 7) as f64) * 2.399_963_229_728_653;
        let u = [angle.cos(), angle.sin(), 0.0];
        for a in 0..D {
            c[a] = u[a] * sep[a] - d[a];
        }
    } else {
        let scale = 1.0 / s.sqrt() - 1.0;
        for a in 0..D {
            c[a] = d[a] * scale;
        }
    }
    Some(c)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::problem::{Obstacle, Spheroid, StartState, Team};
    use nalgebra::Vector3;

    /// Two robots held at fixed points (constant coefficients) on a 1-instant
    /// grid in the middle of the horizon.
    fn setup(p0: [f64; 2], p1: [f64; 2], obstacles: Vec<Obstacle>) -> (Problem, SampleGrid, Vec<f64>) {
        let team = Team::default_for(Dim::Two, 2);
        let nx = team.degree + 1;
        let mut xi = vec![0.0; 2 * 2 * nx];
        for (i, p) in [p0, p1].iter().enumerate() {
            for a in 0..2 {
                xi[(a * 2 + i) * nx..(a * 2 + i + 1) * nx].fill(p[a]);
            }
        }
        let problem = Problem {
            team: team.clone(),
            starts: vec![
                StartState::at_rest(Vector3::new(p0[0], p0[1], 0.0)),
                StartState::at_rest(Vector3::new(p1[0], p1[1], 0.0)),
            ],
            goals: vec![Vector3::new(p0[0], p0[1], 0.0), Vector3::new(p1[0], p1[1], 0.0)],
            obstacles,
        };
        (problem, SampleGrid::new(team.degree, vec![0.5]), xi)
    }

    fn corr(p: &Projection, axis: usize, robot: usize) -> f64 {
        p.corr[axis * 2 + robot]
    }

    #[test]
    fn a_violating_pair_is_pushed_apart_to_the_surface_symmetrically() {
        // 0.1 m apart along x, separation 0.2: each gets half of the 0.1 m gap.
        let (problem, grid, xi) = setup([0.0, 0.0], [0.1, 0.0], vec![]);
        let limits = Limits::new(&problem, &grid, 1.0, [0.0; 3]);
        let mut p = Projection::new(Dim::Two, 2, &grid);
        let primal = p.run(Dim::Two, 2, &grid, &limits, &xi);
        // The pair row's target is d / r = (-0.2, 0): the correction is -0.1 on
        // robot 0 and +0.1 on robot 1; the residual is the 0.1 m deficit.
        assert!((corr(&p, 0, 0) + 0.1).abs() < 1e-12 && (corr(&p, 0, 1) - 0.1).abs() < 1e-12);
        assert_eq!((corr(&p, 1, 0), corr(&p, 1, 1)), (0.0, 0.0));
        assert!((primal - 0.1).abs() < 1e-12);
        assert_eq!(p.touched, vec![true, true]);
    }

    #[test]
    fn pairs_outside_the_separation_are_left_alone() {
        let (problem, grid, xi) = setup([0.0, 0.0], [0.15, 0.15], vec![]);
        let limits = Limits::new(&problem, &grid, 1.0, [0.0; 3]);
        let mut p = Projection::new(Dim::Two, 2, &grid);
        assert_eq!(p.run(Dim::Two, 2, &grid, &limits, &xi), 0.0);
        assert!(p.corr.iter().all(|&c| c == 0.0) && p.touched == vec![false, false]);
        // Inflating by 10% makes the same pair (0.212 m apart) violate.
        let inflated = Limits::new(&problem, &grid, 1.1, [0.0; 3]);
        assert!(p.run(Dim::Two, 2, &grid, &inflated, &xi) > 0.0);
    }

    #[test]
    fn coincident_robots_are_parted_along_a_unit_direction() {
        let (problem, grid, xi) = setup([0.3, 0.3], [0.3, 0.3], vec![]);
        let limits = Limits::new(&problem, &grid, 1.0, [0.0; 3]);
        let mut p = Projection::new(Dim::Two, 2, &grid);
        let primal = p.run(Dim::Two, 2, &grid, &limits, &xi);
        let (cx, cy) = (corr(&p, 0, 0), corr(&p, 1, 0));
        assert!(((cx * cx + cy * cy).sqrt() - 0.2).abs() < 1e-12);
        assert!((primal - 0.2).abs() < 1e-12);
    }

    #[test]
    fn a_robot_inside_an_obstacle_is_pushed_out_radially_and_the_box_clamps() {
        let obstacle =
            Obstacle { position: Vector3::new(0.0, 0.0, 0.0), velocity: Vector3::zeros(), shape: Spheroid::ball(0.1) };
        // Robot 0 at (0.1, 0) inside the 0.2 m inflated obstacle; robot 1 at
        // x = 1.05, outside the [-1, 1] box.
        let (problem, grid, xi) = setup([0.1, 0.0], [1.05, 0.5], vec![obstacle]);
        let limits = Limits::new(&problem, &grid, 1.0, [0.0; 3]);
        let mut p = Projection::new(Dim::Two, 2, &grid);
        let primal = p.run(Dim::Two, 2, &grid, &limits, &xi);
        assert!((corr(&p, 0, 0) - 0.1).abs() < 1e-12, "pushed to x = 0.2");
        assert!((corr(&p, 0, 1) + 0.05).abs() < 1e-12, "clamped to x = 1");
        assert!((primal - (0.1 + 0.05)).abs() < 1e-12);
        // A box inset of 0.1 m clamps robot 1 to 0.9 instead.
        let inset = Limits::new(&problem, &grid, 1.0, [0.1; 3]);
        p.run(Dim::Two, 2, &grid, &inset, &xi);
        assert!((corr(&p, 0, 1) + 0.15).abs() < 1e-12);
    }

    #[test]
    fn a_moving_obstacle_is_tracked_in_time() {
        // At tau = 0.5 (t = 2.5 s) an obstacle starting at x = -0.25 moving at
        // 0.1 m/s sits at x = 0: it overlaps a robot at the origin.
        let moving = Obstacle {
            position: Vector3::new(-0.25, 0.0, 0.0),
            velocity: Vector3::new(0.1, 0.0, 0.0),
            shape: Spheroid::ball(0.1),
        };
        let (problem, grid, xi) = setup([0.0, 0.05], [0.8, 0.8], vec![moving]);
        let limits = Limits::new(&problem, &grid, 1.0, [0.0; 3]);
        let mut p = Projection::new(Dim::Two, 2, &grid);
        let primal = p.run(Dim::Two, 2, &grid, &limits, &xi);
        assert!((corr(&p, 1, 0) - 0.15).abs() < 1e-12, "pushed from y = 0.05 to y = 0.2");
        assert!((primal - 0.15).abs() < 1e-12);
    }
}
