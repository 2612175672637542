//! The steps of one projection on a crew: positions per robot block, the
//! robot pairs (every pair, or the broad phase's candidates) checked in
//! shares and their corrections added in pair order, then the obstacles,
//! the box and the mapping to coefficients per robot block.
//!
//! Every correction lands in the same order whatever the crew's size: a
//! pair's hits in candidate order (one thread adds them), a robot's
//! obstacle corrections obstacle by obstacle, then its box clamp; sums
//! are taken per robot block and added in block order.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use super::super::pairs::{BROAD_PHASE_MIN_ROBOTS, Candidate, KEEP_MIN_ROBOTS};
use super::check::{Check, all_pairs, largest_steps, largest_target, push, reach_share, robot_rows, robot_step};
use super::grid::SampleGrid;
use super::limits::Limits;
use super::memory::{BlockSums, PartMemory, Projection, ROBOT_BLOCK, Routed, block_robots};
use crate::crew::{Crew, Disjoint, owner, share};
use crate::linalg::{Accum, gemm};
use crate::problem::Against;

/// Rows `[axis][robot]` of robots `robots` on axis `a`, `n` robots, each
/// `width` long: the range of the flat buffer.
fn block_rows(a: usize, n: usize, robots: &std::ops::Range<usize>, width: usize) -> std::ops::Range<usize> {
    (a * n + robots.start) * width..(a * n + robots.end) * width
}

/// Candidates a crew part checks at a time (it takes the next chunk left,
/// so parts whose pairs violate more take fewer).
const PAIR_CHUNK: usize = 64;

impl Projection {
    /// Positions of `xi` on `grid`, per robot block: each robot's largest
    /// scaled move and share of the broad phase's reach, each block's
    /// largest move per axis; last iteration's corrections cleared.
    pub(super) fn evaluate<const D: usize>(
        &mut self,
        crew: &Crew<'_>,
        n: usize,
        grid: &SampleGrid,
        limits: &Limits,
        xi: &[f64],
    ) {
        let count = grid.count();
        let n_xi = grid.pt.len() / count;
        let blocks = n.div_ceil(ROBOT_BLOCK);
        let sep = limits.robot_sep;
        let inv = sep.map(|s| 1.0 / (s * s));
        let chord = limits.chord;
        let keep = limits.broad_phase && n >= BROAD_PHASE_MIN_ROBOTS.max(KEEP_MIN_ROBOTS);
        let Projection { pos, corr, touched, steps, grow, blocks: sums, broad, .. } = self;
        let broad = &*broad;
        let (pos, corr, touched) = (Disjoint::new(pos), Disjoint::new(corr), Disjoint::new(touched));
        let (steps, grow, sums) = (Disjoint::new(steps), Disjoint::new(grow), Disjoint::new(sums));
        crew.each(blocks, &|_, b| {
            let robots = block_robots(b, n);
            // SAFETY: each block's rows and robots belong to one part.
            let touched = unsafe { touched.range(robots.clone()) };
            let mut largest = [0.0; 3];
            for a in 0..D {
                let (rows, coefs) = (block_rows(a, n, &robots, count), block_rows(a, n, &robots, n_xi));
                // SAFETY: as above.
                let (pos, corr) = unsafe { (pos.range(rows.clone()), corr.range(rows)) };
                gemm(pos, &xi[coefs], &grid.pt, robots.len(), n_xi, count, Accum::Replace);
                for (row, t) in corr.chunks_exact_mut(count).zip(touched.iter()) {
                    if *t {
                        row.fill(0.0);
                    }
                }
                if chord {
                    largest[a] = largest_steps(pos, 1, robots.len(), count)[0];
                }
            }
            touched.fill(false);
            let mut covered = keep;
            for i in robots.clone() {
                // SAFETY: the block's rows were written above by this part.
                let rows: [&[f64]; D] =
                    std::array::from_fn(|a| unsafe { &*pos.range((a * n + i) * count..(a * n + i + 1) * count) });
                let step = if chord { robot_step::<D>(&rows, &inv) } else { 0.0 };
                let share = reach_share(step, &sep);
                if covered {
                    let rows: [&[f64]; 3] = std::array::from_fn(|a| if a < D { rows[a] } else { &[] });
                    covered = broad.still_covers_robot(D, n, count, i, &rows, &share);
                }
                // SAFETY: robot `i` belongs to this part's block.
                unsafe {
                    *steps.at(i) = step;
                    *grow.at(i) = share;
                }
            }
            unsafe { *sums.at(b) = BlockSums { largest, covered, ..BlockSums::default() } };
        });
    }

