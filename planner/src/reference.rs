//! The smoothest curves meeting a problem's boundary conditions: the
//! optimiser's cold start and the reference the learned planner's samples
//! are written relative to.
//!
//! With the position, velocity and acceleration fixed at both ends, the first
//! and last three Bernstein coefficients of every robot and axis are
//! determined; only the interior ones ([`SmoothReference::interior`]) are
//! free, and the reference picks them to minimise the squared acceleration.

use std::ops::Range;

use crate::basis::{BOUNDARY_ROWS, BasisError};
use crate::kkt::{KktError, SmallKkt};
use crate::problem::{Problem, Team};

/// The per-robot, per-axis smoothest curve through the boundary values.
#[derive(Debug, Clone)]
pub struct SmoothReference {
    n_xi: usize,
    kkt: SmallKkt,
}

/// Why the reference could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReferenceError {
    /// The team's basis is invalid.
    #[error("ReferenceError::Basis: {0}")]
    Basis(#[from] BasisError),
    /// The minimum-acceleration system is singular.
    #[error("ReferenceError::Kkt: {0}")]
    Kkt(#[from] KktError),
}

impl SmoothReference {
    /// The reference for `team`'s basis.
    pub fn new(team: &Team) -> Result<Self, ReferenceError> {
        let basis = team.basis()?;
        let kkt = SmallKkt::new(&basis.acceleration_gram(), &basis.boundary_rows(), basis.n_xi())?;
        Ok(Self { n_xi: basis.n_xi(), kkt })
    }

    /// Coefficients per curve.
    pub fn n_xi(&self) -> usize {
        self.n_xi
    }

    /// The coefficients the boundary conditions leave free.
    pub fn interior(&self) -> Range<usize> {
        BOUNDARY_ROWS / 2..self.n_xi - BOUNDARY_ROWS / 2
    }

    /// The smoothest curve for one row of boundary values
    /// (`[p0, v0, a0, pT, vT, aT]` in normalised time) into `out`.
    pub fn curve(&self, boundary: &[f64], out: &mut [f64]) {
        self.kkt.apply(&vec![0.0; self.n_xi], boundary, out);
    }

    /// The reference coefficients of every robot, `[axis][robot][coef]`.
    pub fn coefficients(&self, problem: &Problem) -> Vec<f64> {
        let b = problem.boundary_values();
        let mut xi = vec![0.0; b.len() / BOUNDARY_ROWS * self.n_xi];
        for (row, bv) in xi.chunks_exact_mut(self.n_xi).zip(b.chunks_exact(BOUNDARY_ROWS)) {
            self.curve(bv, row);
        }
        xi
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::Metrics;
    use crate::plan::JointPlan;
    use crate::problem::Dim;
    use crate::scenario::RandomScenario;

    #[test]
    fn the_reference_meets_the_boundary_conditions_and_only_the_interior_is_free() {
        let team = Team::default_for(Dim::Two, 4);
        let problem = RandomScenario::new(team.clone()).with_start_speed(0.5).generate(2).unwrap();
        let reference = SmoothReference::new(&team).unwrap();
        let xi = reference.coefficients(&problem);
        let m = Metrics::measure(&problem, &JointPlan::new(&team, xi.clone()));
        assert!(m.boundary_error < 1e-9, "boundary error {}", m.boundary_error);
        assert_eq!(reference.interior(), 3..8);
        // Moving an interior coefficient keeps the boundary conditions; moving
        // an end coefficient breaks them.
        let mut inner = xi.clone();
        inner[5] += 0.1;
        assert!(Metrics::measure(&problem, &JointPlan::new(&team, inner)).boundary_error < 1e-9);
        let mut end = xi;
        end[2] += 0.1;
        assert!(Metrics::measure(&problem, &JointPlan::new(&team, end)).boundary_error > 1e-3);
    }
}
