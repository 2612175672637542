//! The measures the evaluation report computes from planning records:
//! success within a time budget, residual decay bands and pairwise
//! distances over time. Pure functions, tested on hand-made
//! inputs with known answers.

use flowopt_planner::am::Residuals;
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::Team;

use crate::offline::harness::Record;
use crate::offline::stats::{mean, quantile};

/// Fraction of `records` that succeeded within `budget_ms` (each planned
/// without a deadline: an instance counts when its plan verified and took
/// at most the budget).
pub fn success_within(records: &[Record], budget_ms: f64) -> f64 {
    if records.is_empty() {
        return f64::NAN;
    }
    records.iter().filter(|r| r.success && r.time_ms <= budget_ms).count() as f64 / records.len() as f64
}

/// One residual series over iterations across many instances: the mean and
/// a 10th-90th percentile band at every iteration.
#[derive(Debug, Clone, PartialEq)]
pub struct Band {
    /// Mean over instances, per iteration.
    pub mean: Vec<f64>,
    /// 10th percentile, per iteration.
    pub low: Vec<f64>,
    /// 90th percentile, per iteration.
    pub high: Vec<f64>,
}

/// Which residual a [`Band`] follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Series {
    /// The primal residual (constraint violation).
    Primal,
    /// The fixed-point residual (size of the update).
    FixedPoint,
}

impl Band {
    /// The band of `series` over the first `length` iterations of
    /// `histories`. A history that stopped early (its study reached the
    /// target residual) keeps its last finite value; iterates without an
    /// update (fixed-point NaN) take the previous finite value.
    pub fn of(histories: &[&[Residuals]], series: Series, length: usize) -> Self {
        let pick = |r: &Residuals| match series {
            Series::Primal => r.primal,
            Series::FixedPoint => r.fixed_point,
        };
        let padded: Vec<Vec<f64>> = histories
            .iter()
            .filter(|h| h.iter().any(|r| pick(r).is_finite()))
            .map(|h| {
                let mut last = f64::NAN;
                (0..length)
                    .map(|l| {
                        if let Some(v) = h.get(l).map(pick).filter(|v| v.is_finite()) {
                            last = v;
                        }
                        last
                    })
                    .collect()
            })
            .collect();
        let mut band = Band { mean: Vec::new(), low: Vec::new(), high: Vec::new() };
        for l in 0..length {
            let column: Vec<f64> = padded.iter().map(|s| s[l]).filter(|v| v.is_finite()).collect();
            band.mean.push(mean(&column));
            band.low.push(quantile(&column, 0.1));
            band.high.push(quantile(&column, 0.9));
        }
        band
    }
}

/// Centre-to-centre distances between the robots of one plan over time.
#[derive(Debug, Clone, PartialEq)]
pub struct PairwiseProfile {
    /// Mean over robot pairs of the distance (m), per instant.
    pub mean: Vec<f64>,
    /// Smallest pair distance (m), per instant.
    pub min: Vec<f64>,
}

