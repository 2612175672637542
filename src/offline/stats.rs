//! Summary statistics for benchmark reports.

/// The `q`-quantile (0..=1) of `values` by nearest rank; NaN when empty.
pub fn quantile(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let rank = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
    sorted[rank - 1]
}

/// The arithmetic mean; NaN when empty.
pub fn mean(values: &[f64]) -> f64 {
    if values.is_empty() { f64::NAN } else { values.iter().sum::<f64>() / values.len() as f64 }
}

/// Mean, smallest and largest iteration count over the instances that
/// reached a residual level, and the fraction that did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IterationStats {
    /// Mean over the instances that reached the level (NaN if none did).
    pub mean: f64,
    /// Fewest iterations (NaN if none reached it).
    pub min: f64,
    /// Most iterations (NaN if none reached it).
    pub max: f64,
    /// Fraction of all instances that reached it.
    pub reached: f64,
}

impl IterationStats {
    /// Statistics of per-instance counts (`None`: the level was not reached).
    pub fn of(counts: impl IntoIterator<Item = Option<usize>>) -> Self {
        let counts: Vec<Option<usize>> = counts.into_iter().collect();
        let reached: Vec<f64> = counts.iter().flatten().map(|&c| c as f64).collect();
        let extreme = |f: fn(f64, f64) -> f64| reached.iter().copied().reduce(f).unwrap_or(f64::NAN);
        Self {
            mean: mean(&reached),
            min: extreme(f64::min),
            max: extreme(f64::max),
            reached: if counts.is_empty() { f64::NAN } else { reached.len() as f64 / counts.len() as f64 },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_quantiles() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(quantile(&v, 0.5), 50.0);
        assert_eq!(quantile(&v, 0.95), 95.0);
        assert_eq!(quantile(&v, 1.0), 100.0);
        assert_eq!(quantile(&[3.0, 1.0, 2.0], 0.5), 2.0);
        assert!(quantile(&[], 0.5).is_nan());
        assert_eq!(mean(&[1.0, 2.0, 6.0]), 3.0);
    }

    #[test]
    fn iteration_stats_skip_instances_that_never_reached_the_level() {
        let s = IterationStats::of([Some(10), None, Some(30), Some(20)]);
        assert_eq!((s.mean, s.min, s.max, s.reached), (20.0, 10.0, 30.0, 0.75));
        let none = IterationStats::of([None, None]);
        assert!(none.mean.is_nan() && none.min.is_nan() && none.max.is_nan());
        assert_eq!(none.reached, 0.0);
    }
}
