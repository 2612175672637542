//! Small dense linear programs: maximise `c . x` over `x` free subject to
//! rows `g_j . x <= h_j`, with a few variables and tens to hundreds of
//! rows. The certificates' programs are of this shape (one robot's plan
//! along one axis: its free coefficients, 5 at degree 10 and 15 at degree
//! 20, against its acceleration at the dense instants:
//! [`crate::braking`]), and solved here in microseconds where a general
//! sparse solver took a tenth of a millisecond each
//! (docs/experiments/2026-11-29-small-programs.md).
//!
//! The program is solved as its dual in standard form, `min h . y` subject
//! to `G^T y = c`, `y >= 0`, by the two-phase revised simplex method: the
//! basis is `d x d` (`d` the variables), a pivot prices every row once
//! (the reduced cost of row `j` is its slack `h_j - g_j . x` at the primal
//! point the basis gives), and its factorisation is made afresh each pivot
//! (`d` is small). Rows added after a solve (cuts) are new columns of the
//! dual: the basis found stays feasible, and the next solve starts from it.
//! The leaving column is chosen by Harris' two passes (the largest pivot
//! among the ratios within a tolerance of the least: the programs' rows,
//! the acceleration at neighbouring instants, are nearly parallel, and the
//! least ratio alone led a degree-20 program into bases too ill-conditioned
//! to finish); degenerate pivots in a row switch to Bland's rule for the
//! rest of the solve.
//!
//! The value reported is the larger of the primal and dual values at the
//! optimum, which agree there (a solve where they do not, to
//! [`AGREEMENT`], is refused): the dual's is at least the program's
//! maximum for any dual-feasible point, the safe side of every bound the
//! certificates read from it.
//!
//! ```
//! use flowopt_planner::lp::Lp;
//!
//! // max x + y with x <= 1, y <= 2, x + y <= 2.5.
//! let mut lp = Lp::maximise(&[1.0, 1.0]);
//! lp.add_le(&[1.0, 0.0], 1.0);
//! lp.add_le(&[0.0, 1.0], 2.0);
//! lp.add_le(&[1.0, 1.0], 2.5);
//! let solution = lp.solve().unwrap();
//! assert!((solution.value - 2.5).abs() < 1e-12);
//! ```

use nalgebra::{DMatrix, DVector};
use thiserror::Error;

/// A reduced cost (a row's slack, rows scaled to unit norm) this far below
/// zero prices a row in.
const PRICE_TOLERANCE: f64 = 1e-10;

/// Direction entries at most this large do not bound a ratio.
const PIVOT_TOLERANCE: f64 = 1e-11;

/// A step this short (a dual level) counts as degenerate.
const DEGENERATE: f64 = 1e-12;

/// Phase one's sum of artificial levels above this: the dual has no
/// feasible point.
const FEASIBILITY_TOLERANCE: f64 = 1e-9;

/// Largest gap between the primal and dual values at the optimum,
/// relative to `1 + |value|`, that a solve reports.
pub const AGREEMENT: f64 = 1e-7;

/// Why a program has no optimum here.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum LpError {
    /// No point keeps every row.
    #[error("LpError::Infeasible: no point keeps every row")]
    Infeasible,
    /// The objective grows without bound over the rows (or no point keeps
    /// them: the dual has no feasible point either way).
    #[error("LpError::Unbounded: the objective grows without bound, or no point keeps the rows")]
    Unbounded,
    /// The pivots ran past their cap (cycling, or rounding).
    #[error("LpError::Stalled: no optimum within {0} pivots")]
    Stalled(usize),
    /// A basis was singular, or the primal and dual values disagree.
    #[error("LpError::Inaccurate: a singular basis, or the primal and dual values disagree")]
    Inaccurate,
}

/// A program's optimum.
#[derive(Debug, Clone, PartialEq)]
pub struct Solution {
    /// The primal point.
    pub x: Vec<f64>,
    /// The objective's maximum (the larger of the primal and dual values).
    pub value: f64,
}

