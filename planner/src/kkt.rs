//! The linear KKT solve at the heart of every AM iteration, and its structure.
//!
//! Per axis, the xi-step solves
//! `min 1/2 xi^T H xi - r^T xi  s.t.  (I_n (x) A_1) xi = b` with
//! `H = I_n (x) C + rho (L_n + (m + w) I_n) (x) P^T P`,
//! where `L_n = n I - 1 1^T` is the complete-graph Laplacian (inter-robot
//! rows), `m` the obstacle count and `w = 2` the two-sided workspace box.
//! `L_n` has eigenvalue 0 on the mean mode `1 / sqrt(n)` and `n` on its
//! orthogonal complement, so the `n n_xi + 6 n` system splits into one small
//! `n_xi + 6` system for the team mean and one shared by every difference
//! mode ([`TeamKkt`]). [`DenseTeamKkt`] assembles and factors the full system;
//! it exists to prove the structured path equal and to measure the gain.
//!
//! ```
//! use flowopt_planner::{basis::Basis, kkt::TeamKkt};
//! let basis = Basis::new(10, 50).unwrap();
//! let n_xi = basis.n_xi();
//! let identity: Vec<f64> = (0..n_xi * n_xi).map(|i| f64::from(i % (n_xi + 1) == 0)).collect();
//! let kkt = TeamKkt::new(&identity, &basis.gram(1), &basis.boundary_rows(), 4, 0, 2.0).unwrap();
//! assert_eq!(kkt.n_xi(), 11);
//! ```

use faer::Mat;
use faer::linalg::solvers::{DenseSolveCore, Solve};
use thiserror::Error;

use crate::basis::BOUNDARY_ROWS;
use crate::linalg::dot;

/// Weight of the workspace term in `H`: a two-sided box puts `P` twice in `G`.
pub const WORKSPACE_WEIGHT: f64 = 2.0;

/// Why a KKT system could not be factored.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum KktError {
    /// The system is singular or numerically so (non-finite inverse).
    #[error("KktError::Singular: the KKT matrix of size {0} is singular")]
    Singular(usize),
}

/// The solution operator of one small KKT system `[[H, A^T], [A, 0]]`:
/// `x = K11 r + K12 b`.
#[derive(Debug, Clone)]
pub struct SmallKkt {
    n: usize,
    /// `n x n`, row-major.
    k11: Vec<f64>,
    /// `n x 6`, row-major.
    k12: Vec<f64>,
}

impl SmallKkt {
    /// Factors `[[H, A^T], [A, 0]]` for `H` (`n x n`) and `A` (`6 x n`),
    /// both row-major, and keeps the blocks of its inverse that map
    /// `(r, b)` to `x`.
    pub fn new(h: &[f64], a: &[f64], n: usize) -> Result<Self, KktError> {
        let size = n + BOUNDARY_ROWS;
        let kkt = Mat::<f64>::from_fn(size, size, |i, j| match (i < n, j < n) {
            (true, true) => h[i * n + j],
            (true, false) => a[(j - n) * n + i],
            (false, true) => a[(i - n) * n + j],
            (false, false) => 0.0,
        });
        let inverse = kkt.partial_piv_lu().inverse();
        let mut k11 = vec![0.0; n * n];
        let mut k12 = vec![0.0; n * BOUNDARY_ROWS];
        for i in 0..n {
            for j in 0..n {
                k11[i * n + j] = inverse[(i, j)];
            }
            for j in 0..BOUNDARY_ROWS {
                k12[i * BOUNDARY_ROWS + j] = inverse[(i, n + j)];
            }
        }
        if k11.iter().chain(&k12).any(|v| !v.is_finite()) {
            return Err(KktError::Singular(size));
        }
        Ok(Self { n, k11, k12 })
    }

    /// The `n x n` block mapping the linear term to the solution.
    pub fn k11(&self) -> &[f64] {
        &self.k11
    }

    /// `out = K11 r + K12 b`.
    pub fn apply(&self, r: &[f64], b: &[f64], out: &mut [f64]) {
        for (i, o) in out.iter_mut().enumerate().take(self.n) {
            let row = &self.k11[i * self.n..(i + 1) * self.n];
            let brow = &self.k12[i * BOUNDARY_ROWS..(i + 1) * BOUNDARY_ROWS];
            *o = dot(row, r) + dot(brow, b);
        }
    }

    /// `out = K12 b` (the part of the solution fixed by the boundary values).
    pub fn apply_boundary(&self, b: &[f64], out: &mut [f64]) {
        for (i, o) in out.iter_mut().enumerate().take(self.n) {
            *o = dot(&self.k12[i * BOUNDARY_ROWS..(i + 1) * BOUNDARY_ROWS], b);
        }
    }
}

