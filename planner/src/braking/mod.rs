//! How far a robot moving towards a side of the box goes before it can
//! turn back, at the least, under any plan it can follow: the certificate
//! behind [`crate::problem::Against::Braking`].
//!
//! Two lower bounds, the larger taken, and, for a start near a side, a
//! third with the robot's goal ([`least_past_side`], in `to_goal.rs`;
//! [`crate::problem::Problem::least_excursion`] takes the largest; it and
//! [`Reach`], where a robot can be at an instant, which the pair
//! certificate of [`crate::closing`] reads, are linear programs on one
//! robot's plan along one axis, `program.rs`):
//!
//! - the physical one, `v^2 / 2a`: constant braking at the largest
//!   acceleration `a`, for any trajectory and any start acceleration;
//! - the plan's: a plan is one polynomial of the team's degree over its
//!   horizon, and from a start at zero acceleration it cannot brake at
//!   once. The least excursion of such a polynomial from a start at speed
//!   `v`, its acceleration within `a` at the dense verification instants,
//!   is a linear program over its coefficients. Relaxed to be the same for
//!   every start and goal (only the start's position, velocity and zero
//!   acceleration are fixed; every later coefficient is free; only the
//!   instants of the first [`CHECKED_SHARE`] of the horizon count), it
//!   depends on the speed alone: it is solved per team shape on a grid of
//!   speeds ([`SPEED_STEP`]; each on first use, or all by [`prepare`]).
//!   Between grid speeds it is read on the line through the two grid
//!   speeds at or below `v`, extended to `v`: the program's value is
//!   convex in the speed (the speed enters only its right-hand side, and
//!   linearly), so that line stays below it beyond the upper one (a test
//!   checks it against the program solved at `v`). Read at the grid speed
//!   below instead, it fell short by up to the slope times the step: 0.9,
//!   1.7 and 7.2 mm at the test's 0.119, 0.219 and 0.999 m/s, against the
//!   box's 2 mm tolerance. In a process that asked for it
//!   ([`solve_in_background`]: the daemon) no caller waits for one: a
//!   speed not solved yet is handed to a background thread and read, until
//!   it and the one below are solved, at the fastest solved grid speed
//!   below it (a smaller bound, still a lower one). Solved
//!   exactly, the relaxation can only be smaller than the true least
//!   excursion, so a robot whose room to the side is less than this (by
//!   more than the box's tolerance) leaves the box under every plan of the
//!   team's form that keeps its acceleration (1.25-3.2 times the physical
//!   bound at 0.05-1.5 m/s for the default team at 3 m/s^2).
//!
//! ```
//! use flowopt_planner::braking::least_excursion;
//!
//! // Degree 10, 50 samples, 5 s, 3 m/s^2: at 1 m/s at least the physical
//! // 1/6 m, and more for a polynomial that starts at zero acceleration.
//! let e = least_excursion(10, 50, 5.0, 3.0, 0.0, 1.0);
//! assert!(e > 1.0 / 6.0 && e < 0.25, "{e}");
//! ```

use std::sync::Mutex;
use std::sync::OnceLock;

use crossbeam::channel::{Sender, unbounded};

use crate::basis::{BOUNDARY_ROWS, DENSE_FACTOR, bernstein_row};
use crate::lp::Lp;

mod excess;
mod program;
mod reach;
mod to_goal;

pub(crate) use program::Memo;
pub use program::{AxisMotion, Form};
pub use reach::Reach;
pub use to_goal::{AxisStart, least_past_side};

/// Starts whose table bound ([`least_excursion`]) leaves them more room
/// than this (m) to the side are not checked with their goal
/// ([`past_side_with_goal`]).
pub const GOAL_CHECK_NEAR: f64 = 0.05;

