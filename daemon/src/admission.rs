//! The checks on a snapshot that need the daemon's own state: its clock
//! and the sequences already accepted. A snapshot is admitted when its
//! timestamp lies in `[now - stale_after, now + skew]` of the daemon's
//! `CLOCK_MONOTONIC` and its sequence exceeds the last one accepted from
//! the same publisher (a restarted controller is a new publisher and starts
//! afresh); `u64::MAX` is never admitted. Rejected snapshots change nothing.

use flowopt_client::Reason;

use crate::convert::Rejection;

/// Publishers whose last sequence is remembered (a service admits two;
/// restarts add more over time, the oldest are forgotten).
const REMEMBERED: usize = 8;

/// The clock window and the last sequence accepted per publisher.
#[derive(Debug, Clone)]
pub struct Admission {
    /// How old a snapshot may be (ns).
    stale_after_ns: u64,
    /// How far ahead of the daemon's clock it may be (ns).
    skew_ns: u64,
    /// `(publisher, last accepted sequence)`, most recent first.
    last: Vec<(u128, u64)>,
}

impl Admission {
    /// Snapshots at most `stale_after_ns` old and `skew_ns` ahead.
    pub fn new(stale_after_ns: u64, skew_ns: u64) -> Self {
        Self { stale_after_ns, skew_ns, last: Vec::new() }
    }

    /// Whether a snapshot of `publisher` with `sequence`, measured at
    /// `timestamp_ns`, may be planned at `now_ns`.
    pub fn check(&self, publisher: u128, sequence: u64, timestamp_ns: u64, now_ns: u64) -> Result<(), Rejection> {
        let oldest = now_ns.saturating_sub(self.stale_after_ns);
        let newest = now_ns.saturating_add(self.skew_ns);
        if timestamp_ns < oldest || timestamp_ns > newest {
            return Err(Rejection::new(Reason::Clock));
        }
        let previous = self.last.iter().find(|(p, _)| *p == publisher).map(|(_, s)| *s);
        if sequence == u64::MAX || previous.is_some_and(|last| sequence <= last) {
            return Err(Rejection::new(Reason::Sequence));
        }
        Ok(())
    }

    /// Records that the snapshot `sequence` of `publisher` was accepted.
    pub fn accept(&mut self, publisher: u128, sequence: u64) {
        self.last.retain(|(p, _)| *p != publisher);
        self.last.insert(0, (publisher, sequence));
        self.last.truncate(REMEMBERED);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const NOW: u64 = 10_000_000_000;

    fn reason(r: Result<(), Rejection>) -> Option<Reason> {
        r.err().map(|r| r.reason)
    }

    #[test]
    fn timestamps_outside_the_window_are_rejected() {
        let a = Admission::new(500_000_000, 50_000_000);
        assert_eq!(reason(a.check(1, 1, NOW, NOW)), None);
        assert_eq!(reason(a.check(1, 1, NOW - 400_000_000, NOW)), None);
        assert_eq!(reason(a.check(1, 1, NOW + 40_000_000, NOW)), None);
        for bad in [0, NOW - 10_000_000_000, NOW + 3_600_000_000_000, u64::MAX, NOW - 600_000_000, NOW + 60_000_000] {
            assert_eq!(reason(a.check(1, 1, bad, NOW)), Some(Reason::Clock), "{bad}");
        }
    }

    #[test]
    fn sequences_must_increase_per_publisher() {
        let mut a = Admission::new(500_000_000, 50_000_000);
        a.accept(1, 10);
        for bad in [10, 9, 0] {
            assert_eq!(reason(a.check(1, bad, NOW, NOW)), Some(Reason::Sequence), "{bad}");
        }
        assert_eq!(reason(a.check(1, 11, NOW, NOW)), None);
        assert_eq!(reason(a.check(1, u64::MAX, NOW, NOW)), Some(Reason::Sequence));
        // A restarted controller is a new publisher: it starts afresh.
        assert_eq!(reason(a.check(2, 1, NOW, NOW)), None);
        // Checking changes nothing; accepting does.
        assert_eq!(reason(a.check(1, 11, NOW, NOW)), None);
        a.accept(1, 11);
        assert_eq!(reason(a.check(1, 11, NOW, NOW)), Some(Reason::Sequence));
    }
}
