//! The projection step: positions at a grid of instants, and the push
//! `e - F xi` that moves every violating robot to the constraint surface.
//!
//! With `d` the offset between two robots (or a robot and an obstacle) and
//! `r = ||diag(a, a, b)^-1 d||` its scaled length, the projected offset is
//! `e = d max(1, 1/r)`: non-violating rows are left alone, violating ones are
//! pushed radially onto the spheroid (the normalised difference, no angles).
//! The box clamps positions. Corrections are summed per robot (`+c` to `i`,
//! `-c` to `j` for a pair row) in position space, and their squared norms give
//! the primal residual `||F xi - e|| + ||G xi - h + s||`.
//!
//! The same code checks feasibility: on the dense grid with the true sizes
//! shrunk by the tolerance, a plan is feasible exactly when no correction is
//! needed.

use std::ops::Range;
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, sync_channel};
use std::thread::Scope;
use std::time::Instant;

use super::pairs::{BROAD_PHASE_MIN_ROBOTS, BroadPhase, Candidate};
use crate::basis::bernstein_row;
use crate::linalg::{Accum, gemm};
use crate::problem::{Dim, Problem};

/// Teams at least this large check their pairs on two threads when their
/// limits ask for it (docs/BENCHMARKS.md, "Big teams").
pub const TWO_THREADS_MIN_ROBOTS: usize = 128;

/// How long a waiting side of the pair helper spins before it blocks: longer
/// than the rest of an iteration of the biggest teams, so that neither side
/// sleeps between iterations (waking an idle core costs tens of
/// microseconds on these hosts).
const SPIN: std::time::Duration = std::time::Duration::from_millis(2);

/// Squared scaled distance below which two centres count as coincident and
/// the push direction is chosen deterministically instead of normalised.
const COINCIDENT: f64 = 1e-18;

/// Instants the constraints are evaluated at, with the basis there.
#[derive(Debug, Clone)]
pub(crate) struct SampleGrid {
    /// Normalised times.
    pub taus: Vec<f64>,
    /// `P^T`, `n_xi x count`, row-major.
    pub pt: Vec<f64>,
    /// `P`, `count x n_xi`, row-major.
    pub p: Vec<f64>,
}

impl SampleGrid {
    /// The basis of `degree` at `taus`.
    pub fn new(degree: usize, taus: Vec<f64>) -> Self {
        let n_xi = degree + 1;
        let count = taus.len();
        let p: Vec<f64> = taus.iter().flat_map(|&t| bernstein_row(degree, 0, t)).collect();
        let mut pt = vec![0.0; n_xi * count];
        for r in 0..count {
            for c in 0..n_xi {
                pt[c * count + r] = p[r * n_xi + c];
            }
        }
        Self { taus, pt, p }
    }

    /// Number of instants.
    pub fn count(&self) -> usize {
        self.taus.len()
    }

    /// Values at the instants (`rows x count`) mapped back to coefficients,
    /// `out = values P` (`rows x n_xi`).
    pub fn to_coefficients(&self, values: &[f64], rows: usize, out: &mut [f64]) {
        let count = self.count();
        gemm(out, values, &self.p, rows, count, self.p.len() / count.max(1), Accum::Replace);
    }
}

/// Sizes, box and obstacle tracks one projection checks against.
#[derive(Debug, Clone)]
pub struct Limits {
    /// Robot-robot separations per axis.
    robot_sep: [f64; 3],
    /// Per obstacle: robot-obstacle separations per axis.
    obstacle_sep: Vec<[f64; 3]>,
    /// Box per axis.
    lo: [f64; 3],
    hi: [f64; 3],
    /// Obstacle centres at the grid instants, `[obstacle][axis][count]`.
    tracks: Vec<f64>,
    /// Inflate each instant's separation by the chord to its neighbours.
    chord: bool,
    /// Find the robot pairs to check by sweep-and-prune (large teams).
    broad_phase: bool,
    /// Check the broad phase's pairs on two threads (teams of
    /// [`TWO_THREADS_MIN_ROBOTS`] or more).
    two_threads: bool,
}

impl Limits {
    /// Robot-robot separations per axis (m).
    pub fn robot_separation(&self) -> [f64; 3] {
        self.robot_sep
    }

    /// Robot-obstacle separations per axis, per obstacle (m).
    pub fn obstacle_separations(&self) -> &[[f64; 3]] {
        &self.obstacle_sep
    }

    /// Whether the broad phase's pairs of teams of
    /// [`TWO_THREADS_MIN_ROBOTS`] or more are checked on two threads.
    pub fn two_threads(&self) -> bool {
        self.two_threads && self.broad_phase
    }

    /// The box positions are clamped into, `(lower, upper)` per axis (m).
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        (self.lo, self.hi)
    }

    /// Obstacle centres at the grid's instants, `[obstacle][axis][sample]` (m).
    pub fn tracks(&self) -> &[f64] {
        &self.tracks
    }

    /// The limits of `problem` on `grid`: every separation scaled by
    /// `scale`, the box moved inwards by `inset` (per axis; negative grows it).
    pub(crate) fn new(problem: &Problem, grid: &SampleGrid, scale: f64, inset: [f64; 3]) -> Self {
        let times: Vec<f64> = grid.taus.iter().map(|tau| tau * problem.team.horizon).collect();
        Self::at_times(problem, &times, scale, inset)
    }

    /// The same limits with the obstacles tracked at `times` (seconds from
    /// the obstacles' reported positions), one per grid instant.
    pub(crate) fn at_times(problem: &Problem, times: &[f64], scale: f64, inset: [f64; 3]) -> Self {
        let team = &problem.team;
        let dim = team.dim.axes();
        let (a, b) = team.separation();
        let count = times.len();
        let mut tracks = vec![0.0; problem.obstacles.len() * dim * count];
        let mut obstacle_sep = Vec::with_capacity(problem.obstacles.len());
        for (m, o) in problem.obstacles.iter().enumerate() {
            for ax in 0..dim {
                for (k, t) in times.iter().enumerate() {
                    tracks[(m * dim + ax) * count + k] = o.position[ax] + o.velocity[ax] * t;
                }
            }
            let (ao, bo) = team.obstacle_separation(&o.shape);
            obstacle_sep.push([ao * scale, ao * scale, bo * scale]);
        }
        Self {
            robot_sep: [a * scale, a * scale, b * scale],
            obstacle_sep,
            lo: [0, 1, 2].map(|ax| team.workspace.min[ax] + inset[ax]),
            hi: [0, 1, 2].map(|ax| team.workspace.max[ax] - inset[ax]),
            tracks,
            chord: false,
            broad_phase: false,
            two_threads: false,
        }
    }

    /// The same limits checked with `chord` inflation (see [`Projection`])
    /// and, for teams of [`BROAD_PHASE_MIN_ROBOTS`] or more, with the
    /// `broad_phase`, its pairs on `two_threads` for teams of
    /// [`TWO_THREADS_MIN_ROBOTS`] or more.
    pub(crate) fn with_rules(self, chord: bool, broad_phase: bool, two_threads: bool) -> Self {
        Self { chord, broad_phase, two_threads, ..self }
    }
}