/// [`least_past_side`] where this process solves a program per start:
/// not in one that solves the table in the background
/// ([`solve_in_background`]: the daemon, whose answers never wait for a
/// program; it keeps the table's bound).
pub fn past_side_with_goal(form: Form, start: AxisStart) -> Option<f64> {
    if !solves_programs() {
        return None;
    }
    least_past_side(form, start)
}

/// Whether this process solves a program per start ([`least_past_side`],
/// [`Reach`]): not one that solves the table in the background
/// ([`solve_in_background`]).
pub fn solves_programs() -> bool {
    BACKGROUND.get().is_none()
}

/// Spacing of the speeds the plan's bound is solved at (m/s).
pub const SPEED_STEP: f64 = 0.02;

/// The fastest speed the plan's bound is solved at (m/s); faster starts get
/// the physical bound alone (a snapshot's robots are refused beyond twice
/// the robots' top speed, 3 m/s by default).
pub const TABLE_TOP_SPEED: f64 = 3.0;

/// A start acceleration (m/s^2) this small counts as zero (a plan
/// evaluated at its origin gives one within rounding).
pub const AT_REST_ACCELERATION: f64 = 1e-9;

/// The share of the horizon whose dense instants the plan's bound checks.
pub const CHECKED_SHARE: f64 = 0.4;

/// The least excursion (m) towards a side of a robot starting at `speed`
/// (m/s) towards it with acceleration `start_acceleration` along it (m/s^2,
/// positive towards it), for plans of `degree` over `horizon` s with
/// `samples` constraint samples and robots of largest acceleration
/// `max_acceleration` (m/s^2): the larger of the two lower bounds of the
/// module's doc (the plan's only for a start at zero acceleration).
pub fn least_excursion(
    degree: usize,
    samples: usize,
    horizon: f64,
    max_acceleration: f64,
    start_acceleration: f64,
    speed: f64,
) -> f64 {
    if speed <= 0.0 {
        return 0.0;
    }
    let physical = speed * speed / (2.0 * max_acceleration);
    if start_acceleration.abs() > AT_REST_ACCELERATION || speed > TABLE_TOP_SPEED {
        return physical;
    }
    physical.max(plan_bound_near(Shape::of(degree, samples, horizon, max_acceleration), speed))
}

/// The plan's bound at `speed` (at most [`TABLE_TOP_SPEED`]): on the line
/// through its two grid speeds at or below, where both are solved (the
/// value is convex in the speed, the module's doc); else at the grid speed
/// at or below.
fn plan_bound_near(shape: Shape, speed: f64) -> f64 {
    let k = ((speed / SPEED_STEP).floor() as usize).min(steps());
    let at = plan_bound_at(shape, k);
    if k == 0 || !at.solved {
        return at.value;
    }
    let below = plan_bound_at(shape, k - 1);
    // A program that did not solve reads 0 (no claim): no line through it.
    if !below.solved || (k > 1 && below.value <= 0.0) || below.value > at.value {
        return at.value;
    }
    at.value + (at.value - below.value) / SPEED_STEP * (speed - k as f64 * SPEED_STEP)
}

/// Solves the plan's bound at every grid speed of a team shape now (about
/// a second here), so that no later check waits for one: the offline
/// commands do it when they build an instance.
pub fn prepare(degree: usize, samples: usize, horizon: f64, max_acceleration: f64) {
    let shape = Shape::of(degree, samples, horizon, max_acceleration);
    for k in 0..=steps() {
        let _ = plan_bound_at(shape, k);
    }
}

fn steps() -> usize {
    (TABLE_TOP_SPEED / SPEED_STEP).round() as usize
}

/// What a table of the plan's bound is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Shape {
    degree: usize,
    samples: usize,
    horizon: u64,
    max_acceleration: u64,
}

impl Shape {
    fn of(degree: usize, samples: usize, horizon: f64, max_acceleration: f64) -> Self {
        Self { degree, samples, horizon: horizon.to_bits(), max_acceleration: max_acceleration.to_bits() }
    }
}

