//! How far apart two robots moving towards each other can stay at the
//! most, whatever both do: the certificate behind
//! [`crate::problem::Against::Closing`].
//!
//! With accelerations of at most `A` each (any direction, any time), the
//! offset between two robots `t` s after a start at offset `d` and relative
//! velocity `w` lies within `A t^2` of `d + w t` (their relative
//! acceleration is at most `2 A`). Where, at some instant, that whole ball
//! is closer than their separation, no pair of trajectories keeps them
//! apart: the pair must touch, whatever the planner. Everything here is in
//! the team's scaled metric (the separation 1): the caller scales the
//! offset and the velocity, and `A` by the larger of `1 / a` and `1 / b`
//! (the `spread`), so that the ball still holds every reachable offset in
//! 3D ([`crate::problem::Problem::start_violations`]).
//!
//! Only the instants the verification checks count (from its first dense
//! instant on): a pair measured within the tolerance of touching and
//! moving apart is not certified.
//!
//! ```
//! use flowopt_planner::closing::most_kept;
//! use nalgebra::Vector3;
//!
//! // Head-on at 1 m/s each, 0.25 m apart (separation 0.2 m), 3 m/s^2:
//! // 1.25 separations apart, closing at 10 separations a second, spread
//! // 15 a second squared. They meet whatever they do.
//! let (q, r) = (Vector3::new(1.25, 0.0, 0.0), Vector3::new(-10.0, 0.0, 0.0));
//! let (most, _) = most_kept(q, r, 15.0, (0.025, 5.0));
//! assert!(most < 1.0, "{most}");
//! // At rest, at the same offset: 1.25 separations.
//! let (most, _) = most_kept(q, Vector3::zeros(), 15.0, (0.025, 5.0));
//! assert!(most > 1.2, "{most}");
//! ```

use nalgebra::Vector3;

/// Golden-section steps of the search for the closest instant (the
/// bracket shrinks to 0.618^60 of the horizon).
const SEARCH_STEPS: usize = 60;

/// Where two robots at scaled offset `q` and relative velocity `r`, their
/// accelerations spreading the offset by at most `spread t^2`, cannot keep
/// their separation over `window` (s) whatever they do ([`most_kept`]
/// below 1): the most they can keep, and when. Pairs the bound
/// `||q|| - c^2 / 4 spread` (`c` the rate they close at) already keeps
/// apart are not searched: the check costs a few operations for most
/// pairs of a team.
pub fn unavoidable(q: Vector3<f64>, r: Vector3<f64>, spread: f64, window: (f64, f64)) -> Option<(f64, f64)> {
    let closing = closing_rate(&q, &r);
    if q.norm() - closing * closing / (4.0 * spread) >= 1.0 {
        return None;
    }
    let (most, at) = most_kept(q, r, spread, window);
    (most < 1.0).then_some((most, at))
}

/// The rate an offset `q` shrinks at under relative velocity `r` (both
/// scaled; 0 where it grows, `||r||` at a zero offset).
pub(crate) fn closing_rate(q: &Vector3<f64>, r: &Vector3<f64>) -> f64 {
    let gap = q.norm();
    if gap > 0.0 { (-q.dot(r) / gap).max(0.0) } else { r.norm() }
}

/// The most scaled distance two robots at scaled offset `q` and relative
/// velocity `r` can be sure to keep over the instants `window` (s), their
/// accelerations spreading the offset by at most `spread t^2`, and the
/// instant that bounds it: the minimum over `t` of `||q + r t|| + spread
/// t^2` (a convex function of `t`), beyond which no pair of trajectories
/// is at that instant.
pub fn most_kept(q: Vector3<f64>, r: Vector3<f64>, spread: f64, (from, to): (f64, f64)) -> (f64, f64) {
    let f = |t: f64| (q + r * t).norm() + spread * t * t;
    let ratio = (5.0_f64.sqrt() - 1.0) / 2.0;
    let (mut lo, mut hi) = (from, to.max(from));
    for _ in 0..SEARCH_STEPS {
        let (x1, x2) = (hi - ratio * (hi - lo), lo + ratio * (hi - lo));
        if f(x1) <= f(x2) {
            hi = x2;
        } else {
            lo = x1;
        }
    }
    let t = 0.5 * (lo + hi);
    (f(t), t)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The separation (m), and the spread of 3 m/s^2 in its units.
    const SEP: f64 = 0.2;
    const SPREAD: f64 = 3.0 / SEP;
    const WINDOW: (f64, f64) = (0.025, 5.0);

    #[test]
    fn the_bound_is_the_minimum_of_a_dense_scan_and_no_braking_or_swerving_pair_keeps_more() {
        let cases = [
            (Vector3::new(0.3, 0.05, 0.0), Vector3::new(-1.5, 0.2, 0.0)),
            (Vector3::new(0.5, 0.0, 0.0), Vector3::new(-2.0, 0.0, 0.0)),
            (Vector3::new(0.25, 0.1, 0.0), Vector3::new(0.0, -1.0, 0.0)),
            (Vector3::new(0.4, 0.0, 0.0), Vector3::new(1.0, 0.0, 0.0)),
        ];
        for (d, w) in cases {
            let (most, at) = most_kept(d / SEP, w / SEP, SPREAD, WINDOW);
            let scan = (0..=5000)
                .map(|k| WINDOW.0 + k as f64 * 0.001)
                .map(|t| (d + w * t).norm() / SEP + 3.0 * t * t / SEP)
                .fold(f64::INFINITY, f64::min);
            assert!((most - scan).abs() < 1e-4, "{most} against the scan's {scan}");
            assert!(at >= WINDOW.0);
            // Both braking at 3 m/s^2 along their relative velocity, or
            // swerving across it, are pairs of trajectories: neither keeps
            // more than the bound.
            let across = Vector3::new(-w.y, w.x, 0.0).normalize();
            for push in [w.normalize() * -6.0, across * 6.0] {
                let closest = (0..=5000)
                    .map(|k| WINDOW.0 + k as f64 * 0.001)
                    .map(|t| {
                        let v = w + push * t;
                        // Braking stops at rest; it does not reverse.
                        let t = if v.dot(&w) < 0.0 && push.dot(&w) < 0.0 { w.norm() / 6.0 } else { t };
                        (d + w * t + push * (0.5 * t * t)).norm() / SEP
                    })
                    .fold(f64::INFINITY, f64::min);
                assert!(closest <= most + 1e-9, "a pair keeps {closest}, above the bound {most}");
            }
            // The shortcut agrees with the search.
            assert_eq!(unavoidable(d / SEP, w / SEP, SPREAD, WINDOW).is_some(), most < 1.0);
        }
    }

    #[test]
    fn a_pair_moving_apart_keeps_its_distance() {
        let (most, _) = most_kept(Vector3::new(1.0, 0.0, 0.0), Vector3::new(5.0, 0.0, 0.0), SPREAD, WINDOW);
        assert!(most > 1.0, "{most}");
        assert!(unavoidable(Vector3::new(1.0, 0.0, 0.0), Vector3::new(5.0, 0.0, 0.0), SPREAD, WINDOW).is_none());
    }
}
