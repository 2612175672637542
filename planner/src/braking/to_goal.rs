//! The plan's bound with the robot's goal: how far past a side of the box
//! one robot goes at the least along one axis under any plan of the
//! team's form that starts as it does, ends at rest at its goal, and keeps
//! its acceleration within the limit at the dense verification instants.
//!
//! The module's table ([`super::least_excursion`]) frees every
//! coefficient after the start's and checks the first
//! [`super::CHECKED_SHARE`] of the horizon, so that it depends on the
//! speed alone; this program fixes the goal's coefficients too and checks
//! the whole horizon, so it is solved per start (about 50 us here at
//! degree 10, [`crate::lp`]). On 16-robot starts at 0.3-1.0 m/s it
//! certified starts the table left to the optimiser, which ran them to its
//! iteration cap 3-9 mm out of the box
//! (docs/experiments/2026-11-28-plans-from-motion-within-the-limit.md).
//!
//! Only the approached side is constrained and only the verification's
//! instants, so that the program's value is a lower bound on every plan's
//! (a relaxation): past the box's tolerance by it, no plan of the team's
//! form within the limit passes the verification.

use super::program::{AxisMotion, AxisProgram, Form, MAX_ROUNDS, Memo};
use crate::lp::Lp;

/// One robot's motion along one axis, towards one side of the box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisStart {
    /// Its start and goal along the axis.
    pub motion: AxisMotion,
    /// The side's coordinate (m).
    pub side: f64,
    /// Whether the side is the upper one.
    pub upper: bool,
}

/// The least distance (m) past the side that any plan of `form` from
/// `start` to its goal reaches at a dense instant, its acceleration within
/// the limit at each (negative: that much room to spare at the least);
/// `None` where the program does not solve (no claim) or the degree leaves
/// no free coefficient.
///
/// The last 256 programs' values are kept, so that the checks of one
/// problem (its validation, the planner's floors, the verdict's) solve
/// each once.
pub fn least_past_side(form: Form, start: AxisStart) -> Option<f64> {
    SOLVED.get_or(Key::of(form, start), || solve(form, start))
}

/// Every how many dense instants the program is first solved on.
const COARSE: usize = 8;

/// The programs solved lately.
static SOLVED: Memo<Key, Option<f64>> = Memo::new();

/// A form and a start, bit for bit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Key([u64; 10]);

impl Key {
    fn of(form: Form, start: AxisStart) -> Self {
        let [a, b, c, d, e, f, g, h] = form.bits_with(start.motion);
        Self([a, b, c, d, e, f, g, h, start.side.to_bits(), u64::from(start.upper)])
    }
}

/// [`least_past_side`]'s program, solved.
fn solve(form: Form, start: AxisStart) -> Option<f64> {
    // The side's direction: distances past it are `sign * p - sign * side`.
    let sign = if start.upper { 1.0 } else { -1.0 };
    let program = AxisProgram::new(form, start.motion, sign)?;
    // The variables: the free coefficients, then how far past the side
    // (minimised: its negative maximised).
    let free = program.free();
    let mut objective = vec![0.0; free + 1];
    objective[free] = -1.0;
    let mut lp = Lp::maximise(&objective);
    // An instant's rows: `sign p - past <= sign side`, `|a| <= limit`.
    let add = |lp: &mut Lp, s: usize| {
        let (position, known) = program.at(s, 0);
        let mut row = position.to_vec();
        row.push(-1.0);
        lp.add_le(&row, sign * start.side - known);
        program.add_acceleration(lp, s);
    };
    for s in program.coarse(COARSE) {
        add(&mut lp, s);
    }
    for _ in 0..MAX_ROUNDS {
        let solution = lp.solve().ok()?;
        let (x, past) = solution.x.split_at(free);
        let side = sign * start.side + past[0];
        // The instants that break the position and the acceleration rows
        // most, added one each per round.
        let past_side = program.worst(x, 0, &|p| p - side);
        let over_limit = program.over_limit(x);
        if past_side.is_none() && over_limit.is_none() {
            return Some(-solution.value);
        }
        for s in past_side.into_iter().chain(over_limit) {
            add(&mut lp, s);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    const FORM: Form = Form { degree: 10, samples: 50, horizon: 5.0, max_acceleration: 3.0 };

    fn towards_upper(position: f64, velocity: f64, goal: f64) -> AxisStart {
        AxisStart { motion: AxisMotion { position, velocity, acceleration: 0.0, goal }, side: 1.0, upper: true }
    }

    #[test]
    fn a_start_far_from_the_side_has_room_and_a_fast_one_close_to_it_has_none() {
        let far = least_past_side(FORM, towards_upper(0.0, 0.3, 0.0)).unwrap();
        assert!(far < -0.5, "{far}");
        let close = least_past_side(FORM, towards_upper(0.95, 1.0, 0.0)).unwrap();
        // At least the physical stop, 1/6 m from 0.95 m.
        assert!(close >= 0.95 + 1.0 / 6.0 - 1.0 - 1e-9, "{close}");
    }

    #[test]
    fn it_is_at_least_the_table_and_the_mirror_image_is_the_same() {
        for (p, v, g) in [(0.9, 0.6, 0.5), (0.97, 0.3, -0.8), (0.8, 1.0, 0.9)] {
            let to_goal = least_past_side(FORM, towards_upper(p, v, g)).unwrap();
            let table = p + super::super::least_excursion(10, 50, 5.0, 3.0, 0.0, v) - 1.0;
            assert!(to_goal >= table - 1e-6, "{p} {v} {g}: {to_goal} below the table's {table}");
            let mirror = least_past_side(
                FORM,
                AxisStart {
                    motion: AxisMotion { position: -p, velocity: -v, acceleration: 0.0, goal: -g },
                    side: -1.0,
                    upper: false,
                },
            )
            .unwrap();
            assert!((mirror - to_goal).abs() < 1e-9, "{mirror} {to_goal}");
        }
    }
}