/// A program: the objective, the rows, and the last solve's basis.
#[derive(Debug, Clone)]
pub struct Lp {
    /// `c`; negative entries' equality rows of the dual are flipped.
    objective: Vec<f64>,
    /// `m x d` row-major, each row scaled to unit norm.
    rows: Vec<f64>,
    /// The rows' right-hand sides, scaled with them.
    rhs: Vec<f64>,
    /// A row of zeros with a negative right-hand side was added.
    broken: bool,
    /// The dual's basic columns after the last solve.
    basis: Option<Vec<Column>>,
}

/// A column of the dual: a row of the program, or the artificial column of
/// one of its equality rows (phase one's start).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Column {
    Row(usize),
    Artificial(usize),
}

/// The sign an equality row of the dual is multiplied by: -1 where the
/// objective's entry is negative.
fn flip(c: f64) -> f64 {
    if c < 0.0 { -1.0 } else { 1.0 }
}

impl Lp {
    /// The program maximising `objective . x`, no rows yet.
    pub fn maximise(objective: &[f64]) -> Self {
        Self { objective: objective.to_vec(), rows: Vec::new(), rhs: Vec::new(), broken: false, basis: None }
    }

    /// The number of variables.
    pub fn variables(&self) -> usize {
        self.objective.len()
    }

    /// The number of rows kept (rows of zeros are not).
    pub fn rows(&self) -> usize {
        self.rhs.len()
    }

    /// Adds the row `row . x <= rhs` (`row` as long as the objective).
    pub fn add_le(&mut self, row: &[f64], rhs: f64) {
        debug_assert_eq!(row.len(), self.variables());
        let norm = row.iter().map(|v| v * v).sum::<f64>().sqrt();
        if norm == 0.0 || !norm.is_finite() {
            self.broken |= rhs.is_nan() || rhs < 0.0 || !norm.is_finite();
            return;
        }
        self.rows.extend(row.iter().map(|v| v / norm));
        self.rhs.push(rhs / norm);
    }

    /// Adds the row `row . x >= rhs`.
    pub fn add_ge(&mut self, row: &[f64], rhs: f64) {
        let negated: Vec<f64> = row.iter().map(|v| -v).collect();
        self.add_le(&negated, -rhs);
    }

    /// The optimum, from the last solve's basis where there was one.
    pub fn solve(&mut self) -> Result<Solution, LpError> {
        if self.broken || !self.rhs.iter().chain(&self.objective).all(|v| v.is_finite()) {
            return Err(LpError::Infeasible);
        }
        let d = self.variables();
        let mut basic = match self.basis.take() {
            Some(basis) if basis.len() == d => basis,
            _ => (0..d).map(Column::Artificial).collect(),
        };
        let solution = self.optimise(&mut basic);
        // A failed solve's basis is not started from.
        self.basis = solution.is_ok().then_some(basic);
        solution
    }

    /// Entry `k` of the dual's column `column` (its equality rows flipped
    /// where the objective is negative, so that their right-hand side is
    /// not).
    fn entry(&self, column: Column, k: usize) -> f64 {
        match column {
            Column::Row(j) => self.rows[j * self.variables() + k] * flip(self.objective[k]),
            Column::Artificial(a) => f64::from(u8::from(a == k)),
        }
    }

    /// `g_j . x` for row `j`: under phase two's costs a row's reduced cost
    /// in the dual is its slack `h_j - g_j . x`.
    fn row_dot(&self, j: usize, x: &[f64]) -> f64 {
        let d = self.variables();
        self.rows[j * d..(j + 1) * d].iter().zip(x).map(|(g, x)| g * x).sum()
    }

