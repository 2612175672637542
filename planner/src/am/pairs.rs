//! Which robot pairs can come closer than their separation, so that the
//! projection only checks those: sweep-and-prune over each robot's
//! bounding box in each of a few time segments of the grid.
//!
//! Two robots whose scaled distance is below `R` at some instant are within
//! `R` separations of each other along every axis at that instant, so their
//! boxes for the segment holding it, grown by `R` separations, overlap: no
//! violating pair is ever left out, and the pairs are returned in the order
//! the all-pairs loop visits them, so the iteration is the same number for
//! number (`tests::the_broad_phase_iteration_equals_the_all_pairs_one`).
//! The boxes are rebuilt from the iterate's positions at every call, so
//! the pair set follows the iterate.

/// Teams at least this large use the broad phase; below it all pairs are
/// checked (sorting costs more than it saves).
pub(crate) const BROAD_PHASE_MIN_ROBOTS: usize = 24;

/// Instants per time segment.
const SEGMENT: usize = 7;

/// The broad phase's working memory.
#[derive(Debug, Clone, Default)]
pub(crate) struct BroadPhase {
    /// Per segment and robot: `[min, max]` per axis.
    boxes: Vec<[[f64; 2]; 3]>,
    /// Robot order of one segment's sweep.
    order: Vec<usize>,
    /// Candidate pairs `(i, j)`, `i < j`, sorted.
    pairs: Vec<(u32, u32)>,
}

impl BroadPhase {
    /// The pairs of `n` robots whose positions `pos` (`[axis][robot][count]`,
    /// `axes` axes) may come within `reach` (per axis, m) of each other at
    /// some instant, sorted.
    pub fn candidates(&mut self, pos: &[f64], axes: usize, n: usize, count: usize, reach: [f64; 3]) -> &[(u32, u32)] {
        let segments = count.div_ceil(SEGMENT).max(1);
        self.boxes.clear();
        self.boxes.resize(segments * n, [[f64::INFINITY, f64::NEG_INFINITY]; 3]);
        for a in 0..axes {
            for i in 0..n {
                let series = &pos[(a * n + i) * count..(a * n + i + 1) * count];
                for (s, chunk) in series.chunks(SEGMENT).enumerate() {
                    let b = &mut self.boxes[s * n + i][a];
                    for &x in chunk {
                        b[0] = b[0].min(x);
                        b[1] = b[1].max(x);
                    }
                }
            }
        }
        self.pairs.clear();
        for s in 0..segments {
            let boxes = &self.boxes[s * n..(s + 1) * n];
            self.order.clear();
            self.order.extend(0..n);
            self.order.sort_unstable_by(|&i, &j| boxes[i][0][0].total_cmp(&boxes[j][0][0]));
            for (k, &i) in self.order.iter().enumerate() {
                let bi = &boxes[i];
                for &j in &self.order[k + 1..] {
                    let bj = &boxes[j];
                    if bj[0][0] > bi[0][1] + reach[0] {
                        break;
                    }
                    let overlap = (1..axes).all(|a| bj[a][0] <= bi[a][1] + reach[a] && bi[a][0] <= bj[a][1] + reach[a]);
                    if overlap {
                        self.pairs.push((i.min(j) as u32, i.max(j) as u32));
                    }
                }
            }
        }
        self.pairs.sort_unstable();
        self.pairs.dedup();
        &self.pairs
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
        assert!(broad.candidates(&pos, 2, n, count, [0.3; 3]).is_empty());
        // Robot 2 passes robot 1 at the last instant only.
        pos[2 * count + count - 1] = 1.1;
        assert_eq!(broad.candidates(&pos, 2, n, count, [0.3; 3]), &[(1, 2)]);
        assert_eq!(broad.candidates(&pos, 2, n, count, [1.0; 3]), &[(0, 1), (1, 2)]);
    }
}
