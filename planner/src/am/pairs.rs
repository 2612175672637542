//! Which robot pairs can come closer than their separation, so that the
//! projection only checks those, and only at the instants they can: sweep-
//! and-prune over each robot's bounding box in each of a few time segments
//! of the grid.
//!
//! Two robots whose scaled distance is below `R` at some instant are within
//! `R` separations of each other along every axis at that instant, so their
//! boxes for the segment holding it, each grown by its robot's share of `R`
//! separations, overlap: no
//! violating pair is ever left out, and the pairs are returned in the order
//! the all-pairs loop visits them. Each pair comes with the instants from
//! its first to its last overlapping segment: it cannot violate outside
//! them, so checking only those is the same iteration number for number
//! (`tests::the_broad_phase_iteration_equals_the_all_pairs_one`).
//! The pair set follows the iterate: boxes are built grown by half again
//! ([`SLACK`]) and kept while every robot's current box (its motion since
//! the build added) still fits inside its built one, so a kept set is a
//! superset of the current one; else they are rebuilt. The optimiser's
//! iterates move little from one iteration to the next, so most
//! iterations skip the sweep.

use crate::crew::{Crew, Disjoint, share};

/// Teams at least this large use the broad phase; below it all pairs are
/// checked (sorting costs more than it saves).
pub(crate) const BROAD_PHASE_MIN_ROBOTS: usize = 24;

/// Instants per time segment.
const SEGMENT: usize = 7;

/// Boxes are built grown by this fraction more than asked, so that the
/// pair set can be kept while the iterate moves.
const SLACK: f64 = 0.5;

/// Teams at least this large keep their pair set within the slack; smaller
/// ones sweep exact boxes every iteration. Runs of a few iterations (the
/// daemon's warm plans of 64 robots) screen the slack's extra pairs more
/// often than they skip a sweep, and the 64-robot demo with kept sets
/// tracked worse (docs/BENCHMARKS.md, "Big teams").
pub(crate) const KEEP_MIN_ROBOTS: usize = 128;

/// A pair `i < j` that may come closer than its reach, and the instants
/// `from..to` it may at (outside them its boxes never overlap).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Candidate {
    pub i: u32,
    pub j: u32,
    pub from: u32,
    pub to: u32,
}

impl Candidate {
    /// The pair `(i, j)` at every one of `count` instants.
    pub fn whole(i: u32, j: u32, count: usize) -> Self {
        Self { i, j, from: 0, to: instant(count) }
    }
}

/// An instant (or segment) index as stored in a [`Candidate`]; a grid of
/// more instants than that holds cannot be checked (a truncated index
/// would miss contacts), so it panics rather than wrap.
fn instant(k: usize) -> u32 {
    u32::try_from(k).expect("a grid of at most u32::MAX instants")
}

/// The broad phase's working memory.
#[derive(Debug, Clone, Default)]
pub(crate) struct BroadPhase {
    /// Each crew part's sweep.
    parts: Vec<SweepPart>,
    /// Which pairs `(i, j)`, `i < j`, are candidates: bit `i * n + j`.
    found: Vec<u64>,
    /// Per pair bit of `found`, once set: its first and last overlapping
    /// segment (stale values where the bit is clear).
    segments: Vec<[u32; 2]>,
    /// Candidate pairs, sorted.
    pairs: Vec<Candidate>,
    /// The positions the pairs were found from (empty before the first).
    built: Vec<f64>,
    /// Each robot's growth per axis they were found with.
    built_grow: Vec<[f64; 3]>,
}

