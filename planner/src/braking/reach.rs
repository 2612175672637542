//! Where one robot can be along one axis at one instant, at the least and
//! at the most, under any plan of the team's form that starts as it does,
//! ends at rest at its goal, and keeps its acceleration within the limit
//! at the dense verification instants ([`super::program`]).
//!
//! The acceleration limit is held along the axis alone (whatever the
//! axis, a slab around the limit's disc), so the interval holds every
//! reachable coordinate (a relaxation): two robots whose intervals at one instant keep them closer
//! than their separation on every combination of ends cannot be kept
//! apart by plans of the team's form ([`crate::problem::Problem::kept_with_goals`]).

use super::program::{AxisMotion, AxisProgram, Form, MAX_ROUNDS};
use crate::lp::Lp;

/// Every how many dense instants a program is first solved on (with the
/// instants that bounded the robot's earlier ones): about 25 us a
/// program here at degree 10, 30 us every 8th; every 32nd leaves fewer
/// instants than free coefficients at degree 16 and over (no bound).
const COARSE: usize = 16;

/// One robot's reach along one axis, at instant after instant: the
/// program's rows, and the instants whose acceleration rows bound its
/// solutions so far in each direction (where the next instant's program
/// starts, besides the coarse ones).
pub struct Reach {
    program: AxisProgram,
    cuts: [Vec<usize>; 2],
}

impl Reach {
    /// The reach of `motion` under plans of `form`; `None` where the
    /// degree leaves no free coefficient.
    pub fn new(form: Form, motion: AxisMotion) -> Option<Self> {
        Some(Self { program: AxisProgram::new(form, motion, 1.0)?, cuts: [Vec::new(), Vec::new()] })
    }

    /// The least and the most coordinate (m) along the axis that any plan
    /// of the form from the motion's start to its goal has at `tau`
    /// (normalised time), its acceleration within the limit at every dense
    /// instant; `None` where a program does not solve (no claim).
    pub fn at(&mut self, tau: f64) -> Option<(f64, f64)> {
        let lo = -extreme(&self.program, tau, -1.0, &mut self.cuts[0])?;
        Some((lo, extreme(&self.program, tau, 1.0, &mut self.cuts[1])?))
    }
}

/// The most `sign` times the coordinate at `tau` is, under `program`,
/// starting from the acceleration rows at `cuts` (and adding to them).
fn extreme(program: &AxisProgram, tau: f64, sign: f64, cuts: &mut Vec<usize>) -> Option<f64> {
    let (weights, known) = program.position(tau);
    let objective: Vec<f64> = weights.iter().map(|w| sign * w).collect();
    let mut lp = Lp::maximise(&objective);
    for s in program.coarse(COARSE).chain(cuts.iter().copied()) {
        program.add_acceleration(&mut lp, s);
    }
    for _ in 0..MAX_ROUNDS {
        let solution = lp.solve().ok()?;
        let Some(s) = program.over_limit(&solution.x) else {
            return Some(solution.value + sign * known);
        };
        cuts.push(s);
        program.add_acceleration(&mut lp, s);
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    const FORM: Form = Form { degree: 10, samples: 50, horizon: 5.0, max_acceleration: 3.0 };

    #[test]
    fn the_interval_holds_the_start_and_grows_no_faster_than_constant_acceleration() {
        let motion = AxisMotion { position: 0.2, velocity: 1.0, acceleration: 0.0, goal: -0.5 };
        let reach = |motion, tau| Reach::new(FORM, motion).unwrap().at(tau);
        let (lo, hi) = reach(motion, 0.0).unwrap();
        assert!((lo - 0.2).abs() < 1e-9 && (hi - 0.2).abs() < 1e-9, "{lo} {hi}");
        for t in [0.05, 0.1, 0.2, 0.4] {
            let (lo, hi) = reach(motion, t / FORM.horizon).unwrap();
            let (coast, spread) = (0.2 + 1.0 * t, 0.5 * 3.0 * t * t);
            // Within constant braking and constant pushing of the coast.
            assert!(lo >= coast - spread - 1e-9 && hi <= coast + spread + 1e-9, "{t}: {lo} {hi}");
            // A polynomial from zero acceleration reaches less of it.
            assert!(hi - lo < 2.0 * spread, "{t}: {lo} {hi}");
            assert!(lo < coast && coast < hi, "{t}: {lo} {hi}");
        }
        // The mirror image is the same.
        let mirror = AxisMotion { position: -0.2, velocity: -1.0, acceleration: 0.0, goal: 0.5 };
        let (lo, hi) = reach(motion, 0.04).unwrap();
        let (mlo, mhi) = reach(mirror, 0.04).unwrap();
        assert!((mlo + hi).abs() < 1e-9 && (mhi + lo).abs() < 1e-9);
    }
}