/// The solved grid speeds of each team shape asked for so far.
static TABLES: Mutex<Vec<(Shape, Vec<Entry>)>> = Mutex::new(Vec::new());

/// Where the speeds to solve go in a process that solves them in the
/// background ([`solve_in_background`]).
static BACKGROUND: OnceLock<Sender<(Shape, usize)>> = OnceLock::new();

/// The plan's bound read at one grid speed.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Read {
    /// The bound (m).
    value: f64,
    /// Whether it is that speed's own (else the fastest solved one below,
    /// while that speed waits for the background thread).
    solved: bool,
}

/// One grid speed of a table.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Entry {
    Unsolved,
    /// Handed to the background thread.
    Asked,
    Solved(f64),
}

/// From now on in this process, no caller of [`least_excursion`] waits for
/// a linear program: a grid speed not solved yet is solved on a background
/// thread (started by the first call) and read meanwhile at the fastest
/// solved grid speed below it, or 0 (the physical bound alone). The
/// daemon's worker asks for it: a linear program takes a few to tens of
/// milliseconds, which a 64-robot team's answers paid inside their 40 ms
/// deadline whenever a gust brought a robot to a new speed. Offline
/// commands keep solving on first use, so their verdicts do not depend on
/// timing. The thread runs `on_start` first (the daemon lowers its
/// priority there); calls after the first change nothing.
pub fn solve_in_background(on_start: fn()) {
    BACKGROUND.get_or_init(|| {
        let (tx, rx) = unbounded::<(Shape, usize)>();
        let solver = std::thread::Builder::new().name("flowopt-braking".into()).spawn(move || {
            on_start();
            for (shape, k) in rx {
                let bound = solve(shape, k);
                let mut tables = TABLES.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
                let index = table(&mut tables, shape);
                tables[index].1[k] = Entry::Solved(bound);
            }
        });
        if let Err(e) = solver {
            tracing::warn!(
                "the braking bound's background thread did not start ({e}): each speed is solved on first use"
            );
        }
        tx
    });
}

/// The index of `shape`'s table in `tables`, added if new.
fn table(tables: &mut Vec<(Shape, Vec<Entry>)>, shape: Shape) -> usize {
    tables.iter().position(|(s, _)| *s == shape).unwrap_or_else(|| {
        tables.push((shape, vec![Entry::Unsolved; steps() + 1]));
        tables.len() - 1
    })
}

/// The plan's bound at grid speed `k` of `shape`.
fn solve(shape: Shape, k: usize) -> f64 {
    let (horizon, max_acceleration) = (f64::from_bits(shape.horizon), f64::from_bits(shape.max_acceleration));
    plan_bound(shape.degree, shape.samples, horizon, max_acceleration, k as f64 * SPEED_STEP)
}

/// The plan's bound at the grid speed `k SPEED_STEP` (the top one beyond
/// it), solved on first use (one small linear program, under a
/// millisecond at degree 10, outside the table's lock) and kept for the process; with
/// [`solve_in_background`], never waited for.
#[must_use]
fn plan_bound_at(shape: Shape, k: usize) -> Read {
    let k = k.min(steps());
    {
        let mut tables = TABLES.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let index = table(&mut tables, shape);
        let entries = &mut tables[index].1;
        if let Entry::Solved(value) = entries[k] {
            return Read { value, solved: true };
        }
        // Handed to the background thread (unless it is gone: then solved
        // here).
        let asked = entries[k] == Entry::Asked
            || BACKGROUND.get().is_some_and(|background| background.send((shape, k)).is_ok());
        if asked {
            entries[k] = Entry::Asked;
            let value = entries[..k]
                .iter()
                .rev()
                .find_map(|e| if let Entry::Solved(b) = e { Some(*b) } else { None })
                .unwrap_or(0.0);
            return Read { value, solved: false };
        }
    }
    let bound = solve(shape, k);
    let mut tables = TABLES.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let index = table(&mut tables, shape);
    tables[index].1[k] = Entry::Solved(bound);
    Read { value: bound, solved: true }
}

