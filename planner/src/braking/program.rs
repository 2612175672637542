//! One robot's plan along one axis as a linear program: the plan is one
//! polynomial of the team's form whose start (position, velocity,
//! acceleration) and end (its goal, at rest) coefficients are fixed, so
//! that the free coefficients are the program's variables, and the
//! acceleration is held within the limit at the dense verification
//! instants. The bounds with the goal ([`super::least_past_side`]) and the
//! reach of a robot at an instant ([`super::reach`]) are programs on it.
//!
//! The acceleration rows are added as cuts: the program is solved on
//! every few dense instants ([`AxisProgram::coarse`]), then the instant its
//! solution breaks most is added until it breaks none. That solves the
//! program on every dense instant, on a few of them.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, PoisonError};

use nalgebra::Vector3;

use crate::basis::{BOUNDARY_ROWS, DENSE_FACTOR, bernstein_row};
use crate::lp::Lp;
use crate::problem::{Problem, Team};

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

impl Form {
    /// The form and `motion`, bit for bit (a memo's key).
    pub(crate) fn bits_with(self, motion: AxisMotion) -> [u64; 8] {
        [
            self.degree as u64,
            self.samples as u64,
            self.horizon.to_bits(),
            self.max_acceleration.to_bits(),
            motion.position.to_bits(),
            motion.velocity.to_bits(),
            motion.acceleration.to_bits(),
            motion.goal.to_bits(),
        ]
    }
}

/// One robot's start and goal along one axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisMotion {
    /// Start position (m).
    pub position: f64,
    /// Start velocity (m/s).
    pub velocity: f64,
    /// Start acceleration (m/s^2).
    pub acceleration: f64,
    /// Goal (m), reached at rest at the horizon.
    pub goal: f64,
}

impl Team {
    /// The form of this team's plans with `max_acceleration`.
    pub fn form(&self, max_acceleration: f64) -> Form {
        Form { degree: self.degree, samples: self.samples, horizon: self.horizon, max_acceleration }
    }
}

impl Problem {
    /// Robot `i`'s start and goal along `axis`.
    pub fn axis_motion(&self, i: usize, axis: usize) -> AxisMotion {
        self.motion_along(i, &Vector3::ith(axis, 1.0))
    }

    /// Robot `i`'s start and goal along the unit vector `direction`.
    pub fn motion_along(&self, i: usize, direction: &Vector3<f64>) -> AxisMotion {
        let s = &self.starts[i];
        AxisMotion {
            position: s.position.dot(direction),
            velocity: s.velocity.dot(direction),
            acceleration: s.acceleration.dot(direction),
            goal: self.goals[i].dot(direction),
        }
    }
}

/// A row over the free coefficients and what the fixed ones add.
pub(super) type Row = (Vec<f64>, f64);

/// The basis' position and acceleration rows (normalised time) at the
/// dense instants of one degree and sample count: the same for every
/// motion, made once per process ([`DenseRows::of`]).
struct DenseRows {
    degree: usize,
    samples: usize,
    rows: Vec<[Vec<f64>; 2]>,
}

/// Every [`DenseRows`] made.
static DENSE_ROWS: Mutex<Vec<Arc<DenseRows>>> = Mutex::new(Vec::new());

impl DenseRows {
    fn of(degree: usize, samples: usize) -> Arc<Self> {
        let mut made = DENSE_ROWS.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(rows) = made.iter().find(|r| r.degree == degree && r.samples == samples) {
            return Arc::clone(rows);
        }
        let dense = DENSE_FACTOR * samples;
        let rows = (0..dense)
            .map(|s| [0, 2].map(|order| bernstein_row(degree, order, s as f64 / (dense - 1) as f64)))
            .collect();
        let rows = Arc::new(Self { degree, samples, rows });
        made.push(Arc::clone(&rows));
        rows
    }
}

/// The program's rows for one motion, along `sign` times the axis (so that
/// a side is approached upwards).
pub(super) struct AxisProgram {
    /// The basis' rows at the dense instants.
    basis: Arc<DenseRows>,
    /// Per dense instant, what the fixed coefficients add to the position
    /// and to the acceleration.
    known_sums: Vec<[f64; 2]>,
    /// The acceleration limit in normalised time.
    limit: f64,
    /// The fixed coefficients, per index (`None`: free).
    known: Vec<Option<f64>>,
    /// The first free coefficient and how many are free.
    free: (usize, usize),
    /// The form.
    form: Form,
}

