//! Dense products over row-major slices, on faer's kernels.
//!
//! The engine's matrices are small (tens of rows, 11 to 200 columns); faer's
//! sequential matmul beats hand-written loops several times at these sizes
//! (docs/BENCHMARKS.md), and running it sequentially avoids thread hand-offs
//! that would cost more than the product.

pub use faer::Accum;
use faer::linalg::matmul::matmul;
use faer::{MatMut, MatRef, Par};

/// `c (m x n) = a (m x k) b (k x n)` ([`Accum::Replace`]) or
/// `c += a b` ([`Accum::Add`]), all row-major.
pub fn gemm(c: &mut [f64], a: &[f64], b: &[f64], m: usize, k: usize, n: usize, accum: Accum) {
    matmul(
        MatMut::from_row_major_slice_mut(c, m, n),
        accum,
        MatRef::from_row_major_slice(a, m, k),
        MatRef::from_row_major_slice(b, k, n),
        1.0,
        Par::Seq,
    );
}

/// `sum a_i b_i`.
pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gemm_matches_the_definition() {
        let a = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]; // 2 x 3
        let b = [1.0, 0.0, 0.0, 1.0, 1.0, 1.0]; // 3 x 2
        let mut c = [10.0; 4];
        gemm(&mut c, &a, &b, 2, 3, 2, Accum::Replace);
        assert_eq!(c, [4.0, 5.0, 10.0, 11.0]);
        gemm(&mut c, &a, &b, 2, 3, 2, Accum::Add);
        assert_eq!(c, [8.0, 10.0, 20.0, 22.0]);
    }
}
