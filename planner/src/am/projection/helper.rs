//! The pair helper of the biggest teams: a second thread, alive for a
//! run, that evaluates each iterate's positions itself, finds the broad
//! phase's pairs, hands the first half back and checks the second half
//! into corrections of its own, mapped to coefficients. The protocol: the
//! main thread sends the iterate ([`Stage::Evaluating`]), clamps the box
//! meanwhile, takes the first half of the pairs ([`Stage::Checking`]),
//! checks them, maps its corrections and adds the helper's
//! ([`Projection::collect`]).

use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, sync_channel};
use std::thread::Scope;
use std::time::Instant;

use super::super::pairs::{BroadPhase, Candidate};
use super::check::{Check, clear_touched, reach_shares, robot_steps};
use super::grid::SampleGrid;
use super::limits::Limits;
use super::memory::{Job, PairHelper, Projection, Share, Stage};
use crate::linalg::{Accum, gemm};
use crate::problem::Dim;

/// How long a waiting side of the pair helper spins before it blocks: longer
/// than the rest of an iteration of the biggest teams, so that neither side
/// sleeps between iterations (waking an idle core costs tens of
/// microseconds on these hosts).
/// Teams at least this large check their pairs on two threads when their
/// limits ask for it (docs/BENCHMARKS.md, "Big teams").
pub const TWO_THREADS_MIN_ROBOTS: usize = 128;

pub(super) const SPIN: std::time::Duration = std::time::Duration::from_millis(2);

impl Projection {
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
    pub(super) fn start_helper(&mut self, robots: usize, limits: &Limits, xi: &[f64]) {
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

    /// With the helper checking pairs: maps this thread's corrections to
    /// coefficients meanwhile, adds the helper's and returns the helper's
    /// sum of `||c||^2` (0 without). Should the helper be gone, this thread
    /// checks its half of the pairs too, and the rest of the run alone.
    pub(super) fn collect<const D: usize>(&mut self, n: usize, grid: &SampleGrid, limits: &Limits) -> f64 {
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
}

/// The helper's loop: each job's positions from its iterate, its broad
/// phase, the first half of the pairs sent back, then the second half's
/// corrections, until the projection hangs up.
pub(super) fn serve(
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

/// The next message, spinning for up to [`SPIN`] before blocking; `None`
/// once the other side hung up.
pub(super) fn receive<T>(from: &Receiver<T>) -> Option<T> {
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