impl BroadPhase {
    /// The pairs of `n` robots whose positions `pos` (`[axis][robot][count]`,
    /// `axes` axes) may come closer than `grow[i] + grow[j]` along every
    /// axis at some instant, sorted, with the instants they may at. `grow`
    /// (`[robot][axis]`, m) is each robot's share of the pair's reach.
    #[cfg(test)]
    pub fn candidates(&mut self, pos: &[f64], axes: usize, n: usize, count: usize, grow: &[[f64; 3]]) -> &[Candidate] {
        let covered = n >= KEEP_MIN_ROBOTS && self.still_covers(pos, axes, n, count, grow);
        self.candidates_covered(&Crew::alone(), covered, pos, axes, n, count, grow)
    }

    /// [`Self::candidates`] where whether the pairs found last still cover
    /// every robot ([`Self::still_covers`] of all of them, teams of
    /// [`KEEP_MIN_ROBOTS`] or more) is known: `covered`.
    #[allow(clippy::too_many_arguments, reason = "the positions' shape")]
    pub fn candidates_covered(
        &mut self,
        crew: &Crew<'_>,
        covered: bool,
        pos: &[f64],
        axes: usize,
        n: usize,
        count: usize,
        grow: &[[f64; 3]],
    ) -> &[Candidate] {
        if n < KEEP_MIN_ROBOTS {
            self.sweep(crew, pos, grow, axes, n, count);
        } else if !covered {
            let mut built = std::mem::take(&mut self.built);
            let mut built_grow = std::mem::take(&mut self.built_grow);
            built.clear();
            built.extend_from_slice(&pos[..axes * n * count]);
            built_grow.clear();
            built_grow.extend(grow.iter().map(|g| g.map(|x| x * (1.0 + SLACK))));
            self.sweep(crew, &built, &built_grow, axes, n, count);
            (self.built, self.built_grow) = (built, built_grow);
        }
        &self.pairs
    }

    /// The pairs the last [`Self::candidates`] returned.
    pub fn current(&self) -> &[Candidate] {
        &self.pairs
    }

    /// Whether the pairs found last still hold every pair whose boxes
    /// overlap now: each robot moved, along each axis, by at most what its
    /// built growth has to spare over its growth now.
    #[cfg(test)]
    fn still_covers(&self, pos: &[f64], axes: usize, n: usize, count: usize, grow: &[[f64; 3]]) -> bool {
        (0..n).all(|i| {
            let rows: [&[f64]; 3] =
                std::array::from_fn(
                    |a| if a < axes { &pos[(a * n + i) * count..(a * n + i + 1) * count] } else { &[] },
                );
            self.still_covers_robot(axes, n, count, i, &rows, &grow[i])
        })
    }

    /// [`Self::still_covers`] for robot `i` of `n`, its positions `rows`
    /// (one per axis) and its growth `grow` now.
    pub fn still_covers_robot(
        &self,
        axes: usize,
        n: usize,
        count: usize,
        i: usize,
        rows: &[&[f64]; 3],
        grow: &[f64; 3],
    ) -> bool {
        if self.built.len() != axes * n * count || self.built_grow.len() != n {
            return false;
        }
        (0..axes).all(|a| {
            let built = &self.built[(a * n + i) * count..(a * n + i + 1) * count];
            let moved = rows[a].iter().zip(built).fold(0.0, |m: f64, (p, q)| m.max((p - q).abs()));
            moved + grow[a] <= self.built_grow[i][a]
        })
    }

