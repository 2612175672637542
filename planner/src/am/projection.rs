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

use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, sync_channel};
use std::thread::Scope;
use std::time::Instant;

use super::pairs::{BROAD_PHASE_MIN_ROBOTS, BroadPhase};
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
        let team = &problem.team;
        let dim = team.dim.axes();
        let (a, b) = team.separation();
        let count = grid.count();
        let mut tracks = vec![0.0; problem.obstacles.len() * dim * count];
        let mut obstacle_sep = Vec::with_capacity(problem.obstacles.len());
        for (m, o) in problem.obstacles.iter().enumerate() {
            for ax in 0..dim {
                for (k, tau) in grid.taus.iter().enumerate() {
                    tracks[(m * dim + ax) * count + k] = o.position[ax] + o.velocity[ax] * tau * team.horizon;
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
    /// Corrections `e - F xi` summed per robot, `[axis][robot][count]`.
    pub corr: Vec<f64>,
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
}

/// The main thread's end of a pair helper ([`Projection::with_helper`]).
#[derive(Debug)]
struct PairHelper {
    jobs: SyncSender<Job>,
    done: Receiver<Job>,
    /// The job's buffers between iterations.
    spare: Option<Job>,
    /// Address of the limits the helper checks against (compared, never read).
    limits: usize,
}

/// Half of an iteration's pairs for the helper, with the iterate it
/// evaluates its own positions from, and its corrections back.
#[derive(Debug)]
struct Job {
    xi: Vec<f64>,
    pairs: Vec<(u32, u32)>,
    share: Share,
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
            touched: vec![false; robots],
            scratch: Scratch { target: vec![1.0; count], step: vec![0.0; count] },
            broad: BroadPhase::default(),
            steps: Vec::with_capacity(robots),
            grow: Vec::with_capacity(robots),
            helper: None,
        }
    }

    /// The same projection checking the second half of the broad phase's
    /// pairs against `limits` on a helper thread of `scope`, which stays
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
        let (outbox, done) = sync_channel(1);
        scope.spawn(move || serve(dim, robots, grid, limits, &inbox, &outbox));
        self.helper = Some(PairHelper { jobs, done, spare: None, limits: std::ptr::from_ref(limits) as usize });
        self
    }

    /// Evaluates `xi` (`[axis][robot][coef]`) on `grid`, computes every
    /// correction against `limits` and returns the primal residual.
    pub fn run(&mut self, dim: Dim, robots: usize, grid: &SampleGrid, limits: &Limits, xi: &[f64]) -> f64 {
        let count = grid.count();
        let n_xi = grid.pt.len() / count;
        let rows = dim.axes() * robots;
        gemm(&mut self.pos, xi, &grid.pt, rows, n_xi, count, Accum::Replace);
        self.corr.fill(0.0);
        self.touched.fill(false);
        if !limits.chord {
            self.scratch.target.fill(1.0);
        }
        let collisions = match dim {
            Dim::Two => self.pairs::<2>(robots, count, limits, xi) + self.obstacles::<2>(robots, count, limits),
            Dim::Three => self.pairs::<3>(robots, count, limits, xi) + self.obstacles::<3>(robots, count, limits),
        };
        let mut box_sq = 0.0;
        for ax in 0..dim.axes() {
            let (lo, hi) = (limits.lo[ax], limits.hi[ax]);
            for i in 0..robots {
                let range = (ax * robots + i) * count..(ax * robots + i + 1) * count;
                let mut any = false;
                for (p, c) in self.pos[range.clone()].iter().zip(&mut self.corr[range]) {
                    let d = p.clamp(lo, hi) - p;
                    *c += d;
                    box_sq += d * d;
                    any |= d != 0.0;
                }
                self.touched[i] |= any;
            }
        }
        collisions.sqrt() + box_sq.sqrt()
    }

    /// Inter-robot corrections for every pair `i < j` (every candidate of
    /// the broad phase, in the same order): where the scaled distance `r` is
    /// below its target `t` (1, or more with the chord inflation) the offset
    /// is pushed to it, `c = d (t/r - 1)`, added to `i` and taken from `j`.
    /// Returns the sum of `||c||^2`.
    fn pairs<const D: usize>(&mut self, n: usize, count: usize, limits: &Limits, xi: &[f64]) -> f64 {
        let sep = limits.robot_sep;
        let inv = sep.map(|s| 1.0 / (s * s));
        let Projection { pos, corr, touched, scratch, broad, steps, grow, helper } = self;
        // A pair's chord inflation is at most sqrt(1 + (s_i + s_j)^2 / 4) <=
        // 1 + (s_i + s_j) / 2 separations, s the robots' largest scaled moves
        // between instants: robot i's share of the reach is (1 + s_i) / 2.
        if limits.chord {
            robot_steps(pos, D, n, count, &inv, steps);
        } else {
            steps.clear();
            steps.resize(n, 0.0);
        }
        let check = Check { pos, steps, n, count, limits, inv };
        if !(limits.broad_phase && n >= BROAD_PHASE_MIN_ROBOTS) {
            let all = (0..n as u32).flat_map(move |i| (i + 1..n as u32).map(move |j| (i, j)));
            return check.push::<D>(all, scratch, corr, touched);
        }
        grow.clear();
        grow.extend(steps.iter().map(|s| sep.map(|x| x * 0.5 * (1.0 + s))));
        let candidates = broad.candidates(pos, D, n, count, grow);
        let Some(link) = helper.as_mut().filter(|h| h.limits == std::ptr::from_ref(limits) as usize) else {
            return check.push::<D>(candidates.iter().copied(), scratch, corr, touched);
        };
        // The second half of the pairs on the helper, into its own
        // corrections, added after: the same iteration up to rounding.
        let (first, second) = candidates.split_at(candidates.len() / 2);
        let mut job = link.spare.take().unwrap_or_else(|| Job {
            xi: Vec::new(),
            pairs: Vec::new(),
            share: Share { corr: vec![0.0; corr.len()], touched: vec![false; n], scratch: scratch.clone() },
            sum: 0.0,
        });
        job.xi.clear();
        job.xi.extend_from_slice(xi);
        job.pairs.clear();
        job.pairs.extend_from_slice(second);
        let sent = link.jobs.send(job).is_ok();
        let mine = check.push::<D>(first.iter().copied(), scratch, corr, touched);
        let Some(job) = sent.then(|| receive(&link.done)).flatten() else {
            // The helper is gone (it panicked; the scope reports it): this
            // thread checks its half too, and the rest of the run alone.
            *helper = None;
            return mine + check.push::<D>(second.iter().copied(), scratch, corr, touched);
        };
        for (c, t) in corr.iter_mut().zip(&job.share.corr) {
            *c += t;
        }
        for (t, u) in touched.iter_mut().zip(&job.share.touched) {
            *t |= u;
        }
        let theirs = job.sum;
        link.spare = Some(job);
        mine + theirs
    }

    /// Robot-obstacle corrections: where robot `i` is inside the (scaled)
    /// obstacle `m` at an instant, its position is pushed to the surface.
    fn obstacles<const D: usize>(&mut self, n: usize, count: usize, limits: &Limits) -> f64 {
        let stride = n * count;
        let Projection { pos, corr, touched, scratch, .. } = self;
        let robot_steps = if limits.chord { largest_steps(pos, D, n, count) } else { [0.0; 3] };
        let mut sum = 0.0;
        for (m, sep) in limits.obstacle_sep.iter().enumerate() {
            let inv = sep.map(|s| 1.0 / (s * s));
            let rows = &limits.tracks[m * D * count..(m + 1) * D * count];
            let track: [&[f64]; D] = std::array::from_fn(|a| &rows[a * count..(a + 1) * count]);
            let bound = limits.chord.then(|| largest_target(&robot_steps, &largest_steps(rows, D, 1, count), &inv));
            for i in 0..n {
                let pi: [&[f64]; D] =
                    std::array::from_fn(|a| &pos[a * stride + i * count..a * stride + (i + 1) * count]);
                if !scratch.violated::<D>(&pi, &track, &inv, bound) {
                    continue;
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
    /// Whether `p` and `q` come closer than their target at any instant
    /// (the screen every pair goes through; vectorises over instants).
    /// Leaves the per-instant targets for [`push`].
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
    ) -> bool {
        let count = self.target.len();
        let p: [&[f64]; D] = std::array::from_fn(|a| &p[a][..count]);
        let q: [&[f64]; D] = std::array::from_fn(|a| &q[a][..count]);
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
        let step = &mut self.step[..count];
        step[count - 1] = 0.0;
        for k in 0..count - 1 {
            let mut l = 0.0;
            for a in 0..D {
                let m = (p[a][k + 1] - q[a][k + 1]) - (p[a][k] - q[a][k]);
                l += m * m * inv[a];
            }
            step[k] = l;
        }
        let target = &mut self.target[..count];
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

/// The helper's loop: each job's positions from its iterate, then its pairs'
/// corrections, until the projection hangs up.
fn serve(dim: Dim, n: usize, grid: &SampleGrid, limits: &Limits, jobs: &Receiver<Job>, done: &SyncSender<Job>) {
    let count = grid.count();
    let (rows, n_xi) = (dim.axes() * n, grid.pt.len() / count);
    let inv = limits.robot_sep.map(|s| 1.0 / (s * s));
    let (mut pos, mut steps) = (vec![0.0; rows * count], Vec::with_capacity(n));
    while let Some(mut job) = receive(jobs) {
        gemm(&mut pos, &job.xi, &grid.pt, rows, n_xi, count, Accum::Replace);
        if limits.chord {
            robot_steps(&pos, dim.axes(), n, count, &inv, &mut steps);
        } else {
            steps.clear();
            steps.resize(n, 0.0);
        }
        let check = Check { pos: &pos, steps: &steps, n, count, limits, inv };
        let Share { corr, touched, scratch } = &mut job.share;
        corr.fill(0.0);
        touched.fill(false);
        if !limits.chord {
            scratch.target.fill(1.0);
        }
        let pairs = job.pairs.iter().copied();
        job.sum = match dim {
            Dim::Two => check.push::<2>(pairs, scratch, corr, touched),
            Dim::Three => check.push::<3>(pairs, scratch, corr, touched),
        };
        if done.send(job).is_err() {
            return;
        }
    }
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
    /// Pushes apart every violating pair of `pairs` (`i < j`, in order),
    /// adding to `corr` and marking `touched`; returns the sum of `||c||^2`.
    fn push<const D: usize>(
        &self,
        pairs: impl Iterator<Item = (u32, u32)>,
        scratch: &mut Scratch,
        corr: &mut [f64],
        touched: &mut [bool],
    ) -> f64 {
        let (pos, count, inv, sep) = (self.pos, self.count, &self.inv, &self.limits.robot_sep);
        let stride = self.n * count;
        let mut sum = 0.0;
        for (i, j) in pairs {
            let (i, j) = (i as usize, j as usize);
            let pi: [&[f64]; D] = std::array::from_fn(|a| &pos[a * stride + i * count..a * stride + (i + 1) * count]);
            let pj: [&[f64]; D] = std::array::from_fn(|a| &pos[a * stride + j * count..a * stride + (j + 1) * count]);
            let bound = self.limits.chord.then(|| 1.0 + 0.25 * (self.steps[i] + self.steps[j]).powi(2));
            if !scratch.violated::<D>(&pi, &pj, inv, bound) {
                continue;
            }
            touched[i] = true;
            touched[j] = true;
            for k in 0..count {
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

/// Each of `n` robots' largest move between neighbouring instants, scaled
/// by `inv`, into `out`.
fn robot_steps(pos: &[f64], axes: usize, n: usize, count: usize, inv: &[f64; 3], out: &mut Vec<f64>) {
    out.clear();
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