/// Positions and corrections at a grid: the projection's working memory.
#[derive(Debug)]
pub(crate) struct Projection {
    /// Positions `[axis][robot][count]`.
    pub pos: Vec<f64>,
    /// Corrections `e - F xi` summed per robot, `[axis][robot][count]`;
    /// with a helper, only this thread's (see [`Self::coefficients`]).
    pub corr: Vec<f64>,
    /// With a helper: all corrections mapped to coefficients, `g = corr P`
    /// summed over both threads, `[axis][robot][coef]` (empty without).
    mapped: Vec<f64>,
    /// Robots with any non-zero correction.
    pub touched: Vec<bool>,
    /// One pair's squared targets and moves per instant.
    scratch: Scratch,
    broad: BroadPhase,
    /// Each robot's largest scaled move between instants (chord inflation).
    steps: Vec<f64>,
    /// Each robot's share of the broad phase's reach, per axis (m).
    grow: Vec<[f64; 3]>,
    /// The thread that checks the second half of the pairs (two threads only).
    helper: Option<PairHelper>,
    /// Stop at the first violation with an infinite sum ([`Self::clear`]).
    first: bool,
    /// The pair the last [`Self::clear`] stopped at: checked first by the
    /// next, since while a run converges the same pair tends to stay short.
    culprit: Option<(u32, u32)>,
}

/// The main thread's end of a pair helper ([`Projection::with_helper`]).
#[derive(Debug)]
struct PairHelper {
    /// The iterate: the helper evaluates its positions and finds the pairs
    /// while this thread evaluates its own and clamps them into the box.
    jobs: SyncSender<Job>,
    /// The first half of the pairs, for this thread.
    firsts: Receiver<Vec<Candidate>>,
    /// The job back, with the helper's corrections for the second half.
    done: Receiver<Job>,
    /// The job's buffers between iterations.
    spare: Option<Job>,
    /// The first half's buffer between iterations.
    spare_pairs: Vec<Candidate>,
    /// Where the helper is in the current iteration.
    stage: Stage,
    /// Address of the limits the helper checks against (compared, never read).
    limits: usize,
}

/// Where a pair helper is in an iteration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stage {
    /// Waiting for an iterate.
    Idle,
    /// Evaluating the iterate it was sent and finding its pairs.
    Evaluating,
    /// Checking its pairs.
    Checking,
}

/// An iteration's iterate for the helper, which evaluates its own positions
/// from it, finds the pairs, sends the first half back in `pairs` and
/// checks the second, and its corrections back, mapped to coefficients.
#[derive(Debug)]
struct Job {
    xi: Vec<f64>,
    pairs: Vec<Candidate>,
    share: Share,
    /// `share.corr P`, `[axis][robot][coef]`.
    mapped: Vec<f64>,
    sum: f64,
}

/// One thread's corrections and working memory for its share of the pairs.
#[derive(Debug, Clone)]
struct Share {
    corr: Vec<f64>,
    touched: Vec<bool>,
    scratch: Scratch,
}

/// Per-instant values of the pair being checked.
#[derive(Debug, Clone)]
struct Scratch {
    /// Squared target: 1, or more with the chord inflation.
    target: Vec<f64>,
    /// Squared scaled move of the offset to the next instant (0 at the last).
    step: Vec<f64>,
}

impl Projection {
    /// Buffers for `robots` robots in `dim` on `grid`.
    pub fn new(dim: Dim, robots: usize, grid: &SampleGrid) -> Self {
        let len = dim.axes() * robots * grid.count();
        let count = grid.count();
        Self {
            pos: vec![0.0; len],
            corr: vec![0.0; len],
            mapped: Vec::new(),
            touched: vec![false; robots],
            scratch: Scratch { target: vec![1.0; count], step: vec![0.0; count] },
            broad: BroadPhase::default(),
            steps: Vec::with_capacity(robots),
            grow: Vec::with_capacity(robots),
            helper: None,
            first: false,
            culprit: None,
        }
    }