impl PairwiseProfile {
    /// The profile of coefficients `xi` of `team` at `samples` evenly spaced
    /// instants over the horizon.
    pub fn of(team: &Team, xi: &[f64], samples: usize) -> Self {
        let axes = team.dim.axes();
        let n = team.robots;
        let positions = JointPlan::new(team, xi.to_vec()).sampled(samples, 0);
        let at = |axis: usize, robot: usize, k: usize| positions[(axis * n + robot) * samples + k];
        let mut profile = PairwiseProfile { mean: Vec::with_capacity(samples), min: Vec::with_capacity(samples) };
        for k in 0..samples {
            let (mut sum, mut min, mut pairs) = (0.0, f64::INFINITY, 0usize);
            for i in 0..n {
                for j in i + 1..n {
                    let d = (0..axes).map(|a| (at(a, i, k) - at(a, j, k)).powi(2)).sum::<f64>().sqrt();
                    sum += d;
                    min = min.min(d);
                    pairs += 1;
                }
            }
            profile.mean.push(if pairs == 0 { f64::NAN } else { sum / pairs as f64 });
            profile.min.push(min);
        }
        profile
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_planner::am::Stop;
    use flowopt_planner::problem::Dim;

    fn record(success: bool, time_ms: f64) -> Record {
        Record {
            success,
            iterations: 1,
            time_ms,
            smoothness: 0.0,
            arc_length: 0.0,
            min_clearance: 0.0,
            max_acceleration: 0.0,
            primal_residual: 0.0,
            stop: Stop::Verified,
            iterations_to_0_01: None,
            iterations_to_0_001: None,
            stages: None,
            by: "test",
            xi: Vec::new(),
            study: Vec::new(),
        }
    }

    #[test]
    fn success_within_a_budget_counts_only_verified_plans_in_time() {
        let records = [record(true, 1.0), record(true, 5.0), record(false, 0.5), record(true, 20.0)];
        assert_eq!(success_within(&records, 0.1), 0.0);
        assert_eq!(success_within(&records, 1.0), 0.25);
        assert_eq!(success_within(&records, 10.0), 0.5);
        assert_eq!(success_within(&records, 1e9), 0.75);
        assert!(success_within(&[], 1.0).is_nan());
    }

    fn residuals(primal: &[f64], fixed_point: &[f64]) -> Vec<Residuals> {
        primal.iter().zip(fixed_point).map(|(&primal, &fixed_point)| Residuals { primal, fixed_point }).collect()
    }

    #[test]
    fn bands_hold_stopped_histories_at_their_last_value() {
        let a = residuals(&[4.0, 2.0, 1.0], &[1.0, 0.5, f64::NAN]);
        let b = residuals(&[8.0], &[f64::NAN]);
        let primal = Band::of(&[&a, &b], Series::Primal, 4);
        assert_eq!(primal.mean, vec![6.0, 5.0, 4.5, 4.5]);
        assert_eq!(primal.low, vec![4.0, 2.0, 1.0, 1.0]);
        assert_eq!(primal.high, vec![8.0, 8.0, 8.0, 8.0]);
        // `b` never has a finite fixed-point residual and is left out; `a`
        // holds its last update's size.
        let fixed = Band::of(&[&a, &b], Series::FixedPoint, 3);
        assert_eq!(fixed.mean, vec![1.0, 0.5, 0.5]);
    }

    /// Coefficients for robots that stand still at `points` (2D).
    fn standing(team: &Team, points: &[[f64; 2]]) -> Vec<f64> {
        let nx = team.degree + 1;
        let mut xi = Vec::new();
        for axis in 0..2 {
            for p in points {
                xi.extend(std::iter::repeat_n(p[axis], nx));
            }
        }
        xi
    }

    #[test]
    fn pairwise_profile_of_robots_at_known_distances() {
        let team = Team::default_for(Dim::Two, 3);
        // A 3-4-5 triangle: pair distances 3, 4 and 5.
        let xi = standing(&team, &[[0.0, 0.0], [3.0, 0.0], [0.0, 4.0]]);
        let profile = PairwiseProfile::of(&team, &xi, 7);
        for (m, n) in profile.mean.iter().zip(&profile.min) {
            assert!((m - 4.0).abs() < 1e-12 && (n - 3.0).abs() < 1e-12);
        }
    }

    #[test]
    fn pairwise_profile_follows_robots_that_meet() {
        let team = Team::default_for(Dim::Two, 2);
        let nx = team.degree + 1;
        // Robot 0 moves linearly from x = -1 to x = 1 (Bernstein coefficients
        // evenly spaced give a linear path); robot 1 stands at the origin.
        let mut xi: Vec<f64> = (0..nx).map(|k| -1.0 + 2.0 * k as f64 / (nx - 1) as f64).collect();
        xi.extend(std::iter::repeat_n(0.0, nx));
        xi.extend(std::iter::repeat_n(0.0, 2 * nx));
        let profile = PairwiseProfile::of(&team, &xi, 5);
        let expected = [1.0, 0.5, 0.0, 0.5, 1.0];
        for (got, want) in profile.mean.iter().zip(expected) {
            assert!((got - want).abs() < 1e-12, "{got} vs {want}");
        }
        assert_eq!(profile.min, profile.mean);
    }
}