    /// Both phases from `basic`, which is left at the last basis.
    fn optimise(&self, basic: &mut [Column]) -> Result<Solution, LpError> {
        let d = self.variables();
        let b = DVector::from_iterator(d, self.objective.iter().map(|c| c.abs()));
        // Phase one where an artificial column is basic above zero.
        let levels = self.levels(basic, &b)?;
        let above = |levels: &DVector<f64>, basic: &[Column]| {
            basic
                .iter()
                .zip(levels.iter())
                .any(|(c, &y)| matches!(c, Column::Artificial(_)) && y > FEASIBILITY_TOLERANCE)
        };
        if above(&levels, basic) {
            let (_, levels) = self.pivot(basic, &b, &|c| f64::from(u8::from(matches!(c, Column::Artificial(_)))))?;
            if above(&levels, basic) {
                return Err(LpError::Unbounded);
            }
        }
        let cost = |c: Column| match c {
            Column::Row(j) => self.rhs[j],
            Column::Artificial(_) => 0.0,
        };
        let (x, levels) = self.pivot(basic, &b, &cost)?;
        let dual: f64 = basic.iter().zip(levels.iter()).map(|(&c, y)| cost(c) * y).sum();
        let primal: f64 = self.objective.iter().zip(&x).map(|(c, x)| c * x).sum();
        if (dual - primal).abs() > AGREEMENT * (1.0 + dual.abs()) {
            return Err(LpError::Inaccurate);
        }
        Ok(Solution { x, value: dual.max(primal) })
    }

    /// The basic columns' levels `B^-1 b`.
    fn levels(&self, basic: &[Column], b: &DVector<f64>) -> Result<DVector<f64>, LpError> {
        self.basis_matrix(basic).lu().solve(b).ok_or(LpError::Inaccurate)
    }

    /// The basis matrix (its columns the dual's basic columns).
    fn basis_matrix(&self, basic: &[Column]) -> DMatrix<f64> {
        let d = self.variables();
        DMatrix::from_fn(d, d, |k, c| self.entry(basic[c], k))
    }