    /// The same projection with the broad phase, and the second half of its
    /// pairs, against `limits` on a helper thread of `scope`, which stays
    /// awake across iterations (a thread started per iteration costs about
    /// 70 us here, more than half the pairs of 128 robots take). The helper
    /// evaluates the iterate itself and ends when the projection is
    /// dropped. Only runs against `limits` use it.
    pub fn with_helper<'scope>(
        mut self,
        scope: &'scope Scope<'scope, '_>,
        dim: Dim,
        robots: usize,
        grid: &'scope SampleGrid,
        limits: &'scope Limits,
    ) -> Self {
        let (jobs, inbox) = sync_channel(1);
        let (first_out, firsts) = sync_channel(1);
        let (outbox, done) = sync_channel(1);
        scope.spawn(move || serve(dim, robots, grid, limits, &inbox, &first_out, &outbox));
        self.helper = Some(PairHelper {
            jobs,
            firsts,
            done,
            spare: None,
            spare_pairs: Vec::new(),
            stage: Stage::Idle,
            limits: std::ptr::from_ref(limits) as usize,
        });
        self
    }

    /// Hands `xi` to the helper if it checks against `limits`, before this
    /// thread evaluates it: the helper's positions and broad phase overlap
    /// this thread's positions and box. Without a helper (or once it is
    /// gone) nothing is sent.
    fn start_helper(&mut self, robots: usize, limits: &Limits, xi: &[f64]) {
        let Some(link) = self.helper.as_mut().filter(|h| h.limits == std::ptr::from_ref(limits) as usize) else {
            return;
        };
        let mut job = link.spare.take().unwrap_or_else(|| Job {
            xi: Vec::new(),
            pairs: Vec::new(),
            share: Share {
                corr: vec![0.0; self.corr.len()],
                touched: vec![false; robots],
                scratch: self.scratch.clone(),
            },
            mapped: Vec::new(),
            sum: 0.0,
        });
        job.pairs = std::mem::take(&mut link.spare_pairs);
        job.xi.clear();
        job.xi.extend_from_slice(xi);
        link.stage = Stage::Evaluating;
        if link.jobs.send(job).is_err() {
            // The helper is gone (it panicked; the scope reports it): this
            // thread checks every pair for the rest of the run.
            self.helper = None;
        }
    }

    /// Evaluates `xi` (`[axis][robot][coef]`) on `grid`, computes every
    /// correction against `limits` and returns the primal residual.
    pub fn run(&mut self, dim: Dim, robots: usize, grid: &SampleGrid, limits: &Limits, xi: &[f64]) -> f64 {
        let count = grid.count();
        let n_xi = grid.pt.len() / count;
        let rows = dim.axes() * robots;
        self.start_helper(robots, limits, xi);
        gemm(&mut self.pos, xi, &grid.pt, rows, n_xi, count, Accum::Replace);
        clear_touched(&mut self.corr, &mut self.touched, count);
        if !limits.chord {
            self.scratch.target.fill(1.0);
        }
        let (pairs, boxed) = match dim {
            Dim::Two => self.pairs::<2>(robots, count, limits),
            Dim::Three => self.pairs::<3>(robots, count, limits),
        };
        if self.first && pairs > 0.0 {
            return pairs;
        }
        let obstacles = match dim {
            Dim::Two => self.obstacles::<2>(robots, count, limits),
            Dim::Three => self.obstacles::<3>(robots, count, limits),
        };
        let theirs = match dim {
            Dim::Two => self.collect::<2>(robots, grid, limits),
            Dim::Three => self.collect::<3>(robots, grid, limits),
        };
        let box_sq = boxed
            .unwrap_or_else(|| clamp_to_box(&self.pos, &mut self.corr, &mut self.touched, limits, dim.axes(), count));
        (pairs + theirs + obstacles).sqrt() + box_sq.sqrt()
    }

    /// Whether the robots of `xi` keep clear of the obstacles of `limits`
    /// at every instant of `grid` (pairs and box are not checked), stopping
    /// at the first violation.
    pub fn obstacles_clear(&mut self, dim: Dim, robots: usize, grid: &SampleGrid, limits: &Limits, xi: &[f64]) -> bool {
        let count = grid.count();
        if count == 0 || limits.obstacle_sep.is_empty() {
            return true;
        }
        let n_xi = grid.pt.len() / count;
        gemm(&mut self.pos, xi, &grid.pt, dim.axes() * robots, n_xi, count, Accum::Replace);
        self.first = true;
        let violation = match dim {
            Dim::Two => self.obstacles::<2>(robots, count, limits),
            Dim::Three => self.obstacles::<3>(robots, count, limits),
        };
        self.first = false;
        violation == 0.0
    }

    /// Whether `xi` needs no correction at all against `limits` (what a zero
    /// [`Self::run`] means), stopping at the first violating pair or
    /// obstacle: the dense verification, which fails on most of its calls
    /// while a run converges. The pair a previous call stopped at is checked
    /// before any other (and before the broad phase); the verdict is the
    /// same either way.
    pub fn clear(&mut self, dim: Dim, robots: usize, grid: &SampleGrid, limits: &Limits, xi: &[f64]) -> bool {
        self.first = true;
        let residual = self.run(dim, robots, grid, limits, xi);
        self.first = false;
        residual == 0.0
    }

    /// The corrections mapped back to coefficients, `g = corr P`
    /// (`[axis][robot][coef]`, `rows` rows), into `g`; with a helper, the
    /// sum both threads mapped.
    pub fn coefficients(&self, grid: &SampleGrid, rows: usize, g: &mut [f64]) {
        if self.mapped.len() == g.len() {
            g.copy_from_slice(&self.mapped);
        } else {
            grid.to_coefficients(&self.corr, rows, g);
        }
    }

    /// With the helper checking pairs: maps this thread's corrections to
    /// coefficients meanwhile, adds the helper's and returns the helper's
    /// sum of `||c||^2` (0 without). Should the helper be gone, this thread
    /// checks its half of the pairs too, and the rest of the run alone.
    fn collect<const D: usize>(&mut self, n: usize, grid: &SampleGrid, limits: &Limits) -> f64 {
        self.mapped.clear();
        let Some(link) = self.helper.as_mut().filter(|h| h.stage == Stage::Checking) else {
            return 0.0;
        };
        link.stage = Stage::Idle;
        let (count, n_xi) = (grid.count(), grid.pt.len() / grid.count());
        let mut mapped = std::mem::take(&mut self.mapped);
        mapped.resize(D * n * n_xi, 0.0);
        grid.to_coefficients(&self.corr, D * n, &mut mapped);
        let Some(job) = receive(&link.done) else {
            // The helper is gone (it panicked; the scope reports it).
            self.helper = None;
            let Projection { pos, corr, touched, scratch, broad, steps, grow, .. } = self;
            let sep = limits.robot_sep;
            let check = Check { pos, steps, n, count, limits, inv: sep.map(|s| 1.0 / (s * s)) };
            let pairs = broad.candidates(pos, D, n, count, reach_shares(steps, &sep, grow));
            return check.push::<D>(pairs[pairs.len() / 2..].iter().copied(), scratch, corr, touched);
        };
        for (m, h) in mapped.iter_mut().zip(&job.mapped) {
            *m += h;
        }
        self.mapped = mapped;
        let theirs = job.sum;
        link.spare = Some(job);
        theirs
    }

    /// Inter-robot corrections for every pair `i < j` (every candidate of
    /// the broad phase, in the same order): where the scaled distance `r` is
    /// below its target `t` (1, or more with the chord inflation) the offset
    /// is pushed to it, `c = d (t/r - 1)`, added to `i` and taken from `j`.
    /// Returns the sum of `||c||^2`, and, where the box corrections were
    /// made while the helper checked its half, theirs.
    fn pairs<const D: usize>(&mut self, n: usize, count: usize, limits: &Limits) -> (f64, Option<f64>) {
        let sep = limits.robot_sep;
        let inv = sep.map(|s| 1.0 / (s * s));
        let Projection { pos, corr, touched, scratch, broad, steps, grow, helper, first, culprit, .. } = self;
        robot_steps(pos, D, n, count, limits, steps);
        let check = Check { pos, steps, n, count, limits, inv };
        let broad_phase = limits.broad_phase && n >= BROAD_PHASE_MIN_ROBOTS;
        if *first {
            if culprit.is_some_and(|(i, j)| check.violates::<D>(Candidate::whole(i, j, count), scratch)) {
                return (f64::INFINITY, None);
            }
            let found = if broad_phase {
                let candidates = broad.candidates(pos, D, n, count, reach_shares(steps, &sep, grow));
                candidates.iter().copied().find(|&pair| check.violates::<D>(pair, scratch))
            } else {
                all_pairs(n, count).find(|&pair| check.violates::<D>(pair, scratch))
            };
            *culprit = found.map(|c| (c.i, c.j));
            return (if culprit.is_some() { f64::INFINITY } else { 0.0 }, None);
        }
        if !broad_phase {
            return (check.push::<D>(all_pairs(n, count), scratch, corr, touched), None);
        }
        let Some(link) = helper.as_mut().filter(|h| h.stage == Stage::Evaluating) else {
            let candidates = broad.candidates(pos, D, n, count, reach_shares(steps, &sep, grow));
            return (check.push::<D>(candidates.iter().copied(), scratch, corr, touched), None);
        };
        // The box while the helper finds the pairs: the same corrections,
        // added in another order; the helper checks the second half of the
        // pairs into its own corrections: the same iteration up to rounding.
        let box_sq = clamp_to_box(pos, corr, touched, limits, D, count);
        let Some(mine) = receive(&link.firsts) else {
            // The helper is gone (it panicked; the scope reports it): this
            // thread checks every pair, for the rest of the run too.
            *helper = None;
            let candidates = broad.candidates(pos, D, n, count, reach_shares(steps, &sep, grow));
            return (check.push::<D>(candidates.iter().copied(), scratch, corr, touched), Some(box_sq));
        };
        let sum = check.push::<D>(mine.iter().copied(), scratch, corr, touched);
        link.spare_pairs = mine;
        link.stage = Stage::Checking;
        (sum, Some(box_sq))
    }

    /// Robot-obstacle corrections: where robot `i` is inside the (scaled)
    /// obstacle `m` at an instant, its position is pushed to the surface.
    fn obstacles<const D: usize>(&mut self, n: usize, count: usize, limits: &Limits) -> f64 {
        if limits.obstacle_sep.is_empty() {
            return 0.0;
        }
        let stride = n * count;
        let Projection { pos, corr, touched, scratch, first, .. } = self;
        let robot_steps = if limits.chord { largest_steps(pos, D, n, count) } else { [0.0; 3] };
        let mut sum = 0.0;
        for (m, sep) in limits.obstacle_sep.iter().enumerate() {
            let inv = sep.map(|s| 1.0 / (s * s));
            let rows = &limits.tracks[m * D * count..(m + 1) * D * count];
            let track = robot_rows::<D>(rows, 1, count, 0);
            let bound = limits.chord.then(|| largest_target(&robot_steps, &largest_steps(rows, D, 1, count), &inv));
            for i in 0..n {
                let pi = robot_rows::<D>(pos, n, count, i);
                if !scratch.violated::<D>(&pi, &track, &inv, bound, 0..count) {
                    continue;
                }
                if *first {
                    return f64::INFINITY;
                }
                touched[i] = true;
                for k in 0..count {
                    let Some(c) = push::<D>(&pi, &track, k, &inv, sep, scratch.target[k], (i, m)) else {
                        continue;
                    };
                    for a in 0..D {
                        corr[a * stride + i * count + k] += c[a];
                        sum += c[a] * c[a];
                    }
                }
            }
        }
        sum
    }
}

