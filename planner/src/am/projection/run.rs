//! A projection's two operations on an iterate: every correction and the
//! primal residual ([`Projection::run`]), and whether none is needed (the
//! dense verification: [`Projection::clear`], [`Projection::obstacles_clear`]).

use super::check::clear_touched;
use super::correct::clamp_to_box;
use super::grid::SampleGrid;
use super::limits::Limits;
use super::memory::Projection;
use crate::linalg::{Accum, gemm};
use crate::problem::Dim;

impl Projection {
    /// Evaluates `xi` (`[axis][robot][coef]`) on `grid`, computes every
    /// correction against `limits` and returns the primal residual.
    pub fn run(&mut self, dim: Dim, robots: usize, grid: &SampleGrid, limits: &Limits, xi: &[f64]) -> f64 {
        let count = grid.count();
        let n_xi = grid.pt.len() / count;
        let rows = dim.axes() * robots;
        self.start_helper(robots, limits, xi);
        gemm(&mut self.pos, xi, &grid.pt, rows, n_xi, count, Accum::Replace);
        clear_touched(&mut self.corr, &mut self.touched, count);
        if !limits.chord {
            self.scratch.target.fill(1.0);
        }
        let (pairs, boxed) = match dim {
            Dim::Two => self.pairs::<2>(robots, count, limits),
            Dim::Three => self.pairs::<3>(robots, count, limits),
        };
        if self.first && pairs > 0.0 {
            return pairs;
        }
        let obstacles = match dim {
            Dim::Two => self.obstacles::<2>(robots, count, limits),
            Dim::Three => self.obstacles::<3>(robots, count, limits),
        };
        let theirs = match dim {
            Dim::Two => self.collect::<2>(robots, grid, limits),
            Dim::Three => self.collect::<3>(robots, grid, limits),
        };
        let box_sq = boxed
            .unwrap_or_else(|| clamp_to_box(&self.pos, &mut self.corr, &mut self.touched, limits, dim.axes(), count));
        (pairs + theirs + obstacles).sqrt() + box_sq.sqrt()
    }

    /// Whether the robots of `xi` keep clear of the obstacles of `limits`
    /// at every instant of `grid` (pairs and box are not checked), stopping
    /// at the first violation.
    pub fn obstacles_clear(&mut self, dim: Dim, robots: usize, grid: &SampleGrid, limits: &Limits, xi: &[f64]) -> bool {
        let count = grid.count();
        if count == 0 || limits.obstacle_sep.is_empty() {
            return true;
        }
        let n_xi = grid.pt.len() / count;
        gemm(&mut self.pos, xi, &grid.pt, dim.axes() * robots, n_xi, count, Accum::Replace);
        self.first = true;
        let violation = match dim {
            Dim::Two => self.obstacles::<2>(robots, count, limits),
            Dim::Three => self.obstacles::<3>(robots, count, limits),
        };
        self.first = false;
        violation == 0.0
    }

    /// Whether `xi` needs no correction at all against `limits` (what a zero
    /// [`Self::run`] means), stopping at the first violating pair or
    /// obstacle: the dense verification, which fails on most of its calls
    /// while a run converges. The pair a previous call stopped at is checked
    /// before any other (and before the broad phase); the verdict is the
    /// same either way.
    pub fn clear(&mut self, dim: Dim, robots: usize, grid: &SampleGrid, limits: &Limits, xi: &[f64]) -> bool {
        self.first = true;
        let residual = self.run(dim, robots, grid, limits, xi);
        self.first = false;
        residual == 0.0
    }

    /// The corrections mapped back to coefficients, `g = corr P`
    /// (`[axis][robot][coef]`, `rows` rows), into `g`; with a helper, the
    /// sum both threads mapped.
    pub fn coefficients(&self, grid: &SampleGrid, rows: usize, g: &mut [f64]) {
        if self.mapped.len() == g.len() {
            g.copy_from_slice(&self.mapped);
        } else {
            grid.to_coefficients(&self.corr, rows, g);
        }
    }
}