    /// The pairs to check: the broad phase's candidates (teams of
    /// [`BROAD_PHASE_MIN_ROBOTS`] or more where `limits` ask for it), else
    /// every pair.
    pub(super) fn candidates<const D: usize>(&mut self, crew: &Crew<'_>, n: usize, count: usize, limits: &Limits) {
        if limits.broad_phase && n >= BROAD_PHASE_MIN_ROBOTS {
            // Whether every robot stays within the kept boxes was found per
            // block with the positions.
            let covered = self.blocks[..n.div_ceil(ROBOT_BLOCK)].iter().all(|b| b.covered);
            self.broad.candidates_covered(crew, covered, &self.pos, D, n, count, &self.grow);
            return;
        }
        let pairs = n * n.saturating_sub(1) / 2;
        if self.all.len() != pairs || self.all.first().is_some_and(|c| c.to as usize != count) {
            self.all.clear();
            self.all.extend(all_pairs(n, count));
        }
    }

    /// Checks the candidates, [`PAIR_CHUNK`] at a time, each part taking
    /// the next chunk left: alone, adding the corrections as it goes (and
    /// their `||c||^2` to the blocks' sums); on a crew, each part's hits
    /// routed to the parts that add them ([`Routed`]), and each chunk's
    /// place among them ([`Self::per_block`] adds them in candidate order).
    /// Stopping at the first violation, the violating pair a part found
    /// instead.
    pub(super) fn check_pairs<const D: usize>(
        &mut self,
        crew: &Crew<'_>,
        n: usize,
        count: usize,
        limits: &Limits,
        broad: bool,
    ) {
        let inv = limits.robot_sep.map(|s| 1.0 / (s * s));
        let Projection { pos, corr, touched, steps, parts, routed, broad: phase, all, first, blocks, .. } = self;
        let candidates: &[Candidate] = if broad { phase.current() } else { all };
        let check = Check { pos, steps, n, count, limits, inv };
        let first = *first;
        if crew.size() == 1 {
            let PartMemory { scratch, found, .. } = &mut parts[0];
            if first {
                *found = candidates.iter().copied().find(|&pair| check.violates::<D>(pair, scratch));
            } else {
                let add = |i: usize, sum: f64| blocks[i / ROBOT_BLOCK].pair_sq += sum;
                check.push::<D>(candidates.iter().copied(), scratch, corr, touched, add);
            }
            return;
        }
        let size = crew.size();
        let chunks = candidates.len().div_ceil(PAIR_CHUNK);
        routed.prepare(size, chunks);
        let next = AtomicUsize::new(0);
        let found = AtomicBool::new(false);
        let Routed { lists, checker, ranges } = routed;
        // The part that adds a robot's corrections: the one whose share of
        // the blocks ([`Self::per_block`]) holds the robot's.
        let blocks = n.div_ceil(ROBOT_BLOCK);
        let adder = |robot: usize| owner(robot / ROBOT_BLOCK, size, blocks);
        let (parts, lists) = (Disjoint::new(parts), Disjoint::new(lists));
        let (checker, ranges) = (Disjoint::new(checker), Disjoint::new(ranges));
        crew.run(&|part| {
            // SAFETY: each part takes its own memory and lists, each chunk
            // one part.
            let (PartMemory { scratch, found: mine }, lists) = unsafe { (parts.at(part), lists.at(part)) };
            let lists = &mut lists[..size];
            lists.iter_mut().for_each(Vec::clear);
            *mine = None;
            loop {
                let chunk = next.fetch_add(1, Ordering::Relaxed);
                if chunk >= chunks || (first && found.load(Ordering::Relaxed)) {
                    break;
                }
                let pairs = &candidates[chunk * PAIR_CHUNK..((chunk + 1) * PAIR_CHUNK).min(candidates.len())];
                // SAFETY: as above.
                let ranges = unsafe { ranges.range(chunk * size..(chunk + 1) * size) };
                for (range, list) in ranges.iter_mut().zip(lists.iter()) {
                    range[0] = list.len() as u32;
                }
                if !first {
                    check.hits::<D>(pairs, scratch, lists, &adder);
                } else if let Some(&pair) = pairs.iter().find(|&&pair| check.violates::<D>(pair, scratch)) {
                    *mine = Some(pair);
                    found.store(true, Ordering::Relaxed);
                }
                for (range, list) in ranges.iter_mut().zip(lists.iter()) {
                    range[1] = list.len() as u32;
                }
                // SAFETY: as above.
                unsafe { *checker.at(chunk) = part as u32 };
            }
        });
        self.routed.reserve(size);
    }

