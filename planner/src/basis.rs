//! The Bernstein polynomial basis every trajectory is written in.
//!
//! A robot's trajectory along one axis is `p(t) = sum_i xi_i B_i(t / T)` with
//! `B_i` the Bernstein polynomials of degree `N` on normalised time
//! `tau = t / T in [0, 1]`. The optimiser works on `K` evenly spaced samples
//! `tau_k = k / (K - 1)`; [`Basis`] holds the `K x (N + 1)` matrices of the
//! basis and of its first two derivatives there. Derivatives are taken in
//! normalised time: divide by `T` (velocity) and `T^2` (acceleration) to get
//! physical units.
//!
//! ```
//! use flowopt_planner::basis::Basis;
//! let basis = Basis::new(10, 50).unwrap();
//! // The basis is a partition of unity: constant coefficients give a constant.
//! let row = basis.position_row(17);
//! assert!((row.iter().sum::<f64>() - 1.0).abs() < 1e-12);
//! ```

use thiserror::Error;

/// Number of boundary rows per robot and axis: position, velocity and
/// acceleration at the start and at the end.
pub const BOUNDARY_ROWS: usize = 6;

/// Dense re-sampling density of the verification ([`crate::metrics`]):
/// this many instants per optimiser sample.
pub const DENSE_FACTOR: usize = 4;

/// Why a basis could not be built.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum BasisError {
    /// The degree must leave room for the six boundary conditions.
    #[error(
        "BasisError::DegreeTooLow: degree {0} < 6 cannot meet position, velocity and acceleration at both ends with freedom left"
    )]
    DegreeTooLow(usize),
    /// The degree is beyond what the binomial evaluation is accurate for.
    #[error("BasisError::DegreeTooHigh: degree {0} > 30")]
    DegreeTooHigh(usize),
    /// There must be at least as many samples as coefficients.
    #[error("BasisError::TooFewSamples: {samples} samples for {coefficients} coefficients")]
    TooFewSamples {
        /// Samples asked for.
        samples: usize,
        /// Coefficients per robot and axis.
        coefficients: usize,
    },
}

/// The Bernstein basis sampled at `K` evenly spaced instants.
#[derive(Debug, Clone)]
pub struct Basis {
    degree: usize,
    samples: usize,
    /// `K x n_xi`, row-major.
    p: Vec<f64>,
    /// First derivative in normalised time, `K x n_xi`, row-major.
    pd: Vec<f64>,
    /// Second derivative in normalised time, `K x n_xi`, row-major.
    pdd: Vec<f64>,
}

impl Basis {
    /// The basis of `degree` sampled at `samples` instants (both ends included).
    pub fn new(degree: usize, samples: usize) -> Result<Self, BasisError> {
        Self::check(degree, samples)?;
        let n_xi = degree + 1;
        let (mut p, mut pd, mut pdd) =
            (vec![0.0; samples * n_xi], vec![0.0; samples * n_xi], vec![0.0; samples * n_xi]);
        for k in 0..samples {
            let tau = k as f64 / (samples - 1) as f64;
            let rows = k * n_xi..(k + 1) * n_xi;
            bernstein_row_into(degree, 0, tau, &mut p[rows.clone()]);
            bernstein_row_into(degree, 1, tau, &mut pd[rows.clone()]);
            bernstein_row_into(degree, 2, tau, &mut pdd[rows]);
        }
        Ok(Self { degree, samples, p, pd, pdd })
    }

    /// Whether a basis of `degree` at `samples` instants can be built (what
    /// [`Self::new`] refuses), without building it.
    pub fn check(degree: usize, samples: usize) -> Result<(), BasisError> {
        if degree < BOUNDARY_ROWS {
            return Err(BasisError::DegreeTooLow(degree));
        }
        if degree > 30 {
            return Err(BasisError::DegreeTooHigh(degree));
        }
        if samples < degree + 1 {
            return Err(BasisError::TooFewSamples { samples, coefficients: degree + 1 });
        }
        Ok(())
    }

    /// Polynomial degree `N`.
    pub fn degree(&self) -> usize {
        self.degree
    }

    /// Coefficients per robot and axis, `n_xi = N + 1`.
    pub fn n_xi(&self) -> usize {
        self.degree + 1
    }

    /// Number of samples `K`.
    pub fn samples(&self) -> usize {
        self.samples
    }

    /// Normalised time of sample `k`.
    pub fn tau(&self, k: usize) -> f64 {
        k as f64 / (self.samples - 1) as f64
    }

    /// The `K x n_xi` position matrix, row-major.
    pub fn position(&self) -> &[f64] {
        &self.p
    }

    /// The `K x n_xi` first-derivative matrix (normalised time), row-major.
    pub fn velocity(&self) -> &[f64] {
        &self.pd
    }

    /// The `K x n_xi` second-derivative matrix (normalised time), row-major.
    pub fn acceleration(&self) -> &[f64] {
        &self.pdd
    }

    /// Row `k` of the position matrix.
    pub fn position_row(&self, k: usize) -> &[f64] {
        let n = self.n_xi();
        &self.p[k * n..(k + 1) * n]
    }

    /// The six boundary rows `[B(0), B'(0), B''(0), B(1), B'(1), B''(1)]`
    /// (normalised time), `6 x n_xi` row-major.
    pub fn boundary_rows(&self) -> Vec<f64> {
        let mut rows = Vec::with_capacity(BOUNDARY_ROWS * self.n_xi());
        for tau in [0.0, 1.0] {
            for order in 0..3 {
                rows.extend(bernstein_row(self.degree, order, tau));
            }
        }
        rows
    }