/// The per-axis xi-step system of a whole team, split into the mean mode and
/// the shared difference-mode system: two factorisations of size `n_xi + 6`
/// serve every robot, axis and batch element.
#[derive(Debug, Clone)]
pub struct TeamKkt {
    robots: usize,
    n_xi: usize,
    mean: SmallKkt,
    diff: SmallKkt,
}

impl TeamKkt {
    /// Builds the two systems for cost Hessian `C` (per robot and axis),
    /// `P^T P` over the constrained samples, the boundary rows `A_1`,
    /// `robots` robots, `obstacles` obstacles and penalty `rho`.
    pub fn new(
        cost_hessian: &[f64],
        gram: &[f64],
        boundary: &[f64],
        robots: usize,
        obstacles: usize,
        rho: f64,
    ) -> Result<Self, KktError> {
        let n_xi = boundary.len() / BOUNDARY_ROWS;
        let shared = obstacles as f64 + WORKSPACE_WEIGHT;
        let h = |modes: f64| -> Vec<f64> { cost_hessian.iter().zip(gram).map(|(c, g)| c + rho * modes * g).collect() };
        Ok(Self {
            robots,
            n_xi,
            mean: SmallKkt::new(&h(shared), boundary, n_xi)?,
            diff: SmallKkt::new(&h(robots as f64 + shared), boundary, n_xi)?,
        })
    }

    /// Coefficients per robot and axis.
    pub fn n_xi(&self) -> usize {
        self.n_xi
    }

    /// The mean-mode solution operator.
    pub fn mean(&self) -> &SmallKkt {
        &self.mean
    }

    /// The difference-mode solution operator.
    pub fn diff(&self) -> &SmallKkt {
        &self.diff
    }

    /// Solves one axis: `rhs` is `n x n_xi` (the linear term per robot), `b`
    /// is `n x 6` (boundary values per robot), `out` is `n x n_xi`.
    ///
    /// `xi_i = S_diff(r_i - r_mean, b_i - b_mean) + S_mean(r_mean, b_mean)`.
    pub fn solve_axis(&self, rhs: &[f64], b: &[f64], out: &mut [f64]) {
        let (n, nx) = (self.robots, self.n_xi);
        let mut r_mean = vec![0.0; nx];
        let mut b_mean = [0.0; BOUNDARY_ROWS];
        for i in 0..n {
            for (m, v) in r_mean.iter_mut().zip(&rhs[i * nx..(i + 1) * nx]) {
                *m += v / n as f64;
            }
            for (m, v) in b_mean.iter_mut().zip(&b[i * BOUNDARY_ROWS..(i + 1) * BOUNDARY_ROWS]) {
                *m += v / n as f64;
            }
        }
        let mut mean_part = vec![0.0; nx];
        self.mean.apply(&r_mean, &b_mean, &mut mean_part);
        let mut dr = vec![0.0; nx];
        let mut db = [0.0; BOUNDARY_ROWS];
        for i in 0..n {
            for c in 0..nx {
                dr[c] = rhs[i * nx + c] - r_mean[c];
            }
            for c in 0..BOUNDARY_ROWS {
                db[c] = b[i * BOUNDARY_ROWS + c] - b_mean[c];
            }
            let xi = &mut out[i * nx..(i + 1) * nx];
            self.diff.apply(&dr, &db, xi);
            for (x, m) in xi.iter_mut().zip(&mean_part) {
                *x += m;
            }
        }
    }
}

/// The same per-axis system assembled densely, `(n n_xi + 6 n)^2`, and
/// LU-factored: the reference the structured path is checked against.
pub struct DenseTeamKkt {
    robots: usize,
    n_xi: usize,
    lu: faer::linalg::solvers::PartialPivLu<f64>,
}

impl DenseTeamKkt {
    /// Assembles and factors the full system (same arguments as [`TeamKkt::new`]).
    pub fn new(
        cost_hessian: &[f64],
        gram: &[f64],
        boundary: &[f64],
        robots: usize,
        obstacles: usize,
        rho: f64,
    ) -> Self {
        let n_xi = boundary.len() / BOUNDARY_ROWS;
        let vars = robots * n_xi;
        let size = vars + robots * BOUNDARY_ROWS;
        let shared = obstacles as f64 + WORKSPACE_WEIGHT;
        let mut m = Mat::<f64>::zeros(size, size);
        for i in 0..robots {
            for j in 0..robots {
                // Laplacian entry plus the obstacle and workspace terms.
                let l = if i == j { robots as f64 - 1.0 + shared } else { -1.0 };
                for r in 0..n_xi {
                    for c in 0..n_xi {
                        let mut v = rho * l * gram[r * n_xi + c];
                        if i == j {
                            v += cost_hessian[r * n_xi + c];
                        }
                        m[(i * n_xi + r, j * n_xi + c)] = v;
                    }
                }
            }
            for r in 0..BOUNDARY_ROWS {
                for c in 0..n_xi {
                    let a = boundary[r * n_xi + c];
                    m[(vars + i * BOUNDARY_ROWS + r, i * n_xi + c)] = a;
                    m[(i * n_xi + c, vars + i * BOUNDARY_ROWS + r)] = a;
                }
            }
        }
        Self { robots, n_xi, lu: m.partial_piv_lu() }
    }