    /// Per robot block: on a crew, the pairs' hits on its robots in
    /// candidate order; the obstacle corrections, the box clamp and (unless
    /// stopping at the first violation) the corrections mapped to
    /// coefficients; the sums in [`BlockSums`].
    pub(super) fn per_block<const D: usize>(&mut self, crew: &Crew<'_>, n: usize, grid: &SampleGrid, limits: &Limits) {
        let count = grid.count();
        let n_xi = grid.pt.len() / count;
        let blocks = n.div_ceil(ROBOT_BLOCK);
        let largest =
            self.blocks[..blocks].iter().fold([0.0f64; 3], |m, b| std::array::from_fn(|a| m[a].max(b.largest[a])));
        self.obstacle_bounds.clear();
        self.obstacle_bounds.extend(limits.obstacle_sep.iter().enumerate().map(|(m, sep)| {
            let inv = sep.map(|s| 1.0 / (s * s));
            let track = &limits.tracks[m * D * count..(m + 1) * D * count];
            limits.chord.then(|| largest_target(&largest, &largest_steps(track, D, 1, count), &inv))
        }));
        let Projection { pos, corr, mapped, touched, parts, routed, blocks: sums, obstacle_bounds, first, .. } = self;
        let (first, pos, bounds, routed) = (*first, &*pos, &*obstacle_bounds, &*routed);
        let (corr, mapped, touched) = (Disjoint::new(corr), Disjoint::new(mapped), Disjoint::new(touched));
        let (parts, sums) = (Disjoint::new(parts), Disjoint::new(sums));
        crew.run(&|part| {
            // SAFETY: each part takes its own memory, each block's rows and
            // robots belong to one part.
            let mine = share(part, crew.size(), blocks);
            if crew.size() > 1 && !first {
                add_hits::<D>(routed, part, crew.size(), n, count, mine.clone(), &corr, &touched, &sums);
            }
            let scratch = unsafe { &mut parts.at(part).scratch };
            for b in mine {
                let robots = block_robots(b, n);
                let touched = unsafe { touched.range(robots.clone()) };
                let mut rows: [&mut [f64]; D] =
                    std::array::from_fn(|a| unsafe { corr.range(block_rows(a, n, &robots, count)) });
                let sums = unsafe { sums.at(b) };
                let (mut obstacle_sq, mut box_sq, mut floor_sq) = (0.0, 0.0, 0.0);
                for (r, i) in robots.clone().enumerate() {
                    let pi = robot_rows::<D>(pos, n, count, i);
                    for (m, sep) in limits.obstacle_sep.iter().enumerate() {
                        // The instants the obstacle is kept clear at (a moving
                        // one's prediction may end before the grid does).
                        let until = limits.until[m];
                        let inv = sep.map(|s| 1.0 / (s * s));
                        let track = robot_rows::<D>(&limits.tracks[m * D * count..(m + 1) * D * count], 1, count, 0);
                        if until == 0
                            || limits.obstacle_has_floor(i, m)
                            || !scratch.violated::<D>(&pi, &track, &inv, bounds[m], 0..until)
                        {
                            continue;
                        }
                        if first {
                            sums.violated = true;
                            return;
                        }
                        touched[r] = true;
                        for k in 0..until {
                            let Some(c) = push::<D>(&pi, &track, k, &inv, sep, scratch.target[k], (i, m)) else {
                                continue;
                            };
                            for a in 0..D {
                                rows[a][r * count + k] += c[a];
                                obstacle_sq += c[a] * c[a];
                            }
                        }
                    }
                    for f in limits.floors.iter().filter(|f| f.robot == i || f.against == Against::Robot(i)) {
                        let (q, sep, instants, other) = match f.against {
                            Against::Robot(j) => (robot_rows::<D>(pos, n, count, j), &limits.robot_sep, count, j),
                            Against::Obstacle(m) => {
                                let track = &limits.tracks[m * D * count..(m + 1) * D * count];
                                (robot_rows::<D>(track, 1, count, 0), &limits.obstacle_sep[m], limits.until[m], m)
                            }
                            Against::Box { .. } | Against::Braking { .. } | Against::Closing(_) => continue,
                        };
                        let p = robot_rows::<D>(pos, n, count, f.robot);
                        let (p, q): ([&[f64]; D], [&[f64]; D]) =
                            (std::array::from_fn(|a| &p[a][..instants]), std::array::from_fn(|a| &q[a][..instants]));
                        let inv = sep.map(|s| 1.0 / (s * s));
                        // The same correction in either robot's block: `+c` to
                        // the first, `-c` to the other robot of a pair.
                        let sign = if f.robot == i { 1.0 } else { -1.0 };
                        let floor = (limits.floors_until, f.floor);
                        let hit = scratch.push_with_floor::<D>(
                            &p,
                            &q,
                            &inv,
                            sep,
                            limits.chord,
                            floor,
                            (f.robot, other),
                            |k, c| {
                                if !first {
                                    for a in 0..D {
                                        rows[a][r * count + k] += sign * c[a];
                                        // A pair's `||c||^2` once, an obstacle's with the obstacles.
                                        let sq = if sign > 0.0 { c[a] * c[a] } else { 0.0 };
                                        match f.against {
                                            Against::Robot(_) => floor_sq += sq,
                                            _ => obstacle_sq += sq,
                                        }
                                    }
                                }
                            },
                        );
                        if hit && first {
                            sums.violated = true;
                            return;
                        }
                        touched[r] |= hit;
                    }
                }
                for (a, axis) in rows.iter_mut().enumerate() {
                    let positions = &pos[block_rows(a, n, &robots, count)];
                    for (r, ((row, p), t)) in axis
                        .chunks_exact_mut(count)
                        .zip(positions.chunks_exact(count))
                        .zip(touched.iter_mut())
                        .enumerate()
                    {
                        let (lo, hi) = (limits.lo[a], limits.hi[a]);
                        let (sq, any) = match limits.box_floor(robots.start + r, a) {
                            None => clamp_row(row, p, lo, hi),
                            Some((l, h)) => {
                                let (head, tail) = row.split_at_mut(limits.floors_until.min(count));
                                let (first, rest) = p.split_at(head.len());
                                let (s0, a0) = clamp_row(head, first, l, h);
                                let (s1, a1) = clamp_row(tail, rest, lo, hi);
                                (s0 + s1, a0 || a1)
                            }
                        };
                        box_sq += sq;
                        *t |= any;
                    }
                    if !first {
                        // SAFETY: as above.
                        let out = unsafe { mapped.range(block_rows(a, n, &robots, n_xi)) };
                        grid.to_coefficients(axis, robots.len(), out);
                    }
                }
                (sums.obstacle_sq, sums.box_sq) = (obstacle_sq, box_sq);
                sums.pair_sq += floor_sq;
            }
        });
    }
}