impl AxisProgram {
    /// The rows of `motion` along `sign` times the axis; `None` where the
    /// degree leaves no free coefficient.
    pub(super) fn new(form: Form, motion: AxisMotion, sign: f64) -> Option<Self> {
        let Form { degree, samples, horizon, max_acceleration } = form;
        let n_xi = degree + 1;
        let fixed = BOUNDARY_ROWS / 2;
        if n_xi <= BOUNDARY_ROWS || samples < 2 {
            return None;
        }
        // Start: position, velocity, acceleration; end: the goal at rest
        // (normalised time).
        let n = degree as f64;
        let c0 = sign * motion.position;
        let c1 = c0 + sign * motion.velocity * horizon / n;
        let c2 = 2.0 * c1 - c0 + sign * motion.acceleration * horizon * horizon / (n * (n - 1.0));
        let goal = sign * motion.goal;
        let known: Vec<Option<f64>> = (0..n_xi)
            .map(|k| match k {
                0 => Some(c0),
                1 => Some(c1),
                2 => Some(c2),
                k if k + fixed >= n_xi => Some(goal),
                _ => None,
            })
            .collect();
        let basis = DenseRows::of(degree, samples);
        let limit = max_acceleration * horizon * horizon;
        let mut program = Self { basis, known_sums: Vec::new(), limit, known, free: (fixed, n_xi - 2 * fixed), form };
        program.known_sums =
            program.basis.rows.iter().map(|[p, a]| [program.known_sum(p), program.known_sum(a)]).collect();
        Some(program)
    }

    /// What the fixed coefficients add to a row of the basis.
    fn known_sum(&self, row: &[f64]) -> f64 {
        row.iter().zip(&self.known).filter_map(|(b, c)| c.map(|c| c * b)).sum()
    }

    /// Dense instant `s`'s position (`which` 0) or acceleration (1) row.
    pub(super) fn at(&self, s: usize, which: usize) -> (&[f64], f64) {
        let (first, count) = self.free;
        (&self.basis.rows[s][which][first..first + count], self.known_sums[s][which])
    }

    /// The position row at `tau` (normalised time), any instant.
    pub(super) fn position(&self, tau: f64) -> Row {
        let row = bernstein_row(self.form.degree, 0, tau);
        let (first, count) = self.free;
        (row[first..first + count].to_vec(), self.known_sum(&row))
    }

    /// How many coefficients are free.
    pub(super) fn free(&self) -> usize {
        self.free.1
    }

    /// Adds the acceleration rows of dense instant `s` to `lp`, whose first
    /// variables are the free coefficients (any after them left out of
    /// the rows).
    pub(super) fn add_acceleration(&self, lp: &mut Lp, s: usize) {
        let (weights, known) = self.at(s, 1);
        let mut row = weights.to_vec();
        row.resize(lp.variables(), 0.0);
        lp.add_le(&row, self.limit - known);
        lp.add_ge(&row, -self.limit - known);
    }

    /// The instants cuts start from: every `every`-th and the last.
    pub(super) fn coarse(&self, every: usize) -> impl Iterator<Item = usize> {
        let dense = self.known_sums.len();
        (0..dense).step_by(every).chain([dense - 1])
    }

    /// The dense instant whose row `which` (0 position, 1 acceleration)
    /// the free coefficients `x` (the first of a solution's variables)
    /// break most by `excess` (beyond [`TOLERANCE`]), if any.
    pub(super) fn worst(&self, x: &[f64], which: usize, excess: &dyn Fn(f64) -> f64) -> Option<usize> {
        (0..self.known_sums.len())
            .map(|s| {
                let (weights, known) = self.at(s, which);
                (s, excess(known + weights.iter().zip(x).map(|(w, c)| w * c).sum::<f64>()))
            })
            .filter(|(_, e)| *e > TOLERANCE)
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(s, _)| s)
    }

    /// The instant the free coefficients `x` break the acceleration limit
    /// at most, if any.
    pub(super) fn over_limit(&self, x: &[f64]) -> Option<usize> {
        self.worst(x, 1, &|a| (a.abs() - self.limit) / self.limit)
    }
}

/// Rounds of added instants before a program gives up (no claim).
pub(super) const MAX_ROUNDS: usize = 100;

/// How far past a constraint (m, or relative for the acceleration) a
/// solution may be and still count as keeping it.
const TOLERANCE: f64 = 1e-9;

/// The last [`MEMO`] programs' values, so that the checks of one problem
/// (its validation, the planner's floors, the verdict's) solve each once.
pub(crate) struct Memo<K, V>(Mutex<VecDeque<(K, V)>>);

/// How many programs a [`Memo`] keeps.
const MEMO: usize = 256;

impl<K: PartialEq, V: Copy> Memo<K, V> {
    /// An empty memo.
    pub(crate) const fn new() -> Self {
        Self(Mutex::new(VecDeque::new()))
    }

    /// The value kept for `key`, else `solve`'s, kept.
    pub(crate) fn get_or(&self, key: K, solve: impl FnOnce() -> V) -> V {
        {
            let memo = self.0.lock().unwrap_or_else(PoisonError::into_inner);
            if let Some((_, value)) = memo.iter().find(|(k, _)| *k == key) {
                return *value;
            }
        }
        let value = solve();
        let mut memo = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        if memo.len() == MEMO {
            memo.pop_front();
        }
        memo.push_back((key, value));
        value
    }
}