    /// Finds the pairs whose boxes around `pos`, grown by `grow`, overlap in
    /// some segment, and the instants of their first to last such segment:
    /// the crew's parts sweep shares of the segments, each into its own
    /// marks, merged after (bitwise or, first and last segment: the same
    /// pairs for every crew size).
    fn sweep(&mut self, crew: &Crew<'_>, pos: &[f64], grow: &[[f64; 3]], axes: usize, n: usize, count: usize) {
        let segments = count.div_ceil(SEGMENT).max(1);
        if self.parts.len() < crew.size() {
            self.parts.resize_with(crew.size(), SweepPart::default);
        }
        let parts = Disjoint::new(&mut self.parts[..crew.size()]);
        crew.run(&|part| {
            // SAFETY: each part takes its own memory.
            let mine = unsafe { parts.at(part) };
            mine.found.clear();
            mine.found.resize((n * n).div_ceil(64), 0);
            mine.segments.resize(n * n, [0; 2]);
            for s in share(part, crew.size(), segments) {
                mine.sweep_segment(pos, grow, axes, n, count, s);
            }
        });
        let (found, marks) = (&mut self.found, &mut self.segments);
        found.clear();
        found.resize((n * n).div_ceil(64), 0);
        marks.resize(n * n, [0; 2]);
        for part in &self.parts[..crew.size()] {
            for (w, (&theirs, ours)) in part.found.iter().zip(found.iter_mut()).enumerate() {
                let mut bits = theirs;
                while bits != 0 {
                    let bit = w * 64 + bits.trailing_zeros() as usize;
                    let [first, last] = part.segments[bit];
                    marks[bit] = if *ours & (1 << (bit % 64)) == 0 {
                        [first, last]
                    } else {
                        [marks[bit][0].min(first), marks[bit][1].max(last)]
                    };
                    bits &= bits - 1;
                }
                *ours |= theirs;
            }
        }
        self.pairs.clear();
        for (w, &word) in self.found.iter().enumerate() {
            let mut bits = word;
            while bits != 0 {
                let bit = w * 64 + bits.trailing_zeros() as usize;
                let [first, last] = self.segments[bit].map(|s| s as usize);
                self.pairs.push(Candidate {
                    i: (bit / n) as u32,
                    j: (bit % n) as u32,
                    from: instant(first * SEGMENT),
                    to: instant(((last + 1) * SEGMENT).min(count)),
                });
                bits &= bits - 1;
            }
        }
    }
}

/// One crew part's sweep: its boxes and order for a segment, and the pairs
/// it found in its segments.
#[derive(Debug, Clone, Default)]
struct SweepPart {
    /// Per robot: `[min, max]` per axis, grown by the robot's share of the
    /// reach (one segment).
    boxes: Vec<[[f64; 2]; 3]>,
    /// Robot order of the segment's sweep.
    order: Vec<usize>,
    /// Which pairs `(i, j)`, `i < j`, overlap in its segments: bit `i * n + j`.
    found: Vec<u64>,
    /// Per pair bit of `found`, once set: its first and last overlapping
    /// segment among this part's (stale values where the bit is clear).
    segments: Vec<[u32; 2]>,
}