    /// Solves one axis (same layout as [`TeamKkt::solve_axis`]).
    pub fn solve_axis(&self, rhs: &[f64], b: &[f64], out: &mut [f64]) {
        let vars = self.robots * self.n_xi;
        let size = vars + self.robots * BOUNDARY_ROWS;
        let r = Mat::<f64>::from_fn(size, 1, |i, _| if i < vars { rhs[i] } else { b[i - vars] });
        let x = self.lu.solve(&r);
        for (i, o) in out.iter_mut().enumerate().take(vars) {
            *o = x[(i, 0)];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::basis::Basis;

    fn pseudo_random(len: usize, seed: u64) -> Vec<f64> {
        let mut s = seed;
        (0..len)
            .map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                ((s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
            })
            .collect()
    }

    fn check_structured_equals_dense(cost: &[f64], robots: usize, obstacles: usize, rho: f64) {
        let basis = Basis::new(10, 50).unwrap();
        let n_xi = basis.n_xi();
        let gram = basis.gram(1);
        let boundary = basis.boundary_rows();
        let fast = TeamKkt::new(cost, &gram, &boundary, robots, obstacles, rho).unwrap();
        let dense = DenseTeamKkt::new(cost, &gram, &boundary, robots, obstacles, rho);
        let rhs = pseudo_random(robots * n_xi, 7);
        let b = pseudo_random(robots * BOUNDARY_ROWS, 11);
        let mut x_fast = vec![0.0; robots * n_xi];
        let mut x_dense = vec![0.0; robots * n_xi];
        fast.solve_axis(&rhs, &b, &mut x_fast);
        dense.solve_axis(&rhs, &b, &mut x_dense);
        let diff: f64 = x_fast.iter().zip(&x_dense).map(|(a, b)| (a - b).powi(2)).sum::<f64>().sqrt();
        let norm: f64 = x_dense.iter().map(|a| a * a).sum::<f64>().sqrt();
        assert!(diff <= 1e-9 * norm, "relative difference {} for n={robots} m={obstacles} rho={rho}", diff / norm);
    }

    #[test]
    fn structured_solve_equals_dense_solve_for_the_safety_filter() {
        let n_xi = 11;
        let identity: Vec<f64> = (0..n_xi * n_xi).map(|i| f64::from(i % (n_xi + 1) == 0)).collect();
        for &(robots, obstacles, rho) in &[(2, 0, 1.0), (16, 0, 5.0), (16, 8, 50.0), (32, 3, 0.3)] {
            check_structured_equals_dense(&identity, robots, obstacles, rho);
        }
    }

    #[test]
    fn structured_solve_equals_dense_solve_for_the_smoothness_optimiser() {
        let basis = Basis::new(10, 50).unwrap();
        let q: Vec<f64> = basis.acceleration_gram().iter().map(|v| v / 625.0).collect();
        for &(robots, obstacles, rho) in &[(8, 0, 1.0), (16, 4, 10.0)] {
            check_structured_equals_dense(&q, robots, obstacles, rho);
        }
    }

    #[test]
    fn solution_meets_the_boundary_rows() {
        let basis = Basis::new(10, 50).unwrap();
        let n_xi = basis.n_xi();
        let identity: Vec<f64> = (0..n_xi * n_xi).map(|i| f64::from(i % (n_xi + 1) == 0)).collect();
        let boundary = basis.boundary_rows();
        let kkt = TeamKkt::new(&identity, &basis.gram(1), &boundary, 5, 2, 3.0).unwrap();
        let rhs = pseudo_random(5 * n_xi, 3);
        let b = pseudo_random(5 * BOUNDARY_ROWS, 5);
        let mut x = vec![0.0; 5 * n_xi];
        kkt.solve_axis(&rhs, &b, &mut x);
        for i in 0..5 {
            for r in 0..BOUNDARY_ROWS {
                let v = dot(&boundary[r * n_xi..(r + 1) * n_xi], &x[i * n_xi..(i + 1) * n_xi]);
                assert!((v - b[i * BOUNDARY_ROWS + r]).abs() < 1e-9);
            }
        }
    }
}
