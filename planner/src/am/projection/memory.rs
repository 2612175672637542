//! A projection's working memory: positions and corrections at a grid,
//! their coefficients, the pair checks' broad phase, and each crew part's
//! and each robot block's own.

use super::super::pairs::{BroadPhase, Candidate};
use super::check::{Hit, Scratch};
use super::grid::SampleGrid;
use crate::problem::Dim;

/// Robots per block of the per-robot steps (positions, obstacles, the box,
/// the products): the blocks, not the crew's size, decide every product's
/// rows and every sum's order, so plans do not depend on the threads.
pub(crate) const ROBOT_BLOCK: usize = 16;

/// The robots of block `b` of a team of `n`.
pub(crate) fn block_robots(b: usize, n: usize) -> std::ops::Range<usize> {
    b * ROBOT_BLOCK..((b + 1) * ROBOT_BLOCK).min(n)
}

/// Positions and corrections at a grid: the projection's working memory.
#[derive(Debug)]
pub(crate) struct Projection {
    /// Positions `[axis][robot][count]`.
    pub pos: Vec<f64>,
    /// Corrections `e - F xi` summed per robot, `[axis][robot][count]`.
    pub corr: Vec<f64>,
    /// The corrections mapped to coefficients, `g = corr P`,
    /// `[axis][robot][coef]` (after [`Self::run`], not [`Self::clear`]).
    pub(super) mapped: Vec<f64>,
    /// Robots with any non-zero correction.
    pub touched: Vec<bool>,
    /// Each crew part's memory (one at least).
    pub(super) parts: Vec<PartMemory>,
    /// On a crew, the corrections of the violating pairs, routed to the
    /// parts that add them (apart from [`PartMemory`], since parts read
    /// each other's while they write their own scratch).
    pub(super) routed: Routed,
    /// Each robot block's results.
    pub(super) blocks: Vec<BlockSums>,
    pub(super) broad: BroadPhase,
    /// Every pair, in order (teams checked without the broad phase).
    pub(super) all: Vec<Candidate>,
    /// Each robot's largest scaled move between instants (chord inflation).
    pub(super) steps: Vec<f64>,
    /// Each robot's share of the broad phase's reach, per axis (m).
    pub(super) grow: Vec<[f64; 3]>,
    /// Per obstacle, the largest squared target a robot can have against it
    /// this iteration (with the chord inflation).
    pub(super) obstacle_bounds: Vec<Option<f64>>,
    /// Stop at the first violation with an infinite sum ([`Self::clear`]).
    pub(super) first: bool,
    /// The pair the last [`Self::clear`] stopped at: checked first by the
    /// next, since while a run converges the same pair tends to stay short.
    pub(super) culprit: Option<(u32, u32)>,
}

/// One crew part's memory: its pair checks' scratch and what they found.
#[derive(Debug, Clone)]
pub(super) struct PartMemory {
    pub(super) scratch: Scratch,
    /// Stopping at the first violation: the violating pair it found.
    pub(super) found: Option<Candidate>,
}

/// One robot block's results of a projection, summed block by block.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct BlockSums {
    /// The largest move between neighbouring instants of its robots, per axis.
    pub(super) largest: [f64; 3],
    /// Sum of the squared pair corrections of the pairs `(i, j)` with `i`
    /// in the block.
    pub(super) pair_sq: f64,
    /// Sum of the squared obstacle corrections.
    pub(super) obstacle_sq: f64,
    /// Sum of the squared box corrections.
    pub(super) box_sq: f64,
    /// Stopping at the first violation: one of its robots meets an obstacle.
    pub(super) violated: bool,
    /// Its robots stay within the broad phase's kept boxes
    /// ([`BroadPhase::still_covers`]).
    pub(super) covered: bool,
}

impl Projection {
    /// Buffers for `robots` robots in `dim` on `grid`.
    pub fn new(dim: Dim, robots: usize, grid: &SampleGrid) -> Self {
        let len = dim.axes() * robots * grid.count();
        let count = grid.count();
        let n_xi = grid.pt.len() / count.max(1);
        Self {
            pos: vec![0.0; len],
            corr: vec![0.0; len],
            mapped: vec![0.0; dim.axes() * robots * n_xi],
            touched: vec![false; robots],
            parts: vec![PartMemory::new(count)],
            routed: Routed::default(),
            blocks: vec![BlockSums::default(); robots.div_ceil(ROBOT_BLOCK)],
            broad: BroadPhase::default(),
            all: Vec::new(),
            steps: vec![0.0; robots],
            grow: vec![[0.0; 3]; robots],
            obstacle_bounds: Vec::new(),
            first: false,
            culprit: None,
        }
    }

    /// Memory for a crew of `parts` parts.
    pub(super) fn ensure_parts(&mut self, parts: usize, count: usize) {
        if self.parts.len() < parts {
            self.parts.resize(parts, PartMemory::new(count));
        }
        self.routed.ensure_parts(parts);
    }
}

/// The pairs' hits of one step on a crew, each in the lists of the parts
/// that add it (the part of the block of its robot `i`, and of `j`'s):
/// a part adding its robots' corrections reads only the hits on them,
/// instead of every hit of the step (which, on many threads, every part
/// reading everything made as slow as one).
#[derive(Debug, Default)]
pub(super) struct Routed {
    /// `[checking part][adding part]`: the hits one part found for
    /// another, chunk after chunk, in candidate order within each.
    pub(super) lists: Vec<Vec<Vec<Hit>>>,
    /// Per chunk of candidates, the part that checked it.
    pub(super) checker: Vec<u32>,
    /// Per chunk and adding part (`chunk * parts + part`), the range of the
    /// chunk's hits in its checker's list for that part.
    pub(super) ranges: Vec<[u32; 2]>,
}

impl Routed {
    /// Lists for a crew of `parts` parts.
    fn ensure_parts(&mut self, parts: usize) {
        if self.lists.len() < parts {
            self.lists.resize_with(parts, Vec::new);
        }
        for lists in &mut self.lists {
            if lists.len() < parts {
                lists.resize_with(parts, Vec::new);
            }
        }
    }

    /// Ready for a step of `chunks` chunks on `parts` parts.
    pub(super) fn prepare(&mut self, parts: usize, chunks: usize) {
        self.checker.resize(chunks, 0);
        self.ranges.resize(chunks * parts, [0; 2]);
    }

    /// After a step on `parts` parts: room in every checking part's list
    /// for all the hits its adding part got, so that warm iterations do
    /// not allocate whichever part is faster.
    pub(super) fn reserve(&mut self, parts: usize) {
        for adder in 0..parts {
            let total: usize = self.lists[..parts].iter().map(|l| l[adder].len()).sum();
            for lists in &mut self.lists[..parts] {
                let list = &mut lists[adder];
                list.reserve(total.saturating_sub(list.len()));
            }
        }
    }
}

impl PartMemory {
    fn new(count: usize) -> Self {
        Self { scratch: Scratch { target: vec![1.0; count], step: vec![0.0; count] }, found: None }
    }
}