impl Scratch {
    /// Whether `p` and `q` come closer than their target at any of the
    /// `instants` (the screen every pair goes through; vectorises over
    /// instants). Leaves the per-instant targets there for [`push`]; the
    /// targets at the ends take the moves inside `instants` only.
    ///
    /// With the chord inflation (`bound`, the largest target any pair can
    /// have this iteration), an instant's target is `1 + L^2 / 4` (squared,
    /// scaled units), `L` the longer of the offset's moves to its neighbouring
    /// instants: two instants at least that far apart keep the straight
    /// motion between them clear of the separation, however fast the pair
    /// moves (the motion's curvature between instants is left to the
    /// margin). Pairs that stay beyond `bound` are screened out before the
    /// targets are computed.
    fn violated<const D: usize>(
        &mut self,
        p: &[&[f64]; D],
        q: &[&[f64]; D],
        inv: &[f64; 3],
        bound: Option<f64>,
        instants: Range<usize>,
    ) -> bool {
        let count = instants.len();
        let p: [&[f64]; D] = std::array::from_fn(|a| &p[a][instants.clone()]);
        let q: [&[f64]; D] = std::array::from_fn(|a| &q[a][instants.clone()]);
        let scaled = |k: usize| -> f64 {
            let mut s = 0.0;
            for a in 0..D {
                let d = p[a][k] - q[a][k];
                s += d * d * inv[a];
            }
            s
        };
        let below = |t: f64| -> bool {
            let mut any = false;
            for k in 0..count {
                any |= scaled(k) < t;
            }
            any
        };
        let Some(bound) = bound else {
            return below(1.0);
        };
        if !below(bound) {
            return false;
        }
        // Three passes that vectorise: the squared moves between instants,
        // the targets, the comparison.
        let step = &mut self.step[instants.clone()];
        step[count - 1] = 0.0;
        for k in 0..count - 1 {
            let mut l = 0.0;
            for a in 0..D {
                let m = (p[a][k + 1] - q[a][k + 1]) - (p[a][k] - q[a][k]);
                l += m * m * inv[a];
            }
            step[k] = l;
        }
        let target = &mut self.target[instants];
        target[0] = 1.0 + 0.25 * step[0];
        for k in 1..count {
            target[k] = 1.0 + 0.25 * f64::max(step[k - 1], step[k]);
        }
        let mut any = false;
        for (k, t) in target.iter().enumerate() {
            any |= scaled(k) < *t;
        }
        any
    }
}

