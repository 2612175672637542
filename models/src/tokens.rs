//! What the flow policy's tokens hold: the plan's deviation from the
//! reference ([`crate::coding::Coding`]) at its interior Bernstein
//! coefficients, as the datasets store it, or at the positions of a few
//! interior instants ([`TokenSpace::Positions`]).
//!
//! The two are one linear map apart (the deviation's boundary coefficients
//! are zero, so its interior coefficients and its positions at as many
//! interior instants determine each other), but they weigh errors very
//! differently. A detour around an obstacle halfway along the path is a
//! bump at one or two instants; in coefficients it is a large alternating
//! pattern over all five (degree 10), and the map from coefficients to
//! positions shrinks errors along such patterns (condition number about
//! 66). A network trained on the flow-matching loss in coefficients spends
//! its capacity on coefficient patterns the positions barely show; in
//! positions the loss is the positional error itself (docs/LEARNED.md,
//! "Teaching the policy obstacles").

use candle_core::{Device, Tensor};
use flowopt_planner::basis::{BOUNDARY_ROWS, bernstein_row};
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use crate::ModelError;

/// The values of a plan token (one per robot, `dim x interior` values,
/// axis-major).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TokenSpace {
    /// The interior Bernstein coefficients' deviation from the reference
    /// (the datasets' layout; weights from before this choice).
    #[default]
    Coefficients,
    /// The deviation's positions at the interior instants
    /// `s / (interior + 1)` of the horizon, `s = 1..=interior`.
    Positions,
}

/// The linear maps between a token space and the datasets' coefficients
/// for one basis; the identity for [`TokenSpace::Coefficients`].
#[derive(Debug, Clone)]
pub struct TokenMap {
    /// `[W, W]` right factors: `coefficients · to_model` gives model
    /// tokens, `model · to_coefficients` coefficients; `None` for the
    /// identity.
    factors: Option<(Tensor, Tensor)>,
}

impl TokenMap {
    /// The map of `space` for `dim` axes and `n_xi` coefficients per curve.
    pub fn new(space: TokenSpace, dim: usize, n_xi: usize) -> Result<Self, ModelError> {
        let interior = n_xi.checked_sub(BOUNDARY_ROWS).filter(|&i| i > 0).ok_or_else(|| {
            ModelError::Config(format!("{n_xi} coefficients per curve leave no interior coefficient"))
        })?;
        if space == TokenSpace::Coefficients {
            return Ok(Self { factors: None });
        }
        let first = BOUNDARY_ROWS / 2;
        // positions = M coefficients, M[s][c] = b_{first + c}(tau_s).
        let m = DMatrix::from_fn(interior, interior, |s, c| {
            bernstein_row(n_xi - 1, 0, (s + 1) as f64 / (interior + 1) as f64)[first + c]
        });
        let inverse = m
            .clone()
            .try_inverse()
            .ok_or_else(|| ModelError::Config(format!("the positions of degree {} are not invertible", n_xi - 1)))?;
        // Right factors over a whole token: block diagonal, transposed.
        let width = dim * interior;
        let block_diagonal = |a: &DMatrix<f64>| -> Result<Tensor, ModelError> {
            let mut full = vec![0f32; width * width];
            for axis in 0..dim {
                let o = axis * interior;
                for (r, c) in (0..interior).flat_map(|r| (0..interior).map(move |c| (r, c))) {
                    full[(o + c) * width + o + r] = a[(r, c)] as f32;
                }
            }
            Ok(Tensor::from_vec(full, (width, width), &Device::Cpu)?)
        };
        Ok(Self { factors: Some((block_diagonal(&m)?, block_diagonal(&inverse)?)) })
    }

    /// Model tokens of coefficient tokens (`[..., W]`).
    pub fn to_model(&self, coefficients: &Tensor) -> Result<Tensor, ModelError> {
        Ok(match &self.factors {
            Some((to_model, _)) => coefficients.broadcast_matmul(to_model)?,
            None => coefficients.clone(),
        })
    }

    /// Coefficient tokens of model tokens (`[..., W]`).
    pub fn to_coefficients(&self, model: &Tensor) -> Result<Tensor, ModelError> {
        Ok(match &self.factors {
            Some((_, to_coefficients)) => model.broadcast_matmul(to_coefficients)?,
            None => model.clone(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::coding::Coding;
    use flowopt_planner::plan::JointPlan;
    use flowopt_planner::problem::{Dim, Team};
    use flowopt_planner::scenario::RandomScenario;

    /// Position tokens are the plan's positions minus the reference's at
    /// the interior instants, and map back to the same coefficients.
    #[test]
    fn position_tokens_are_the_deviation_at_interior_instants_and_invert() {
        let team = Team::default_for(Dim::Two, 3);
        let problem = RandomScenario::new(team.clone()).with_start_speed(0.3).generate(4).unwrap();
        let coding = Coding::new(&team).unwrap();
        let reference = coding.reference(&problem);
        let mut xi = reference.clone();
        for (k, x) in xi.iter_mut().enumerate() {
            if (3..8).contains(&(k % 11)) {
                *x += 0.03 * ((k * 7) % 5) as f64 - 0.05;
            }
        }
        let coefficients = coding.encode(&reference, &xi);
        let map = TokenMap::new(TokenSpace::Positions, 2, 11).unwrap();
        let tensor = Tensor::from_vec(coefficients.clone(), (1, 3, 10), &Device::Cpu).unwrap();
        let model = map.to_model(&tensor).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let (plan, straight) = (JointPlan::new(&team, xi), JointPlan::new(&team, reference));
        for s in 1..=5 {
            let t = team.horizon * s as f64 / 6.0;
            for (i, (p, r)) in plan.at(t).iter().zip(straight.at(t)).enumerate() {
                for axis in 0..2 {
                    let token = model[i * 10 + axis * 5 + s - 1];
                    assert!((f64::from(token) - (p.position[axis] - r.position[axis])).abs() < 1e-5);
                }
            }
        }
        let back = map.to_coefficients(&map.to_model(&tensor).unwrap()).unwrap().flatten_all().unwrap();
        for (a, b) in back.to_vec1::<f32>().unwrap().iter().zip(&coefficients) {
            assert!((a - b).abs() < 1e-4);
        }
    }
}
