//! The plan's bound with the robot's goal: how far past a side of the box
//! one robot goes at the least along one axis under any plan of the
//! team's form that starts as it does, ends at rest at its goal, and keeps
//! its acceleration within the limit at the dense verification instants.
//!
//! The module's table ([`super::least_excursion`]) frees every
//! coefficient after the start's and checks the first
//! [`super::CHECKED_SHARE`] of the horizon, so that it depends on the
//! speed alone; this program fixes the goal's coefficients too and checks
//! the whole horizon, so it is solved per start (about a millisecond
//! here). On 16-robot starts at 0.3-1.0 m/s it certified starts the table
//! left to the optimiser, which ran them to its iteration cap 3-9 mm out
//! of the box (docs/experiments/2026-11-28-plans-from-motion-within-the-limit.md).
//!
//! Only the approached side is constrained and only the verification's
//! instants, so that the program's value is a lower bound on every plan's
//! (a relaxation): past the box's tolerance by it, no plan of the team's
//! form within the limit passes the verification.

use std::collections::VecDeque;
use std::sync::Mutex;

use microlp::{ComparisonOp, OptimizationDirection, Problem as Lp};

use crate::basis::{BOUNDARY_ROWS, DENSE_FACTOR, bernstein_row};

/// One robot's motion along one axis, towards one side of the box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisStart {
    /// Start position (m).
    pub position: f64,
    /// Start velocity (m/s).
    pub velocity: f64,
    /// Start acceleration (m/s^2).
    pub acceleration: f64,
    /// Goal (m), reached at rest at the horizon.
    pub goal: f64,
    /// The side's coordinate (m).
    pub side: f64,
    /// Whether the side is the upper one.
    pub upper: bool,
}

/// The plans' form: degree, constraint samples, horizon (s), and the
/// largest acceleration (m/s^2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Form {
    /// Bernstein degree.
    pub degree: usize,
    /// Constraint samples (the dense instants are [`DENSE_FACTOR`] times as many).
    pub samples: usize,
    /// Horizon (s).
    pub horizon: f64,
    /// Largest acceleration (m/s^2).
    pub max_acceleration: f64,
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
    let key = Key::of(form, start);
    {
        let memo = SOLVED.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some((_, value)) = memo.iter().find(|(k, _)| *k == key) {
            return *value;
        }
    }
    let value = solve(form, start);
    let mut memo = SOLVED.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    if memo.len() == MEMO {
        memo.pop_front();
    }
    memo.push_back((key, value));
    value
}

/// How many programs [`least_past_side`] keeps.
const MEMO: usize = 256;

/// The programs solved lately.
static SOLVED: Mutex<VecDeque<(Key, Option<f64>)>> = Mutex::new(VecDeque::new());

/// A form and a start, bit for bit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Key([u64; 10]);

impl Key {
    fn of(form: Form, start: AxisStart) -> Self {
        Self([
            form.degree as u64,
            form.samples as u64,
            form.horizon.to_bits(),
            form.max_acceleration.to_bits(),
            start.position.to_bits(),
            start.velocity.to_bits(),
            start.acceleration.to_bits(),
            start.goal.to_bits(),
            start.side.to_bits(),
            u64::from(start.upper),
        ])
    }
}