/// The helper's loop: each job's positions from its iterate, its broad
/// phase, the first half of the pairs sent back, then the second half's
/// corrections, until the projection hangs up.
fn serve(
    dim: Dim,
    n: usize,
    grid: &SampleGrid,
    limits: &Limits,
    jobs: &Receiver<Job>,
    firsts: &SyncSender<Vec<Candidate>>,
    done: &SyncSender<Job>,
) {
    let count = grid.count();
    let (rows, n_xi) = (dim.axes() * n, grid.pt.len() / count);
    let sep = limits.robot_sep;
    let inv = sep.map(|s| 1.0 / (s * s));
    let (mut pos, mut steps, mut grow) = (vec![0.0; rows * count], Vec::with_capacity(n), Vec::with_capacity(n));
    let mut broad = BroadPhase::default();
    while let Some(mut job) = receive(jobs) {
        gemm(&mut pos, &job.xi, &grid.pt, rows, n_xi, count, Accum::Replace);
        robot_steps(&pos, dim.axes(), n, count, limits, &mut steps);
        let candidates = broad.candidates(&pos, dim.axes(), n, count, reach_shares(&steps, &sep, &mut grow));
        let (first, second) = candidates.split_at(candidates.len() / 2);
        let mut theirs = std::mem::take(&mut job.pairs);
        theirs.clear();
        theirs.extend_from_slice(first);
        if firsts.send(theirs).is_err() {
            return;
        }
        let check = Check { pos: &pos, steps: &steps, n, count, limits, inv };
        let Share { corr, touched, scratch } = &mut job.share;
        clear_touched(corr, touched, count);
        if !limits.chord {
            scratch.target.fill(1.0);
        }
        let pairs = second.iter().copied();
        job.sum = match dim {
            Dim::Two => check.push::<2>(pairs, scratch, corr, touched),
            Dim::Three => check.push::<3>(pairs, scratch, corr, touched),
        };
        job.mapped.resize(rows * n_xi, 0.0);
        grid.to_coefficients(corr, rows, &mut job.mapped);
        if done.send(job).is_err() {
            return;
        }
    }
}

/// Each robot's share of the broad phase's reach per axis, into `grow`:
/// a pair's chord inflation is at most `sqrt(1 + (s_i + s_j)^2 / 4) <=
/// 1 + (s_i + s_j) / 2` separations, `s` the robots' largest scaled moves
/// between instants (`steps`), so robot `i`'s share is `(1 + s_i) / 2`.
fn reach_shares<'a>(steps: &[f64], sep: &[f64; 3], grow: &'a mut Vec<[f64; 3]>) -> &'a [[f64; 3]] {
    grow.clear();
    grow.extend(steps.iter().map(|s| sep.map(|x| x * 0.5 * (1.0 + s))));
    grow
}

/// Clamps the positions (`[axis][robot][count]`, `axes` axes) into the box
/// of `limits`: adds the corrections to `corr`, marks the robots moved in
/// `touched` and returns the corrections' sum of squares.
fn clamp_to_box(
    pos: &[f64],
    corr: &mut [f64],
    touched: &mut [bool],
    limits: &Limits,
    axes: usize,
    count: usize,
) -> f64 {
    let robots = touched.len();
    let mut box_sq = 0.0;
    for ax in 0..axes {
        let (lo, hi) = (limits.lo[ax], limits.hi[ax]);
        for (i, touched) in touched.iter_mut().enumerate() {
            let range = (ax * robots + i) * count..(ax * robots + i + 1) * count;
            let mut any = false;
            for (p, c) in pos[range.clone()].iter().zip(&mut corr[range]) {
                let d = p.clamp(lo, hi) - p;
                *c += d;
                box_sq += d * d;
                any |= d != 0.0;
            }
            *touched |= any;
        }
    }
    box_sq
}

/// Zeroes the rows (`[axis][robot][count]`) of the robots `touched` marks,
/// and the marks: the rows of unmarked robots are zero already, so this
/// clears `corr` at a fraction of the memory traffic.
fn clear_touched(corr: &mut [f64], touched: &mut [bool], count: usize) {
    for block in corr.chunks_exact_mut(touched.len() * count) {
        for (row, _) in block.chunks_exact_mut(count).zip(touched.iter()).filter(|(_, t)| **t) {
            row.fill(0.0);
        }
    }
    touched.fill(false);
}

/// The next message, spinning for up to [`SPIN`] before blocking; `None`
/// once the other side hung up.
fn receive<T>(from: &Receiver<T>) -> Option<T> {
    let started = Instant::now();
    loop {
        for _ in 0..64 {
            match from.try_recv() {
                Ok(message) => return Some(message),
                Err(TryRecvError::Disconnected) => return None,
                Err(TryRecvError::Empty) => std::hint::spin_loop(),
            }
        }
        if started.elapsed() > SPIN {
            return from.recv().ok();
        }
    }
}

/// What one thread's pair checks read: the positions, the robots' largest
/// moves between instants and the limits.
#[derive(Clone, Copy)]
struct Check<'a> {
    pos: &'a [f64],
    steps: &'a [f64],
    n: usize,
    count: usize,
    limits: &'a Limits,
    inv: [f64; 3],
}