/// Clamps positions `p` into `[lo, hi]`, adding the moves to `row`: the
/// moves' squared sum and whether any moved.
#[inline(always)]
fn clamp_row(row: &mut [f64], p: &[f64], lo: f64, hi: f64) -> (f64, bool) {
    let (mut sq, mut any) = (0.0, false);
    for (c, p) in row.iter_mut().zip(p) {
        let d = p.clamp(lo, hi) - p;
        *c += d;
        sq += d * d;
        any |= d != 0.0;
    }
    (sq, any)
}

/// Adds the hits `routed` to part `part` of `parts` on the robots of its
/// robot blocks `blocks` to their corrections, chunk by chunk in candidate order: `+c` to `i`,
/// `-c` to `j`, each pair's `||c||^2` to the sums of `i`'s block (as
/// [`super::check::Check::push`] adds them). The caller owns those blocks'
/// rows, marks and sums.
#[allow(clippy::too_many_arguments, reason = "the step's shared buffers")]
fn add_hits<const D: usize>(
    routed: &Routed,
    part: usize,
    parts: usize,
    n: usize,
    count: usize,
    blocks: std::ops::Range<usize>,
    corr: &Disjoint<'_, f64>,
    touched: &Disjoint<'_, bool>,
    sums: &Disjoint<'_, BlockSums>,
) {
    if blocks.is_empty() {
        return;
    }
    let robots = blocks.start * ROBOT_BLOCK..block_robots(blocks.end - 1, n).end;
    let first_block = blocks.start;
    // SAFETY: the caller owns these blocks' rows, marks and sums.
    let rows: [&mut [f64]; D] = std::array::from_fn(|a| unsafe { corr.range(block_rows(a, n, &robots, count)) });
    // SAFETY: as above.
    let touched = unsafe { touched.range(robots.clone()) };
    // SAFETY: as above.
    let sums = unsafe { sums.range(blocks) };
    let mut pending: Option<(usize, f64)> = None;
    let mut flush = |pending: &mut Option<(usize, f64)>| {
        if let Some((i, sum)) = pending.take() {
            sums[i / ROBOT_BLOCK - first_block].pair_sq += sum;
        }
    };
    let mut last = (u32::MAX, u32::MAX);
    for (chunk, &checker) in routed.checker.iter().enumerate() {
        let [start, end] = routed.ranges[chunk * parts + part];
        for hit in &routed.lists[checker as usize][part][start as usize..end as usize] {
            if (hit.i, hit.j) != last {
                flush(&mut pending);
                last = (hit.i, hit.j);
            }
            let (i, j, k) = (hit.i as usize, hit.j as usize, hit.k as usize);
            if robots.contains(&i) {
                let r = i - robots.start;
                touched[r] = true;
                let sum = &mut pending.get_or_insert((i, 0.0)).1;
                for a in 0..D {
                    rows[a][r * count + k] += hit.c[a];
                    *sum += hit.c[a] * hit.c[a];
                }
            }
            if robots.contains(&j) {
                let r = j - robots.start;
                touched[r] = true;
                for a in 0..D {
                    rows[a][r * count + k] -= hit.c[a];
                }
            }
        }
    }
    flush(&mut pending);
}