impl SweepPart {
    /// Marks the pairs whose boxes overlap in segment `s`.
    fn sweep_segment(&mut self, pos: &[f64], grow: &[[f64; 3]], axes: usize, n: usize, count: usize, s: usize) {
        let instants = s * SEGMENT..((s + 1) * SEGMENT).min(count);
        self.boxes.clear();
        self.boxes.extend((0..n).map(|i| {
            std::array::from_fn(|a| {
                if a >= axes {
                    return [f64::INFINITY, f64::NEG_INFINITY];
                }
                let series = &pos[(a * n + i) * count..(a * n + i + 1) * count];
                let (lo, hi) = series[instants.clone()]
                    .iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| (lo.min(x), hi.max(x)));
                [lo - grow[i][a], hi + grow[i][a]]
            })
        }));
        let boxes = &self.boxes;
        self.order.clear();
        self.order.extend(0..n);
        self.order.sort_unstable_by(|&i, &j| boxes[i][0][0].total_cmp(&boxes[j][0][0]));
        for (k, &i) in self.order.iter().enumerate() {
            let bi = &boxes[i];
            for &j in &self.order[k + 1..] {
                let bj = &boxes[j];
                if bj[0][0] > bi[0][1] {
                    break;
                }
                if (1..axes).all(|a| bj[a][0] <= bi[a][1] && bi[a][0] <= bj[a][1]) {
                    let bit = i.min(j) * n + i.max(j);
                    let (word, mask) = (&mut self.found[bit / 64], 1 << (bit % 64));
                    // A part's segments go in order: its first sets both ends.
                    if *word & mask == 0 {
                        self.segments[bit][0] = instant(s);
                    }
                    *word |= mask;
                    self.segments[bit][1] = instant(s);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn robots_far_apart_in_every_segment_are_no_candidates() {
        // Three robots on a line, 1 m apart, still; reach 0.3 m.
        let (n, count) = (3, 10);
        let mut pos = vec![0.0; 2 * n * count];
        for i in 0..n {
            pos[i * count..(i + 1) * count].fill(i as f64);
        }
        let mut broad = BroadPhase::default();
        assert!(broad.candidates(&pos, 2, n, count, &[[0.15; 3]; 3]).is_empty());
        // Robot 2 passes robot 1 at the last instant only.
        pos[2 * count + count - 1] = 1.1;
        // Only in the second segment (instants 7..10).
        let at = |i, j, from, to| Candidate { i, j, from, to };
        assert_eq!(broad.candidates(&pos, 2, n, count, &[[0.15; 3]; 3]), &[at(1, 2, 7, 10)]);
        assert_eq!(broad.candidates(&pos, 2, n, count, &[[0.5; 3]; 3]), &[at(0, 1, 0, 10), at(1, 2, 0, 10)]);
        // A robot's own share reaches further: robot 0 grown by 0.95 meets 1.
        assert_eq!(
            broad.candidates(&pos, 2, n, count, &[[0.95; 3], [0.15; 3], [0.15; 3]]),
            &[at(0, 1, 0, 10), at(1, 2, 7, 10)]
        );
    }

    #[test]
    fn big_teams_keep_the_pairs_while_the_robots_stay_within_the_slack_and_find_them_anew_beyond() {
        // A big team on a line, 1 m apart, still.
        let (n, count) = (KEEP_MIN_ROBOTS, 10);
        let mut pos = vec![0.0; 2 * n * count];
        for i in 0..n {
            pos[i * count..(i + 1) * count].fill(i as f64);
        }
        let grow = vec![[0.2; 3]; n];
        let mut broad = BroadPhase::default();
        assert!(broad.candidates(&pos, 2, n, count, &grow).is_empty());
        // Robot 2 moves 0.05 m towards robot 1 (its built growth spares
        // 0.1): the set found earlier is kept; it holds every pair whose
        // boxes overlap now, none.
        pos[2 * count..3 * count].iter_mut().for_each(|x| *x -= 0.05);
        assert!(broad.candidates(&pos, 2, n, count, &grow).is_empty());
        assert_eq!(broad.built[2 * count], 2.0);
        // 0.65 m: beyond the slack, so found anew (robot 2 at 1.35 meets 1).
        pos[2 * count..3 * count].iter_mut().for_each(|x| *x -= 0.6);
        let pair = |c: &[Candidate]| c.iter().map(|c| (c.i, c.j)).collect::<Vec<_>>();
        assert_eq!(pair(broad.candidates(&pos, 2, n, count, &grow)), [(1, 2)]);
        assert!((broad.built[2 * count] - 1.35).abs() < 1e-12);
        // A robot's growth rising past its spare also finds them anew.
        let mut wider = grow.clone();
        wider[2] = [0.45; 3];
        assert_eq!(pair(broad.candidates(&pos, 2, n, count, &wider)), [(1, 2)]);
        assert_eq!(broad.built_grow[2][0], 0.45 * (1.0 + SLACK));
        // A small team sweeps its exact boxes every time and keeps nothing.
        let mut line = vec![0.0; 2 * 3 * count];
        for i in 0..3 {
            line[i * count..(i + 1) * count].fill(i as f64);
        }
        let mut small = BroadPhase::default();
        assert!(small.candidates(&line, 2, 3, count, &grow[..3]).is_empty());
        assert!(small.built.is_empty());
    }
}