impl Check<'_> {
    /// Whether the candidate comes closer than its target at any of the
    /// [`Self::instants`] it is checked at.
    #[inline(always)]
    fn violates<const D: usize>(&self, pair: Candidate, scratch: &mut Scratch) -> bool {
        let (i, j) = (pair.i as usize, pair.j as usize);
        let bound = self.limits.chord.then(|| 1.0 + 0.25 * (self.steps[i] + self.steps[j]).powi(2));
        let (pi, pj) =
            (robot_rows::<D>(self.pos, self.n, self.count, i), robot_rows::<D>(self.pos, self.n, self.count, j));
        scratch.violated::<D>(&pi, &pj, &self.inv, bound, self.instants(pair))
    }

    /// The instants a candidate is checked at: its own and one more on
    /// either side, whose moves its end instants' chord targets take. The
    /// extra instants lie outside the candidate's (where its boxes do not
    /// overlap, so they cannot violate even with their targets cut short).
    fn instants(&self, pair: Candidate) -> Range<usize> {
        (pair.from as usize).saturating_sub(1)..(pair.to as usize + 1).min(self.count)
    }

    /// Pushes apart every violating pair of `pairs` (`i < j`, in order),
    /// adding to `corr` and marking `touched`; returns the sum of `||c||^2`.
    fn push<const D: usize>(
        &self,
        pairs: impl Iterator<Item = Candidate>,
        scratch: &mut Scratch,
        corr: &mut [f64],
        touched: &mut [bool],
    ) -> f64 {
        let (count, inv, sep) = (self.count, &self.inv, &self.limits.robot_sep);
        let stride = self.n * count;
        let mut sum = 0.0;
        for pair in pairs {
            if !self.violates::<D>(pair, scratch) {
                continue;
            }
            let (i, j) = (pair.i as usize, pair.j as usize);
            let (pi, pj) = (robot_rows::<D>(self.pos, self.n, count, i), robot_rows::<D>(self.pos, self.n, count, j));
            touched[i] = true;
            touched[j] = true;
            for k in self.instants(pair) {
                let Some(c) = push::<D>(&pi, &pj, k, inv, sep, scratch.target[k], (i, j)) else {
                    continue;
                };
                for a in 0..D {
                    corr[a * stride + i * count + k] += c[a];
                    corr[a * stride + j * count + k] -= c[a];
                    sum += c[a] * c[a];
                }
            }
        }
        sum
    }
}

/// Robot `i`'s rows of `values` (`[axis][robot][count]`, `n` robots), one
/// per axis.
#[inline(always)]
fn robot_rows<const D: usize>(values: &[f64], n: usize, count: usize, i: usize) -> [&[f64]; D] {
    let stride = n * count;
    std::array::from_fn(|a| &values[a * stride + i * count..a * stride + (i + 1) * count])
}

/// Every pair `i < j` of `n` robots, in order, at every one of `count`
/// instants.
fn all_pairs(n: usize, count: usize) -> impl Iterator<Item = Candidate> {
    (0..n as u32).flat_map(move |i| (i + 1..n as u32).map(move |j| Candidate::whole(i, j, count)))
}

/// Each of `n` robots' largest move between neighbouring instants, scaled
/// by the robot separations of `limits`, into `out` (zeros without the
/// chord inflation).
fn robot_steps(pos: &[f64], axes: usize, n: usize, count: usize, limits: &Limits, out: &mut Vec<f64>) {
    out.clear();
    if !limits.chord {
        out.resize(n, 0.0);
        return;
    }
    let inv = limits.robot_sep.map(|s| 1.0 / (s * s));
    out.extend((0..n).map(|i| {
        let mut largest: f64 = 0.0;
        for k in 1..count {
            let mut s = 0.0;
            for (a, inv) in inv.iter().enumerate().take(axes) {
                let x = &pos[(a * n + i) * count..(a * n + i + 1) * count];
                s += (x[k] - x[k - 1]).powi(2) * inv;
            }
            largest = largest.max(s);
        }
        largest.sqrt()
    }));
}

/// The largest move between neighbouring instants of each of `rows`
/// (`axes` blocks of `rows` rows of `count` positions), per axis.
fn largest_steps(pos: &[f64], axes: usize, rows: usize, count: usize) -> [f64; 3] {
    let mut out = [0.0; 3];
    for (a, largest) in out.iter_mut().enumerate().take(axes) {
        for i in 0..rows {
            let x = &pos[(a * rows + i) * count..(a * rows + i + 1) * count];
            for k in 1..count {
                *largest = f64::max(*largest, (x[k] - x[k - 1]).abs());
            }
        }
    }
    out
}

/// The largest squared target (`1 + L^2 / 4`) of a pair whose members move
/// at most `p` and `q` per axis between instants, scaled by `inv`.
fn largest_target(p: &[f64; 3], q: &[f64; 3], inv: &[f64; 3]) -> f64 {
    let l2: f64 = (0..3).map(|a| (p[a] + q[a]).powi(2) * inv[a]).sum();
    1.0 + 0.25 * l2
}