/// [`least_past_side`]'s program, solved.
fn solve(form: Form, start: AxisStart) -> Option<f64> {
    let Form { degree, samples, horizon, max_acceleration } = form;
    let n_xi = degree + 1;
    let fixed = BOUNDARY_ROWS / 2;
    if n_xi <= BOUNDARY_ROWS || samples < 2 {
        return None;
    }
    // The side's direction: distances past it are `sign * p - sign * side`.
    let sign = if start.upper { 1.0 } else { -1.0 };
    // Start: position, velocity, acceleration; end: the goal at rest
    // (normalised time, coefficients along the side's direction).
    let n = degree as f64;
    let c0 = sign * start.position;
    let c1 = c0 + sign * start.velocity * horizon / n;
    let c2 = 2.0 * c1 - c0 + sign * start.acceleration * horizon * horizon / (n * (n - 1.0));
    let goal = sign * start.goal;
    let known_coefficient = |k: usize| match k {
        0 => Some(c0),
        1 => Some(c1),
        2 => Some(c2),
        k if k + fixed >= n_xi => Some(goal),
        _ => None,
    };
    let limit = max_acceleration * horizon * horizon;
    // Every dense instant's rows: the free coefficients' weights and what
    // the known ones give, for the position and the acceleration.
    let dense = DENSE_FACTOR * samples;
    let rows: Vec<[(Vec<f64>, f64); 2]> = (0..dense)
        .map(|s| {
            let tau = s as f64 / (dense - 1) as f64;
            [0, 2].map(|order| {
                let row = bernstein_row(degree, order, tau);
                let known = row.iter().enumerate().filter_map(|(k, b)| known_coefficient(k).map(|c| c * b)).sum();
                (row[fixed..n_xi - fixed].to_vec(), known)
            })
        })
        .collect();
    let mut lp = Lp::new(OptimizationDirection::Minimize);
    let free: Vec<_> = (fixed..n_xi - fixed).map(|_| lp.add_var(0.0, (f64::NEG_INFINITY, f64::INFINITY))).collect();
    let past = lp.add_var(1.0, (f64::NEG_INFINITY, f64::INFINITY));
    // An instant's constraints: `sign p - past <= sign side`, `|a| <= limit`.
    type Row = (Vec<(microlp::Variable, f64)>, ComparisonOp, f64);
    let constraints = |s: usize| -> [Row; 3] {
        let [(position, p_known), (acceleration, a_known)] = &rows[s];
        let terms = |weights: &[f64]| -> Vec<_> { free.iter().zip(weights).map(|(v, b)| (*v, *b)).collect() };
        let mut at = terms(position);
        at.push((past, -1.0));
        [
            (at, ComparisonOp::Le, sign * start.side - p_known),
            (terms(acceleration), ComparisonOp::Le, limit - a_known),
            (terms(acceleration), ComparisonOp::Ge, -limit - a_known),
        ]
    };
    // Solved on every [`COARSE`]-th instant, then the instants the solution
    // breaks added until it breaks none: the program on every instant,
    // solved on a few of them.
    for s in (0..dense).step_by(COARSE).chain([dense - 1]) {
        for (terms, op, rhs) in constraints(s) {
            lp.add_constraint(&terms, op, rhs);
        }
    }
    let mut solution = lp.solve().ok()?.into_solution().ok()?;
    for _ in 0..MAX_ROUNDS {
        let x: Vec<f64> = free.iter().map(|v| solution.var_value(*v)).collect();
        let value = |weights: &[f64], known: f64| known + weights.iter().zip(&x).map(|(w, c)| w * c).sum::<f64>();
        let side = sign * start.side + solution.var_value(past);
        // The instants that break the position and the acceleration rows
        // most, added one each per round.
        let worst = |row: usize, excess: &dyn Fn(f64) -> f64| {
            (0..dense)
                .map(|s| {
                    let (weights, known) = &rows[s][row];
                    (s, excess(value(weights, *known)))
                })
                .filter(|(_, e)| *e > TOLERANCE)
                .max_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(s, _)| s)
        };
        let past_side = worst(0, &|p| p - side);
        let over_limit = worst(1, &|a| (a.abs() - limit) / limit);
        if past_side.is_none() && over_limit.is_none() {
            return Some(solution.objective());
        }
        for s in past_side.into_iter().chain(over_limit) {
            for (terms, op, rhs) in constraints(s) {
                solution = solution.add_constraint(&terms, op, rhs).ok()?.into_solution().ok()?;
            }
        }
    }
    None
}

/// Every how many dense instants the program is first solved on.
const COARSE: usize = 8;

/// Rounds of added instants before the program gives up (no claim).
const MAX_ROUNDS: usize = 100;

/// How far past a constraint (m, or relative for the acceleration) a
/// solution may be and still count as keeping it.
const TOLERANCE: f64 = 1e-9;

#[cfg(test)]
mod tests {
    use super::*;

    const FORM: Form = Form { degree: 10, samples: 50, horizon: 5.0, max_acceleration: 3.0 };

    fn towards_upper(position: f64, velocity: f64, goal: f64) -> AxisStart {
        AxisStart { position, velocity, acceleration: 0.0, goal, side: 1.0, upper: true }
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
                AxisStart { position: -p, velocity: -v, goal: -g, side: -1.0, upper: false, ..towards_upper(p, v, g) },
            )
            .unwrap();
            assert!((mirror - to_goal).abs() < 1e-9, "{mirror} {to_goal}");
        }
    }
}
