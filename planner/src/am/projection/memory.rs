//! A projection's working memory: positions and corrections at a grid,
//! the pair checks' scratch and broad phase, and the pair helper's end.

use std::sync::mpsc::{Receiver, SyncSender};

use super::super::pairs::{BroadPhase, Candidate};
use super::check::Scratch;
use super::grid::SampleGrid;
use crate::problem::Dim;

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
    pub(super) mapped: Vec<f64>,
    /// Robots with any non-zero correction.
    pub touched: Vec<bool>,
    /// One pair's squared targets and moves per instant.
    pub(super) scratch: Scratch,
    pub(super) broad: BroadPhase,
    /// Each robot's largest scaled move between instants (chord inflation).
    pub(super) steps: Vec<f64>,
    /// Each robot's share of the broad phase's reach, per axis (m).
    pub(super) grow: Vec<[f64; 3]>,
    /// The thread that checks the second half of the pairs (two threads only).
    pub(super) helper: Option<PairHelper>,
    /// Stop at the first violation with an infinite sum ([`Self::clear`]).
    pub(super) first: bool,
    /// The pair the last [`Self::clear`] stopped at: checked first by the
    /// next, since while a run converges the same pair tends to stay short.
    pub(super) culprit: Option<(u32, u32)>,
}

/// The main thread's end of a pair helper ([`Projection::with_helper`]).
#[derive(Debug)]
pub(super) struct PairHelper {
    /// The iterate: the helper evaluates its positions and finds the pairs
    /// while this thread evaluates its own and clamps them into the box.
    pub(super) jobs: SyncSender<Job>,
    /// The first half of the pairs, for this thread.
    pub(super) firsts: Receiver<Vec<Candidate>>,
    /// The job back, with the helper's corrections for the second half.
    pub(super) done: Receiver<Job>,
    /// The job's buffers between iterations.
    pub(super) spare: Option<Job>,
    /// The first half's buffer between iterations.
    pub(super) spare_pairs: Vec<Candidate>,
    /// Where the helper is in the current iteration.
    pub(super) stage: Stage,
    /// Address of the limits the helper checks against (compared, never read).
    pub(super) limits: usize,
}

/// Where a pair helper is in an iteration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Stage {
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
pub(super) struct Job {
    pub(super) xi: Vec<f64>,
    pub(super) pairs: Vec<Candidate>,
    pub(super) share: Share,
    /// `share.corr P`, `[axis][robot][coef]`.
    pub(super) mapped: Vec<f64>,
    pub(super) sum: f64,
}

/// One thread's corrections and working memory for its share of the pairs.
#[derive(Debug, Clone)]
pub(super) struct Share {
    pub(super) corr: Vec<f64>,
    pub(super) touched: Vec<bool>,
    pub(super) scratch: Scratch,
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
}