/// The correction `e - d` for offset `d = p(k) - q(k)` if its scaled
/// squared length is below `target` (squared). Coincident centres get a
/// deterministic direction derived from `ids` and `k`.
fn push<const D: usize>(
    p: &[&[f64]; D],
    q: &[&[f64]; D],
    k: usize,
    inv: &[f64; 3],
    sep: &[f64; 3],
    target: f64,
    ids: (usize, usize),
) -> Option<[f64; D]> {
    let mut d = [0.0; D];
    let mut s = 0.0;
    for a in 0..D {
        d[a] = p[a][k] - q[a][k];
        s += d[a] * d[a] * inv[a];
    }
    if s >= target {
        return None;
    }
    let reach = target.sqrt();
    let mut c = [0.0; D];
    if s < COINCIDENT {
        // Golden-angle spread so that coincident pairs part in different directions.
        let angle = ((ids.0 * 31 + ids.1 * 17 + k * 7) as f64) * 2.399_963_229_728_653;
        let u = [angle.cos(), angle.sin(), 0.0];
        for a in 0..D {
            c[a] = u[a] * sep[a] * reach - d[a];
        }
    } else {
        let scale = reach / s.sqrt() - 1.0;
        for a in 0..D {
            c[a] = d[a] * scale;
        }
    }
    Some(c)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::problem::{Obstacle, Spheroid, StartState, Team};
    use nalgebra::Vector3;

    /// Two robots held at fixed points (constant coefficients) on a 1-instant
    /// grid in the middle of the horizon.
    fn setup(p0: [f64; 2], p1: [f64; 2], obstacles: Vec<Obstacle>) -> (Problem, SampleGrid, Vec<f64>) {
        let team = Team::default_for(Dim::Two, 2);
        let nx = team.degree + 1;
        let mut xi = vec![0.0; 2 * 2 * nx];
        for (i, p) in [p0, p1].iter().enumerate() {
            for a in 0..2 {
                xi[(a * 2 + i) * nx..(a * 2 + i + 1) * nx].fill(p[a]);
            }
        }
        let problem = Problem {
            team: team.clone(),
            starts: vec![
                StartState::at_rest(Vector3::new(p0[0], p0[1], 0.0)),
                StartState::at_rest(Vector3::new(p1[0], p1[1], 0.0)),
            ],
            goals: vec![Vector3::new(p0[0], p0[1], 0.0), Vector3::new(p1[0], p1[1], 0.0)],
            obstacles,
        };
        (problem, SampleGrid::new(team.degree, vec![0.5]), xi)
    }

    fn corr(p: &Projection, axis: usize, robot: usize) -> f64 {
        p.corr[axis * 2 + robot]
    }

    #[test]
    fn a_violating_pair_is_pushed_apart_to_the_surface_symmetrically() {
        // 0.1 m apart along x, separation 0.2: each gets half of the 0.1 m gap.
        let (problem, grid, xi) = setup([0.0, 0.0], [0.1, 0.0], vec![]);
        let limits = Limits::new(&problem, &grid, 1.0, [0.0; 3]);
        let mut p = Projection::new(Dim::Two, 2, &grid);
        let primal = p.run(Dim::Two, 2, &grid, &limits, &xi);
        // The pair row's target is d / r = (-0.2, 0): the correction is -0.1 on
        // robot 0 and +0.1 on robot 1; the residual is the 0.1 m deficit.
        assert!((corr(&p, 0, 0) + 0.1).abs() < 1e-12 && (corr(&p, 0, 1) - 0.1).abs() < 1e-12);
        assert_eq!((corr(&p, 1, 0), corr(&p, 1, 1)), (0.0, 0.0));
        assert!((primal - 0.1).abs() < 1e-12);
        assert_eq!(p.touched, vec![true, true]);
    }

    #[test]
    fn pairs_outside_the_separation_are_left_alone() {
        let (problem, grid, xi) = setup([0.0, 0.0], [0.15, 0.15], vec![]);
        let limits = Limits::new(&problem, &grid, 1.0, [0.0; 3]);
        let mut p = Projection::new(Dim::Two, 2, &grid);
        assert_eq!(p.run(Dim::Two, 2, &grid, &limits, &xi), 0.0);
        assert!(p.corr.iter().all(|&c| c == 0.0) && p.touched == vec![false, false]);
        // Inflating by 10% makes the same pair (0.212 m apart) violate.
        let inflated = Limits::new(&problem, &grid, 1.1, [0.0; 3]);
        assert!(p.run(Dim::Two, 2, &grid, &inflated, &xi) > 0.0);
    }

    #[test]
    fn coincident_robots_are_parted_along_a_unit_direction() {
        let (problem, grid, xi) = setup([0.3, 0.3], [0.3, 0.3], vec![]);
        let limits = Limits::new(&problem, &grid, 1.0, [0.0; 3]);
        let mut p = Projection::new(Dim::Two, 2, &grid);
        let primal = p.run(Dim::Two, 2, &grid, &limits, &xi);
        let (cx, cy) = (corr(&p, 0, 0), corr(&p, 1, 0));
        assert!(((cx * cx + cy * cy).sqrt() - 0.2).abs() < 1e-12);
        assert!((primal - 0.2).abs() < 1e-12);
    }

    #[test]
    fn a_robot_inside_an_obstacle_is_pushed_out_radially_and_the_box_clamps() {
        let obstacle =
            Obstacle { position: Vector3::new(0.0, 0.0, 0.0), velocity: Vector3::zeros(), shape: Spheroid::ball(0.1) };
        // Robot 0 at (0.1, 0) inside the 0.2 m inflated obstacle; robot 1 at
        // x = 1.05, outside the [-1, 1] box.
        let (problem, grid, xi) = setup([0.1, 0.0], [1.05, 0.5], vec![obstacle]);
        let limits = Limits::new(&problem, &grid, 1.0, [0.0; 3]);
        let mut p = Projection::new(Dim::Two, 2, &grid);
        let primal = p.run(Dim::Two, 2, &grid, &limits, &xi);
        assert!((corr(&p, 0, 0) - 0.1).abs() < 1e-12, "pushed to x = 0.2");
        assert!((corr(&p, 0, 1) + 0.05).abs() < 1e-12, "clamped to x = 1");
        assert!((primal - (0.1 + 0.05)).abs() < 1e-12);
        // A box inset of 0.1 m clamps robot 1 to 0.9 instead.
        let inset = Limits::new(&problem, &grid, 1.0, [0.1; 3]);
        p.run(Dim::Two, 2, &grid, &inset, &xi);
        assert!((corr(&p, 0, 1) + 0.15).abs() < 1e-12);
    }

    #[test]
    fn a_moving_obstacle_is_tracked_in_time() {
        // At tau = 0.5 (t = 2.5 s) an obstacle starting at x = -0.25 moving at
        // 0.1 m/s sits at x = 0: it overlaps a robot at the origin.
        let moving = Obstacle {
            position: Vector3::new(-0.25, 0.0, 0.0),
            velocity: Vector3::new(0.1, 0.0, 0.0),
            shape: Spheroid::ball(0.1),
        };
        let (problem, grid, xi) = setup([0.0, 0.05], [0.8, 0.8], vec![moving]);
        let limits = Limits::new(&problem, &grid, 1.0, [0.0; 3]);
        let mut p = Projection::new(Dim::Two, 2, &grid);
        let primal = p.run(Dim::Two, 2, &grid, &limits, &xi);
        assert!((corr(&p, 1, 0) - 0.15).abs() < 1e-12, "pushed from y = 0.05 to y = 0.2");
        assert!((primal - 0.15).abs() < 1e-12);
    }

    #[test]
    fn the_chord_inflation_pushes_fast_pairs_further_apart() {
        // Two robots 0.21 m apart (beyond the 0.2 m separation) at the
        // middle instant of three, passing each other at 1 m/s relative
        // over instants 0.1 s apart: the straight motion between instants
        // dips to 0.2 * ... below the separation, so the chord target asks
        // for more.
        let team = Team::default_for(Dim::Two, 2);
        let problem = setup([0.0, 0.0], [0.21, 0.0], vec![]).0;
        let grid = SampleGrid::new(team.degree, vec![0.45, 0.5, 0.55]);
        let nx = team.degree + 1;
        // Robot 0 still at the origin; robot 1 moving along y at 1 m/s
        // (T = 5 s, so 0.25 m between these instants), at x = 0.21.
        let mut xi = vec![0.0; 2 * 2 * nx];
        for c in 0..nx {
            let tau = c as f64 / (nx - 1) as f64;
            xi[nx + c] = 0.21;
            xi[3 * nx + c] = 5.0 * (tau - 0.5);
        }
        let plain = Limits::new(&problem, &grid, 1.0, [0.0; 3]);
        let mut p = Projection::new(Dim::Two, 2, &grid);
        assert_eq!(p.run(Dim::Two, 2, &grid, &plain, &xi), 0.0, "clear at every instant");
        let chord = plain.clone().with_rules(true, false, false);
        let primal = p.run(Dim::Two, 2, &grid, &chord, &xi);
        assert!(primal > 0.0, "the chords between the instants dip through the separation");
        // The middle instant is pushed to sqrt(1 + L^2/4) separations, L =
        // 0.25 / 0.2 the scaled move: 0.2 * sqrt(1 + 1.25^2 / 4) = 0.2358 m.
        let target = 0.2 * (1.0f64 + 1.25 * 1.25 / 4.0).sqrt();
        assert!((corr(&p, 1, 1) - corr(&p, 0, 1) - (target - 0.21)).abs() < 1e-9);
    }

    /// `iterations` iterations of the optimiser with `settings` on
    /// `problem` from its cold start, every residual recorded.
    fn optimise(problem: &Problem, settings: crate::am::AmSettings, iterations: usize) -> crate::am::AmOutcome {
        use crate::am::{Engine, Objective};
        let mut settings = settings.residual_study(-1.0);
        settings.max_iterations = iterations;
        let engine = Engine::new(&problem.team, problem.obstacles.len(), Objective::smoothness(), settings).unwrap();
        let prepared = engine.prepare(problem, None).unwrap();
        engine.run(&prepared, engine.cold_start(&prepared))
    }

    #[test]
    fn the_two_thread_iteration_equals_the_one_thread_one_up_to_rounding() {
        use crate::am::AmSettings;
        use crate::scenario::RandomScenario;
        let team = Team {
            workspace: crate::problem::Workspace::centred(crate::scenes::density_half_width(
                Dim::Two,
                TWO_THREADS_MIN_ROBOTS,
            )),
            ..Team::default_for(Dim::Two, TWO_THREADS_MIN_ROBOTS)
        };
        let problem = RandomScenario::new(team.clone()).generate(3).unwrap();
        let run = |two_threads| optimise(&problem, AmSettings { two_threads, ..AmSettings::optimiser() }, 40);
        let (two, one) = (run(true), run(false));
        assert!(one.history.iter().all(|r| r.primal > 0.0), "the pairs are exercised");
        let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-9 * (1.0 + y.abs()));
        assert!(close(&two.state.xi, &one.state.xi) && close(&two.state.lambda, &one.state.lambda));
        let primal = |h: &[crate::am::Residuals]| h.iter().map(|r| r.primal).collect::<Vec<f64>>();
        assert!(close(&primal(&two.history), &primal(&one.history)));
        // The split is fixed, so two threads repeat themselves exactly.
        assert_eq!(two.state, run(true).state);
    }

    #[test]
    fn stopping_at_the_first_violation_decides_as_the_whole_projection_does() {
        use crate::am::{AmSettings, Engine, Objective};
        use crate::scenario::RandomScenario;
        let team = Team { workspace: crate::problem::Workspace::centred(1.6), ..Team::default_for(Dim::Two, 40) };
        let problem = RandomScenario::new(team.clone()).with_obstacles(2).generate(1).unwrap();
        let engine = Engine::new(&team, 2, Objective::smoothness(), AmSettings::optimiser()).unwrap();
        let prepared = engine.prepare(&problem, None).unwrap();
        let solved = engine.solve_prepared(&prepared).state.xi;
        let mut verdicts = Vec::new();
        // Kept across the iterates: each call checks first the pair the
        // previous one stopped at.
        let mut kept = [Projection::new(Dim::Two, 40, &engine.grid), Projection::new(Dim::Two, 40, &engine.dense)];
        for xi in [
            optimise(&problem, AmSettings::optimiser(), 0).state.xi,
            optimise(&problem, AmSettings::optimiser(), 30).state.xi,
            solved,
        ] {
            for (g, (grid, limits)) in
                [(&engine.grid, &prepared.constraint), (&engine.dense, &prepared.verify)].into_iter().enumerate()
            {
                let clear = Projection::new(Dim::Two, 40, grid).clear(Dim::Two, 40, grid, limits, &xi);
                let residual = Projection::new(Dim::Two, 40, grid).run(Dim::Two, 40, grid, limits, &xi);
                assert_eq!(clear, residual == 0.0, "residual {residual}");
                assert_eq!(kept[g].clear(Dim::Two, 40, grid, limits, &xi), clear);
                verdicts.push(clear);
            }
        }
        assert!(verdicts.contains(&true) && verdicts.contains(&false), "{verdicts:?}");
    }

    #[test]
    fn the_broad_phase_iteration_equals_the_all_pairs_one() {
        use crate::am::AmSettings;
        use crate::scenario::RandomScenario;
        let team = Team { workspace: crate::problem::Workspace::centred(1.6), ..Team::default_for(Dim::Two, 40) };
        for seed in 0..3 {
            let problem = RandomScenario::new(team.clone()).with_obstacles(2).generate(seed).unwrap();
            let run = |broad_phase| optimise(&problem, AmSettings { broad_phase, ..AmSettings::optimiser() }, 60);
            let (broad, all) = (run(true), run(false));
            assert!(all.history.iter().any(|r| r.primal > 0.0), "the pairs are exercised");
            assert_eq!(broad.state, all.state, "seed {seed}");
            let bits = |h: &[crate::am::Residuals]| -> Vec<(u64, u64)> {
                h.iter().map(|r| (r.primal.to_bits(), r.fixed_point.to_bits())).collect()
            };
            assert_eq!(bits(&broad.history), bits(&all.history), "seed {seed}");
        }
    }
}
