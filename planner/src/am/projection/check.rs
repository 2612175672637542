//! One pair (or robot and obstacle) at a grid's instants: the screen of
//! whether it comes closer than its target anywhere ([`Scratch::violated`],
//! with the chord inflation) and the push of its offset to the target
//! ([`push`]); the per-robot rows and moves they read.

use std::ops::Range;

use super::super::pairs::Candidate;
use super::limits::Limits;

/// Squared scaled distance below which two centres count as coincident and
/// the push direction is chosen deterministically instead of normalised.
pub(super) const COINCIDENT: f64 = 1e-18;

/// Per-instant values of the pair being checked.
#[derive(Debug, Clone)]
pub(super) struct Scratch {
    /// Squared target: 1, or more with the chord inflation.
    pub(super) target: Vec<f64>,
    /// Squared scaled move of the offset to the next instant (0 at the last).
    pub(super) step: Vec<f64>,
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
    pub(super) fn violated<const D: usize>(
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

/// What one thread's pair checks read: the positions, the robots' largest
/// moves between instants and the limits.
#[derive(Clone, Copy)]
pub(super) struct Check<'a> {
    pub(super) pos: &'a [f64],
    pub(super) steps: &'a [f64],
    pub(super) n: usize,
    pub(super) count: usize,
    pub(super) limits: &'a Limits,
    pub(super) inv: [f64; 3],
}

impl Check<'_> {
    /// Whether the candidate comes closer than its target at any of the
    /// [`Self::instants`] it is checked at.
    #[inline(always)]
    pub(super) fn violates<const D: usize>(&self, pair: Candidate, scratch: &mut Scratch) -> bool {
        let (i, j) = (pair.i as usize, pair.j as usize);
        if self.limits.pair_has_floor(i, j) {
            // Checked against its floor with the robots' obstacles.
            return false;
        }
        let bound = self.limits.chord.then(|| 1.0 + 0.25 * (self.steps[i] + self.steps[j]).powi(2));
        let (pi, pj) =
            (robot_rows::<D>(self.pos, self.n, self.count, i), robot_rows::<D>(self.pos, self.n, self.count, j));
        scratch.violated::<D>(&pi, &pj, &self.inv, bound, self.instants(pair))
    }

    /// The instants a candidate is checked at: its own and one more on
    /// either side, whose moves its end instants' chord targets take. The
    /// extra instants lie outside the candidate's (where its boxes do not
    /// overlap, so they cannot violate even with their targets cut short).
    pub(super) fn instants(&self, pair: Candidate) -> Range<usize> {
        (pair.from as usize).saturating_sub(1)..(pair.to as usize + 1).min(self.count)
    }

    /// Pushes apart every violating pair of `pairs` (`i < j`, in order),
    /// adding to `corr`, marking `touched` and handing each pair's
    /// `||c||^2` to `add(i, sum)`: the same numbers, in the same order, as
    /// [`Self::hits`] of the pairs added one after the other.
    pub(super) fn push<const D: usize>(
        &self,
        pairs: impl Iterator<Item = Candidate>,
        scratch: &mut Scratch,
        corr: &mut [f64],
        touched: &mut [bool],
        mut add: impl FnMut(usize, f64),
    ) {
        let (count, inv, sep) = (self.count, &self.inv, &self.limits.robot_sep);
        let stride = self.n * count;
        for pair in pairs {
            if !self.violates::<D>(pair, scratch) {
                continue;
            }
            let (i, j) = (pair.i as usize, pair.j as usize);
            let (pi, pj) = (robot_rows::<D>(self.pos, self.n, count, i), robot_rows::<D>(self.pos, self.n, count, j));
            let mut sum = 0.0;
            for k in self.instants(pair) {
                let Some(c) = push::<D>(&pi, &pj, k, inv, sep, scratch.target[k], (i, j)) else {
                    continue;
                };
                touched[i] = true;
                touched[j] = true;
                for a in 0..D {
                    corr[a * stride + i * count + k] += c[a];
                    corr[a * stride + j * count + k] -= c[a];
                    sum += c[a] * c[a];
                }
            }
            add(i, sum);
        }
    }

    /// The corrections of every violating pair of `pairs` (in order),
    /// appended instant by instant (`+c` for `i`, `-c` for `j`) to the
    /// list of the part that adds `i`'s corrections and, where another
    /// part adds `j`'s, to that part's too (`adder`: a robot's part). One
    /// call per chunk of candidates: the screen of the pairs that do not
    /// violate (most of them) runs in this loop, not in a call per pair.
    pub(super) fn hits<const D: usize>(
        &self,
        pairs: &[Candidate],
        scratch: &mut Scratch,
        lists: &mut [Vec<Hit>],
        adder: &impl Fn(usize) -> usize,
    ) {
        for &pair in pairs {
            if !self.violates::<D>(pair, scratch) {
                continue;
            }
            let (i, j) = (pair.i as usize, pair.j as usize);
            let (to_i, to_j) = (adder(i), adder(j));
            let (pi, pj) =
                (robot_rows::<D>(self.pos, self.n, self.count, i), robot_rows::<D>(self.pos, self.n, self.count, j));
            for k in self.instants(pair) {
                if let Some(c) = push::<D>(&pi, &pj, k, &self.inv, &self.limits.robot_sep, scratch.target[k], (i, j)) {
                    let mut c3 = [0.0; 3];
                    c3[..D].copy_from_slice(&c);
                    let hit = Hit { i: pair.i, j: pair.j, k: k as u32, c: c3 };
                    lists[to_i].push(hit);
                    if to_j != to_i {
                        lists[to_j].push(hit);
                    }
                }
            }
        }
    }
}