    /// Simplex pivots under `cost` (artificial columns never enter) until
    /// no row prices in; the primal point and the basic levels of the last
    /// basis.
    fn pivot(
        &self,
        basic: &mut [Column],
        b: &DVector<f64>,
        cost: &dyn Fn(Column) -> f64,
    ) -> Result<(Vec<f64>, DVector<f64>), LpError> {
        let (d, m) = (self.variables(), self.rows());
        let cap = 50 * (m + d) + 100;
        let (mut degenerate, mut bland) = (0, false);
        for _ in 0..cap {
            let basis = self.basis_matrix(basic);
            let lu = basis.clone().lu();
            let levels = lu.solve(b).ok_or(LpError::Inaccurate)?;
            let costs = DVector::from_iterator(d, basic.iter().map(|&c| cost(c)));
            let pi = basis.transpose().lu().solve(&costs).ok_or(LpError::Inaccurate)?;
            // The primal point: the multipliers, unflipped.
            let x: Vec<f64> = (0..d).map(|k| pi[k] * flip(self.objective[k])).collect();
            // Entering: the most violated row; after degenerate pivots in a
            // row, for the rest of the solve, the first violated one
            // (Bland's rule, which cannot cycle).
            bland |= degenerate > 2 * d;
            let mut enter: Option<(usize, f64)> = None;
            for j in 0..m {
                let reduced = cost(Column::Row(j)) - self.row_dot(j, &x);
                if reduced < -PRICE_TOLERANCE && !basic.contains(&Column::Row(j)) {
                    if enter.is_none_or(|(_, r)| reduced < r) {
                        enter = Some((j, reduced));
                    }
                    if bland {
                        break;
                    }
                }
            }
            let Some((j, _)) = enter else {
                return Ok((x, levels));
            };
            let column = DVector::from_fn(d, |k, _| self.entry(Column::Row(j), k));
            let u = lu.solve(&column).ok_or(LpError::Inaccurate)?;
            // Leaving (Harris' two passes): the ratios, an artificial column
            // at zero that the step would move counting 0; the bound on
            // the step that moves no level past zero by more than the
            // tolerance; among the columns within it, the largest pivot
            // (the best conditioned basis next), or the first basic column
            // under Bland's rule.
            let ratios: Vec<Option<(f64, f64)>> = basic
                .iter()
                .enumerate()
                .map(|(c, column)| match column {
                    Column::Artificial(_) if u[c].abs() > PIVOT_TOLERANCE && levels[c] <= FEASIBILITY_TOLERANCE => {
                        Some((0.0, 0.0))
                    }
                    _ if u[c] > PIVOT_TOLERANCE => {
                        Some((levels[c].max(0.0) / u[c], (levels[c].max(0.0) + FEASIBILITY_TOLERANCE) / u[c]))
                    }
                    _ => None,
                })
                .collect();
            let bound = ratios.iter().flatten().map(|r| r.1).fold(f64::INFINITY, f64::min);
            let mut leave: Option<(usize, f64)> = None;
            for (c, ratio) in ratios.iter().enumerate() {
                let Some((ratio, _)) = *ratio else { continue };
                if ratio > bound {
                    continue;
                }
                let better = match leave {
                    None => true,
                    Some((l, _)) if bland => basic[c] < basic[l],
                    Some((l, _)) => u[c].abs() > u[l].abs(),
                };
                if better {
                    leave = Some((c, ratio));
                }
            }
            let Some((c, ratio)) = leave else {
                // The dual is unbounded below: no primal point keeps the rows.
                return Err(LpError::Infeasible);
            };
            degenerate = if ratio <= DEGENERATE { degenerate + 1 } else { 0 };
            basic[c] = Column::Row(j);
        }
        Err(LpError::Stalled(cap))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The maximum by enumerating the vertices (every `d` rows solved as
    /// equalities, kept where every row holds): `None` where no vertex does.
    fn by_vertices(objective: &[f64], rows: &[(Vec<f64>, f64)]) -> Option<f64> {
        let d = objective.len();
        let mut best: Option<f64> = None;
        let mut pick = vec![0; d];
        fn next(pick: &mut [usize], m: usize) -> bool {
            let d = pick.len();
            for i in (0..d).rev() {
                if pick[i] < m - d + i {
                    pick[i] += 1;
                    for k in i + 1..d {
                        pick[k] = pick[k - 1] + 1;
                    }
                    return true;
                }
            }
            false
        }
        for (i, p) in pick.iter_mut().enumerate() {
            *p = i;
        }
        loop {
            let a = DMatrix::from_fn(d, d, |r, c| rows[pick[r]].0[c]);
            let h = DVector::from_fn(d, |r, _| rows[pick[r]].1);
            if let Some(x) = (a.determinant().abs() > 1e-9).then(|| a.lu().solve(&h)).flatten() {
                let holds =
                    rows.iter().all(|(g, h)| g.iter().zip(x.iter()).map(|(g, x)| g * x).sum::<f64>() <= h + 1e-7);
                if holds {
                    let value: f64 = objective.iter().zip(x.iter()).map(|(c, x)| c * x).sum();
                    best = Some(best.map_or(value, |b: f64| b.max(value)));
                }
            }
            if !next(&mut pick, rows.len()) {
                return best;
            }
        }
    }

    /// Rows `-10 <= x_k <= 10` for `d` variables: every program bounded.
    fn boxed(d: usize) -> Vec<(Vec<f64>, f64)> {
        (0..d)
            .flat_map(|k| {
                let e: Vec<f64> = (0..d).map(|i| f64::from(u8::from(i == k))).collect();
                [(e.clone(), 10.0), (e.iter().map(|v| -v).collect(), 10.0)]
            })
            .collect()
    }

    fn solved(objective: &[f64], rows: &[(Vec<f64>, f64)]) -> Result<Solution, LpError> {
        let mut lp = Lp::maximise(objective);
        for (g, h) in rows {
            lp.add_le(g, *h);
        }
        lp.solve()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(300))]

        #[test]
        fn the_optimum_is_the_best_vertex_and_the_point_keeps_every_row(
            d in 1usize..4,
            objective in proptest::collection::vec(-3.0f64..3.0, 3),
            extra in proptest::collection::vec((proptest::collection::vec(-2.0f64..2.0, 3), -1.0f64..4.0), 0..6),
        ) {
            let objective = &objective[..d];
            let mut rows = boxed(d);
            rows.extend(extra.into_iter().map(|(g, h)| (g[..d].to_vec(), h)));
            let expected = by_vertices(objective, &rows);
            match (solved(objective, &rows), expected) {
                (Ok(solution), Some(best)) => {
                    prop_assert!((solution.value - best).abs() < 1e-7 * (1.0 + best.abs()), "{} {best}", solution.value);
                    for (g, h) in &rows {
                        let at: f64 = g.iter().zip(&solution.x).map(|(g, x)| g * x).sum();
                        prop_assert!(at <= h + 1e-7 * (1.0 + h.abs()), "{at} > {h}");
                    }
                }
                (Err(LpError::Infeasible), None) => {}
                (got, expected) => prop_assert!(false, "{got:?} against {expected:?}"),
            }
        }

        #[test]
        fn rows_added_after_a_solve_give_what_a_solve_of_all_of_them_gives(
            objective in proptest::collection::vec(-3.0f64..3.0, 3),
            first in proptest::collection::vec((proptest::collection::vec(-2.0f64..2.0, 3), 0.5f64..4.0), 0..5),
            later in proptest::collection::vec((proptest::collection::vec(-2.0f64..2.0, 3), 0.5f64..4.0), 1..5),
        ) {
            let mut rows = boxed(3);
            rows.extend(first);
            let mut lp = Lp::maximise(&objective);
            for (g, h) in &rows {
                lp.add_le(g, *h);
            }
            prop_assert!(lp.solve().is_ok());
            for (g, h) in &later {
                lp.add_le(g, *h);
                rows.push((g.clone(), *h));
            }
            // The origin keeps every row (right-hand sides positive).
            let (warm, cold) = (lp.solve().unwrap(), solved(&objective, &rows).unwrap());
            prop_assert!((warm.value - cold.value).abs() < 1e-9 * (1.0 + cold.value.abs()), "{} {}", warm.value, cold.value);
        }
    }