/// The linear program of the module's doc at `speed`; 0 if it does not
/// solve (no claim).
fn plan_bound(degree: usize, samples: usize, horizon: f64, max_acceleration: f64, speed: f64) -> f64 {
    if speed <= 0.0 {
        return 0.0;
    }
    let n_xi = degree + 1;
    let fixed = BOUNDARY_ROWS / 2;
    // From 0 at `speed` (normalised time), zero acceleration: the first
    // three coefficients.
    let step = speed * horizon / degree as f64;
    let start = [0.0, step, 2.0 * step];
    let dense = DENSE_FACTOR * samples;
    let limit = max_acceleration * horizon * horizon;
    // The variables: the free coefficients, then the excursion (minimised:
    // its negative maximised).
    let free = n_xi - fixed;
    let mut objective = vec![0.0; free + 1];
    objective[free] = -1.0;
    let mut lp = Lp::maximise(&objective);
    let last = ((dense - 1) as f64 * CHECKED_SHARE).floor() as usize;
    for s in 1..=last {
        let tau = s as f64 / (dense - 1) as f64;
        for (order, row) in [(0, bernstein_row(degree, 0, tau)), (2, bernstein_row(degree, 2, tau))] {
            let known: f64 = start.iter().zip(&row).map(|(c, b)| c * b).sum();
            let mut terms = row[fixed..].to_vec();
            if order == 0 {
                terms.push(-1.0);
                lp.add_le(&terms, -known);
            } else {
                terms.push(0.0);
                lp.add_le(&terms, limit - known);
                lp.add_ge(&terms, -limit - known);
            }
        }
    }
    lp.solve().map_or(0.0, |solution| (-solution.value).max(0.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plan_bound_grows_with_the_speed_and_is_above_the_physical_one() {
        let shape = Shape::of(10, 50, 5.0, 3.0);
        let t: Vec<f64> = (0..=steps()).map(|k| plan_bound_at(shape, k).value).collect();
        assert_eq!(t[0], 0.0);
        for (k, w) in t.windows(2).enumerate() {
            assert!(w[1] >= w[0], "at {} m/s: {} < {}", (k + 1) as f64 * SPEED_STEP, w[1], w[0]);
        }
        for k in 1..t.len() {
            let v = k as f64 * SPEED_STEP;
            assert!(t[k] >= v * v / 6.0 * (1.0 - 1e-9), "at {v} m/s: {} below the physical bound", t[k]);
        }
        // A start accelerating, or faster than the table, gets the physical bound.
        assert_eq!(least_excursion(10, 50, 5.0, 3.0, 0.5, 1.0), 1.0 / 6.0);
        assert_eq!(least_excursion(10, 50, 5.0, 3.0, 0.0, 4.0), 16.0 / 6.0);
        assert_eq!(least_excursion(10, 50, 5.0, 3.0, 0.0, -1.0), 0.0);
    }

    #[test]
    fn between_grid_speeds_the_bound_stays_below_the_program_solved_there() {
        let shape = Shape::of(10, 50, 5.0, 3.0);
        // Off-grid speeds, among them the two whose reading at the grid
        // speed below left starts that cannot brake inside the tolerance
        // uncertified (0.1185 and 0.2194 m/s: 0.9 and 1.7 mm short).
        for speed in [0.031, 0.1185, 0.2194, 0.457, 0.999, 1.4731, 2.987] {
            let k = (speed / SPEED_STEP).floor() as usize;
            let (grid, near) = (plan_bound_at(shape, k).value, plan_bound_near(shape, speed));
            let exact = plan_bound(10, 50, 5.0, 3.0, speed);
            assert!(near <= exact + 1e-9, "at {speed} m/s: {near} above the program's {exact}");
            // Closer to the program than the grid speed below.
            assert!(near > grid, "at {speed} m/s: {near}, the grid speed's {grid}");
        }
    }
}