    /// `P^T P` (`n_xi x n_xi`, row-major) over the sample rows `from..K`.
    pub fn gram(&self, from: usize) -> Vec<f64> {
        gram_of(&self.p, self.n_xi(), from)
    }

    /// `P''^T P''` (`n_xi x n_xi`, row-major) over all samples, normalised time.
    pub fn acceleration_gram(&self) -> Vec<f64> {
        gram_of(&self.pdd, self.n_xi(), 0)
    }
}

/// `M^T M` over rows `from..` of a row-major matrix with `cols` columns.
pub(crate) fn gram_of(m: &[f64], cols: usize, from: usize) -> Vec<f64> {
    let mut g = vec![0.0; cols * cols];
    for row in m.chunks_exact(cols).skip(from) {
        for (i, &ri) in row.iter().enumerate() {
            for (j, &rj) in row.iter().enumerate() {
                g[i * cols + j] += ri * rj;
            }
        }
    }
    g
}

/// Binomial coefficient as f64 (exact for the degrees allowed here).
fn binomial(n: usize, k: usize) -> f64 {
    (0..k).fold(1.0, |acc, i| acc * (n - i) as f64 / (i + 1) as f64)
}

/// Values at `tau` of the `order`-th derivative (normalised time) of the
/// `degree + 1` Bernstein polynomials of `degree`.
///
/// Uses `d^r/dtau^r B_{i,N} = N!/(N-r)! sum_j (-1)^(r-j) C(r,j) B_{i-j,N-r}`.
pub fn bernstein_row(degree: usize, order: usize, tau: f64) -> Vec<f64> {
    let mut row = vec![0.0; degree + 1];
    bernstein_row_into(degree, order, tau, &mut row);
    row
}

/// [`bernstein_row`] written into `row` (`degree + 1` long), allocating
/// nothing.
pub fn bernstein_row_into(degree: usize, order: usize, tau: f64, row: &mut [f64]) {
    debug_assert_eq!(row.len(), degree + 1);
    if order > degree {
        row.fill(0.0);
        return;
    }
    let low = degree - order;
    // B_{i, N-r}(tau), computed where it is used (no buffer: a plan's
    // evaluation calls this per instant).
    let lower = |i: usize| binomial(low, i) * tau.powi(i as i32) * (1.0 - tau).powi((low - i) as i32);
    let falling: f64 = (0..order).map(|i| (degree - i) as f64).product();
    for (i, value) in row.iter_mut().enumerate() {
        let mut sum = 0.0;
        for j in 0..=order {
            // term B_{i-j, N-r}
            if i >= j && i - j <= low {
                let sign = if (order - j).is_multiple_of(2) { 1.0 } else { -1.0 };
                sum += sign * binomial(order, j) * lower(i - j);
            }
        }
        *value = falling * sum;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn eval(row: &[f64], coeffs: &[f64]) -> f64 {
        row.iter().zip(coeffs).map(|(a, b)| a * b).sum()
    }

    #[test]
    fn derivatives_match_finite_differences() {
        let degree = 10;
        let coeffs: Vec<f64> = (0..=degree).map(|i| ((i * 7) % 5) as f64 - 1.3).collect();
        let h = 1e-5;
        for &tau in &[0.05, 0.3, 0.5, 0.77, 0.95] {
            let f = |t: f64, order| eval(&bernstein_row(degree, order, t), &coeffs);
            let fd1 = (f(tau + h, 0) - f(tau - h, 0)) / (2.0 * h);
            let fd2 = (f(tau + h, 1) - f(tau - h, 1)) / (2.0 * h);
            assert!((fd1 - f(tau, 1)).abs() < 1e-6 * (1.0 + fd1.abs()), "first derivative at {tau}");
            assert!((fd2 - f(tau, 2)).abs() < 1e-5 * (1.0 + fd2.abs()), "second derivative at {tau}");
        }
    }

    #[test]
    fn boundary_rows_have_the_closed_form() {
        let basis = Basis::new(10, 50).unwrap();
        let rows = basis.boundary_rows();
        let n = basis.n_xi();
        // B(0) = e_0, B'(0) = N (e_1 - e_0), B''(0) = N(N-1)(e_0 - 2 e_1 + e_2).
        assert_eq!(rows[0], 1.0);
        assert_eq!(&rows[1..n], &vec![0.0; n - 1][..]);
        assert_eq!((rows[n], rows[n + 1]), (-10.0, 10.0));
        assert_eq!((rows[2 * n], rows[2 * n + 1], rows[2 * n + 2]), (90.0, -180.0, 90.0));
        // B(1) = e_N.
        assert_eq!(rows[3 * n + n - 1], 1.0);
    }

    #[test]
    fn sampled_rows_are_a_partition_of_unity_and_derivatives_sum_to_zero() {
        let basis = Basis::new(10, 50).unwrap();
        let n = basis.n_xi();
        for k in 0..basis.samples() {
            let p: f64 = basis.position()[k * n..(k + 1) * n].iter().sum();
            let v: f64 = basis.velocity()[k * n..(k + 1) * n].iter().sum();
            let a: f64 = basis.acceleration()[k * n..(k + 1) * n].iter().sum();
            assert!((p - 1.0).abs() < 1e-12 && v.abs() < 1e-9 && a.abs() < 1e-8);
        }
    }

    #[test]
    fn invalid_sizes_are_rejected() {
        assert_eq!(Basis::new(4, 50).unwrap_err(), BasisError::DegreeTooLow(4));
        assert!(matches!(Basis::new(10, 8), Err(BasisError::TooFewSamples { .. })));
    }
}