impl Scratch {
    /// Pushes `p` away from `q` (rows over the same instants) wherever
    /// they come closer than their target: 1 (or the chord target) with
    /// `floor` for 1 at the first `until` instants, where a start violation
    /// is recovered from ([`crate::recovery`]). Hands each instant's
    /// correction of `p` to `add(k, c)` and returns whether there was any.
    #[allow(clippy::too_many_arguments, reason = "one pair's rows, sizes and floor")]
    pub(super) fn push_with_floor<const D: usize>(
        &mut self,
        p: &[&[f64]; D],
        q: &[&[f64]; D],
        inv: &[f64; 3],
        sep: &[f64; 3],
        chord: bool,
        (until, floor): (usize, f64),
        ids: (usize, usize),
        mut add: impl FnMut(usize, [f64; D]),
    ) -> bool {
        let count = p[0].len();
        if chord {
            // An unbounded screen leaves every instant's chord target.
            self.violated::<D>(p, q, inv, Some(f64::INFINITY), 0..count);
        } else {
            self.target[..count].fill(1.0);
        }
        // The floor takes the separation's place: `floor^2 + L^2 / 4` with
        // the chord (the straight move between instants kept above it); a
        // floor of 0 asks nothing.
        for t in &mut self.target[..until.min(count)] {
            *t = if floor > 0.0 { *t + floor * floor - 1.0 } else { 0.0 };
        }
        let mut any = false;
        for k in 0..count {
            if let Some(c) = push::<D>(p, q, k, inv, sep, self.target[k], ids) {
                any = true;
                add(k, c);
            }
        }
        if !chord {
            // The other pairs read 1 without a chord.
            self.target[..count].fill(1.0);
        }
        any
    }
}

/// One violating pair's correction at one instant: `+c` for robot `i`,
/// `-c` for robot `j` (the axes past the team's dimension zero).
#[derive(Debug, Clone, Copy)]
pub(super) struct Hit {
    pub(super) i: u32,
    pub(super) j: u32,
    pub(super) k: u32,
    pub(super) c: [f64; 3],
}

/// Robot `i`'s rows of `values` (`[axis][robot][count]`, `n` robots), one
/// per axis.
#[inline(always)]
pub(super) fn robot_rows<const D: usize>(values: &[f64], n: usize, count: usize, i: usize) -> [&[f64]; D] {
    let stride = n * count;
    std::array::from_fn(|a| &values[a * stride + i * count..a * stride + (i + 1) * count])
}

/// Every pair `i < j` of `n` robots, in order, at every one of `count`
/// instants.
pub(super) fn all_pairs(n: usize, count: usize) -> impl Iterator<Item = Candidate> {
    (0..n as u32).flat_map(move |i| (i + 1..n as u32).map(move |j| Candidate::whole(i, j, count)))
}

/// Robot `i`'s largest move between neighbouring instants, scaled by
/// `inv` (the inverse squared separations), of positions `rows` (its row
/// per axis).
pub(super) fn robot_step<const D: usize>(rows: &[&[f64]; D], inv: &[f64; 3]) -> f64 {
    let count = rows[0].len();
    let mut largest: f64 = 0.0;
    for k in 1..count {
        let mut s = 0.0;
        for a in 0..D {
            s += (rows[a][k] - rows[a][k - 1]).powi(2) * inv[a];
        }
        largest = largest.max(s);
    }
    largest.sqrt()
}

/// The largest move between neighbouring instants of each of `rows`
/// (`axes` blocks of `rows` rows of `count` positions), per axis.
pub(super) fn largest_steps(pos: &[f64], axes: usize, rows: usize, count: usize) -> [f64; 3] {
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
pub(super) fn largest_target(p: &[f64; 3], q: &[f64; 3], inv: &[f64; 3]) -> f64 {
    let l2: f64 = (0..3).map(|a| (p[a] + q[a]).powi(2) * inv[a]).sum();
    1.0 + 0.25 * l2
}

/// The correction `e - d` for offset `d = p(k) - q(k)` if its scaled
/// squared length is below `target` (squared). Coincident centres get a
/// deterministic direction derived from `ids` and `k`.
pub(super) fn push<const D: usize>(
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

/// A robot's share of the broad phase's reach per axis: a pair's chord
/// inflation is at most `sqrt(1 + (s_i + s_j)^2 / 4) <= 1 + (s_i + s_j) / 2`
/// separations, `s` the robots' largest scaled moves between instants
/// (`step`), so robot `i`'s share is `(1 + s_i) / 2`.
pub(super) fn reach_share(step: f64, sep: &[f64; 3]) -> [f64; 3] {
    sep.map(|x| x * 0.5 * (1.0 + step))
}