    #[test]
    fn an_unbounded_and_an_infeasible_program_say_so() {
        let mut lp = Lp::maximise(&[1.0, 0.0]);
        lp.add_ge(&[1.0, 0.0], 0.0);
        assert_eq!(lp.solve(), Err(LpError::Unbounded));
        let mut lp = Lp::maximise(&[1.0, 1.0]);
        lp.add_le(&[1.0, 0.0], 0.0);
        lp.add_ge(&[1.0, 0.0], 1.0);
        lp.add_le(&[0.0, 1.0], 1.0);
        assert_eq!(lp.solve(), Err(LpError::Infeasible));
        // A row of zeros: kept or refused by its right-hand side.
        let mut lp = Lp::maximise(&[1.0]);
        lp.add_le(&[1.0], 2.0);
        lp.add_le(&[0.0], 1.0);
        assert_eq!(lp.rows(), 1);
        assert_eq!(lp.solve().map(|s| s.value), Ok(2.0));
        lp.add_le(&[0.0], -1.0);
        assert_eq!(lp.solve(), Err(LpError::Infeasible));
    }

    #[test]
    fn many_rows_through_the_optimum_do_not_cycle() {
        // Every row of a fan touches the vertex (1, 1) of max x + y: as
        // degenerate as a program gets.
        let mut lp = Lp::maximise(&[1.0, 1.0]);
        for k in 0..40 {
            let angle = 0.05 + 1.47 * k as f64 / 39.0;
            let (c, s) = (angle.cos(), angle.sin());
            lp.add_le(&[c, s], c + s);
        }
        let solution = lp.solve().unwrap();
        assert!((solution.value - 2.0).abs() < 1e-9, "{}", solution.value);
        assert!((solution.x[0] - 1.0).abs() < 1e-6 && (solution.x[1] - 1.0).abs() < 1e-6, "{:?}", solution.x);
    }
}
