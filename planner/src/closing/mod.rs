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
//! instant on), and only below the tolerance a start may be within
//! ([`crate::problem::FEASIBILITY_TOLERANCE`]): a pair measured within it
//! is accepted, and not certified. Where the ball leaves a pair near
//! touching, `with_goals.rs` bounds it again under plans of the team's
//! form (`Problem::unavoidable_pair`, which the validation calls).
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

pub mod with_goals;

/// Golden-section steps of the search for the closest instant (the
/// bracket shrinks to 0.618^60 of the horizon).
const SEARCH_STEPS: usize = 60;

/// Where two robots at scaled offset `q` and relative velocity `r`, their
/// accelerations spreading the offset by at most `spread t^2`, cannot keep
/// `touching` (the separation less a tolerance) over `window` (s)
/// whatever they do ([`most_kept`] below it): the most they can keep, and
/// when. Pairs the bound
/// `||q|| - c^2 / 4 spread` (`c` the rate they close at) already keeps
/// apart are not searched: the check costs a few operations for most
/// pairs of a team.
pub fn unavoidable(
    q: Vector3<f64>,
    r: Vector3<f64>,
    spread: f64,
    window: (f64, f64),
    touching: f64,
) -> Option<(f64, f64)> {
    let closing = closing_rate(&q, &r);
    if q.norm() - closing * closing / (4.0 * spread) >= touching {
        return None;
    }
    let (most, at) = most_kept(q, r, spread, window);
    (most < touching).then_some((most, at))
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

    /// Where robots at offset `d` (m) and relative velocity `w` (m/s)
    /// are, scaled, `t` s on, their relative acceleration `push` (m/s^2)
    /// constant.
    fn apart(d: Vector3<f64>, w: Vector3<f64>, push: Vector3<f64>, t: f64) -> f64 {
        (d + w * t + push * (0.5 * t * t)).norm() / SEP
    }

    #[test]
    fn the_bound_is_what_pushing_apart_reaches_at_its_instant_and_no_braking_or_swerving_pair_keeps_more() {
        let cases = [
            (Vector3::new(0.3, 0.05, 0.0), Vector3::new(-1.5, 0.2, 0.0)),
            (Vector3::new(0.5, 0.0, 0.0), Vector3::new(-2.0, 0.0, 0.0)),
            (Vector3::new(0.25, 0.1, 0.0), Vector3::new(0.0, -1.0, 0.0)),
            (Vector3::new(0.4, 0.0, 0.0), Vector3::new(1.0, 0.0, 0.0)),
        ];
        for (d, w) in cases {
            let (most, at) = most_kept(d / SEP, w / SEP, SPREAD, WINDOW);
            assert!(at >= WINDOW.0);
            // Both robots accelerating apart at 3 m/s^2 along the offset
            // at that instant reach the bound there: no pair is farther
            // apart at that instant, this one is that far.
            let along = (d + w * at).normalize();
            assert!((apart(d, w, along * 6.0, at) - most).abs() < 1e-9, "{most}");
            // A pair that brakes along its relative velocity, or swerves
            // across it, at 3 m/s^2 each is no farther apart there.
            let across = Vector3::new(-w.y, w.x, 0.0).normalize();
            let brake = w.normalize() * -6.0;
            let stop = w.norm() / 6.0;
            let braked = if at < stop { apart(d, w, brake, at) } else { apart(d, w, brake, stop) };
            assert!(braked <= most + 1e-9 && apart(d, w, across * 6.0, at) <= most + 1e-9);
            // The shortcut never skips a pair the search would certify.
            for touching in [0.5, 0.99, 1.0, 1.5, 3.0] {
                assert_eq!(unavoidable(d / SEP, w / SEP, SPREAD, WINDOW, touching).is_some(), most < touching);
            }
        }
    }

    #[test]
    fn a_pair_moving_apart_keeps_its_distance_and_one_at_rest_within_the_tolerance_is_not_certified() {
        let (q, r) = (Vector3::new(1.0, 0.0, 0.0), Vector3::new(5.0, 0.0, 0.0));
        assert!(most_kept(q, r, SPREAD, WINDOW).0 > 1.0);
        assert!(unavoidable(q, r, SPREAD, WINDOW, 0.99).is_none());
        // At rest 0.9903 separations apart: 0.0094 more by the first instant.
        let q = Vector3::new(0.9903, 0.0, 0.0);
        assert!(most_kept(q, Vector3::zeros(), SPREAD, WINDOW).0 < 1.0);
        assert!(unavoidable(q, Vector3::zeros(), SPREAD, WINDOW, 0.99).is_none());
    }
}
