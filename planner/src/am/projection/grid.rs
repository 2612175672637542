//! The instants a projection evaluates positions at, with the Bernstein
//! basis there.

use crate::basis::bernstein_row;
use crate::linalg::{Accum, gemm};

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

    /// `P^T P` (`n_xi x n_xi`, row-major) over the instants.
    pub fn gram(&self) -> Vec<f64> {
        let count = self.count();
        let n_xi = self.pt.len() / count.max(1);
        let mut g = vec![0.0; n_xi * n_xi];
        gemm(&mut g, &self.pt, &self.p, n_xi, count, n_xi, Accum::Replace);
        g
    }

    /// Number of instants.
    pub fn count(&self) -> usize {
        self.taus.len()
    }

    /// Values at the instants (`rows x count`) mapped back to coefficients,
    /// `out = values P` (`rows x n_xi`).
    pub fn to_coefficients(&self, values: &[f64], rows: usize, out: &mut [f64]) {
        let count = self.count();
        gemm(out, values, &self.p, rows, count, self.p.len() / count.max(1), Accum::Replace);
    }
}
