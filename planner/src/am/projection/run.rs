//! A projection's two operations on an iterate: every correction and the
//! primal residual ([`Projection::run`]), and whether none is needed (the
//! dense verification: [`Projection::clear`], [`Projection::obstacles_clear`]).

use super::super::pairs::{BROAD_PHASE_MIN_ROBOTS, Candidate};
use super::check::Check;
use super::grid::SampleGrid;
use super::limits::Limits;
use super::memory::{BlockSums, Projection, ROBOT_BLOCK};
use crate::crew::Crew;
use crate::problem::Dim;

impl Projection {
    /// Evaluates `xi` (`[axis][robot][coef]`) on `grid`, computes every
    /// correction against `limits` on `crew` and returns the primal
    /// residual; the corrections mapped to coefficients are then
    /// [`Self::mapped`]. The same numbers for every crew size.
    pub fn run(
        &mut self,
        crew: &Crew<'_>,
        dim: Dim,
        robots: usize,
        grid: &SampleGrid,
        limits: &Limits,
        xi: &[f64],
    ) -> f64 {
        match dim {
            Dim::Two => self.run_in::<2>(crew, robots, grid, limits, xi),
            Dim::Three => self.run_in::<3>(crew, robots, grid, limits, xi),
        }
    }

    fn run_in<const D: usize>(
        &mut self,
        crew: &Crew<'_>,
        n: usize,
        grid: &SampleGrid,
        limits: &Limits,
        xi: &[f64],
    ) -> f64 {
        let count = grid.count();
        self.ensure_parts(crew.size(), count);
        if !limits.chord {
            for part in &mut self.parts {
                part.scratch.target.fill(1.0);
            }
        }
        self.evaluate::<D>(crew, n, grid, limits, xi);
        if self.first && self.culprit_violates::<D>(n, count, limits) {
            return f64::INFINITY;
        }
        self.candidates::<D>(crew, n, count, limits);
        let broad = limits.broad_phase && n >= BROAD_PHASE_MIN_ROBOTS;
        self.check_pairs::<D>(crew, n, count, limits, broad);
        if self.first {
            self.culprit = self.parts[..crew.size()].iter().find_map(|p| p.found).map(|c| (c.i, c.j));
            if self.culprit.is_some() {
                return f64::INFINITY;
            }
        }
        self.per_block::<D>(crew, n, grid, limits);
        let blocks = &self.blocks[..n.div_ceil(ROBOT_BLOCK)];
        if blocks.iter().any(|b| b.violated) {
            return f64::INFINITY;
        }
        let (pairs, obstacles, box_sq) = blocks
            .iter()
            .fold((0.0, 0.0, 0.0), |(p, o, b), s: &BlockSums| (p + s.pair_sq, o + s.obstacle_sq, b + s.box_sq));
        (pairs + obstacles).sqrt() + box_sq.sqrt()
    }

    /// Whether the pair the last [`Self::clear`] stopped at still violates.
    fn culprit_violates<const D: usize>(&mut self, n: usize, count: usize, limits: &Limits) -> bool {
        let Some((i, j)) = self.culprit else {
            return false;
        };
        let inv = limits.robot_sep.map(|s| 1.0 / (s * s));
        let Projection { pos, steps, parts, .. } = self;
        let check = Check { pos, steps, n, count, limits, inv };
        check.violates::<D>(Candidate::whole(i, j, count), &mut parts[0].scratch)
    }

    /// Whether the robots of `xi` keep clear of the obstacles of `limits`
    /// at every instant of `grid` (pairs and box are not checked), stopping
    /// at the first violation.
    pub fn obstacles_clear(&mut self, dim: Dim, robots: usize, grid: &SampleGrid, limits: &Limits, xi: &[f64]) -> bool {
        let count = grid.count();
        if count == 0 || limits.obstacle_sep.is_empty() {
            return true;
        }
        let crew = Crew::alone();
        self.first = true;
        match dim {
            Dim::Two => {
                self.evaluate::<2>(&crew, robots, grid, limits, xi);
                self.per_block::<2>(&crew, robots, grid, limits);
            }
            Dim::Three => {
                self.evaluate::<3>(&crew, robots, grid, limits, xi);
                self.per_block::<3>(&crew, robots, grid, limits);
            }
        }
        self.first = false;
        !self.blocks[..robots.div_ceil(ROBOT_BLOCK)].iter().any(|b| b.violated)
    }

    /// Whether `xi` needs no correction at all against `limits` (what a zero
    /// [`Self::run`] means), stopping at the first violating pair or
    /// obstacle: the dense verification, which fails on most of its calls
    /// while a run converges. The pair a previous call stopped at is checked
    /// before any other (and before the broad phase); the verdict is the
    /// same either way, and for every crew size.
    pub fn clear(
        &mut self,
        crew: &Crew<'_>,
        dim: Dim,
        robots: usize,
        grid: &SampleGrid,
        limits: &Limits,
        xi: &[f64],
    ) -> bool {
        self.first = true;
        let residual = self.run(crew, dim, robots, grid, limits, xi);
        self.first = false;
        residual == 0.0
    }

    /// The corrections of the last [`Self::run`] mapped back to
    /// coefficients, `g = corr P` (`[axis][robot][coef]`).
    pub fn mapped(&self) -> &[f64] {
        &self.mapped
    }
}
