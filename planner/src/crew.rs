//! A crew: threads that live for one run and share each of its parallel
//! steps ([`Crew::run`]: every member runs the same job with its own part
//! number, and the call returns when all are done; [`Crew::each`]: each
//! member takes the same contiguous share of a step's items every time).
//!
//! Results must not depend on the crew's size, so the work is cut into
//! blocks whose bounds depend on the problem alone, members
//! take contiguous runs of blocks ([`share`]), and whatever is summed across
//! blocks is summed afterwards, block by block, in order. faer's products
//! round differently for different row counts, which is why a member
//! multiplies block by block rather than its whole share at once.
//!
//! A member between jobs spins for [`SPIN`], then naps [`NAP`] at a time:
//! a run's steps follow each other within microseconds, and waking a
//! sleeping thread costs tens of them.

use std::cell::UnsafeCell;
use std::marker::PhantomData;
use std::ops::Range;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use crossbeam::utils::CachePadded;

/// How long an idle member spins before it naps.
const SPIN: Duration = Duration::from_millis(2);

/// Spin hints between two looks of a spinning thread: few, so that a
/// waiting thread sees a new step or the last part's end within a fraction
/// of a microsecond (an empty step on two threads of this 2-core machine:
/// 0.8 us with 4, 1.3-1.4 us with 32, whose waits the optimiser's short
/// steps felt).
const SPIN_HINTS: usize = 4;

/// How long an idle member naps between two looks for a job.
const NAP: Duration = Duration::from_micros(50);

/// A job as the members see it, its lifetime erased ([`Crew::run`] waits
/// for every member before the job it points to goes away).
type Job = *const (dyn Fn(usize) + Sync + 'static);

/// What the members of a crew share.
struct Board {
    /// Bumped for every job.
    generation: CachePadded<AtomicUsize>,
    /// Members still running the current job.
    pending: CachePadded<AtomicUsize>,
    /// The current job: written only while no member runs one, before the
    /// generation is bumped (release); read after it is seen (acquire).
    job: UnsafeCell<Option<Job>>,
    /// The crew is done: members return.
    stop: AtomicBool,
    /// A member's job panicked.
    panicked: AtomicBool,
}

// SAFETY: `job` is written by the leader only while no member reads it
// (between jobs, `pending` zero) and published through `generation`.
unsafe impl Sync for Board {}

/// A run's threads: the calling one (part 0) and `size - 1` members.
pub struct Crew<'b> {
    board: Option<&'b Board>,
    size: usize,
}

impl Crew<'static> {
    /// The calling thread alone.
    pub fn alone() -> Self {
        Crew { board: None, size: 1 }
    }
}

impl Crew<'_> {
    /// Runs `body` with a crew of `threads` threads (the calling one among
    /// them) that lives until it returns. Members that cannot be started
    /// leave a smaller crew, which computes the same results.
    pub fn with<R>(threads: usize, body: impl FnOnce(&Crew<'_>) -> R) -> R {
        if threads <= 1 {
            return body(&Crew::alone());
        }
        let board = Board {
            generation: CachePadded::new(AtomicUsize::new(0)),
            pending: CachePadded::new(AtomicUsize::new(0)),
            job: UnsafeCell::new(None),
            stop: AtomicBool::new(false),
            panicked: AtomicBool::new(false),
        };
        std::thread::scope(|scope| {
            let board = &board;
            let mut size = 1;
            for part in 1..threads {
                let started = std::thread::Builder::new()
                    .name(format!("flowopt-crew-{part}"))
                    .spawn_scoped(scope, move || serve(board, part));
                if started.is_err() {
                    break;
                }
                size += 1;
            }
            /// Sends the members home when the body returns or unwinds.
            struct Dismiss<'a>(&'a Board);
            impl Drop for Dismiss<'_> {
                fn drop(&mut self) {
                    self.0.stop.store(true, Ordering::Release);
                }
            }
            let _dismiss = Dismiss(board);
            body(&Crew { board: Some(board), size })
        })
    }

    /// Threads in the crew.
    pub fn size(&self) -> usize {
        self.size
    }

    /// Runs `job(part)` for every part `0..size` (this thread takes part 0)
    /// and returns once all are done. A member's panic is raised here.
    pub fn run(&self, job: &(dyn Fn(usize) + Sync)) {
        let Some(board) = self.board else {
            job(0);
            return;
        };
        let erased: *const (dyn Fn(usize) + Sync + '_) = job;
        // SAFETY: only the lifetime changes; `Wait` below keeps this call
        // (and so `job`) alive until no member can read the pointer.
        let erased: Job = unsafe { std::mem::transmute(erased) };
        // SAFETY: no member runs a job (the previous call waited for all).
        unsafe { *board.job.get() = Some(erased) };
        board.pending.store(self.size - 1, Ordering::Relaxed);
        board.generation.fetch_add(1, Ordering::Release);
        /// Waits for the members, also while this thread's part unwinds.
        struct Wait<'a>(&'a Board);
        impl Drop for Wait<'_> {
            fn drop(&mut self) {
                let started = Instant::now();
                while self.0.pending.load(Ordering::Acquire) > 0 {
                    pause(started);
                }
            }
        }
        let wait = Wait(board);
        job(0);
        drop(wait);
        if board.panicked.load(Ordering::Acquire) {
            panic!("a crew member's part of a parallel step panicked");
        }
    }
}

impl Crew<'_> {
    /// Runs `job(part, item)` for every item of `0..items` on the crew,
    /// part `p` taking the same contiguous share of them at every call
    /// ([`share`]), and returns once all are done. A robot block's rows
    /// then stay in the cache of the core that wrote them the step before
    /// (on a 16-core host, 16 threads against one, crowds of 256 / 128
    /// robots: 4.33x / 2.15x, against 4.07x / 1.77x with parts taking the
    /// next item left, in the same run:
    /// docs/experiments/2026-11-27-crew-locality.md). Which part takes an
    /// item must not change what it computes.
    pub fn each(&self, items: usize, job: &(dyn Fn(usize, usize) + Sync)) {
        if self.size == 1 {
            (0..items).for_each(|item| job(0, item));
            return;
        }
        self.run(&|part| share(part, self.size, items).for_each(|item| job(part, item)));
    }
}

/// A member's loop: each new job's part `part`, until the crew is dismissed.
fn serve(board: &Board, part: usize) {
    let mut seen = 0;
    loop {
        let started = Instant::now();
        loop {
            let generation = board.generation.load(Ordering::Acquire);
            if generation != seen {
                seen = generation;
                break;
            }
            if board.stop.load(Ordering::Acquire) {
                return;
            }
            pause(started);
        }
        // SAFETY: the job was written before the generation this thread
        // acquired, and stays alive until `pending` reaches zero.
        let job = unsafe { *board.job.get() };
        if let Some(job) = job {
            // SAFETY: as above.
            let job = unsafe { &*job };
            if catch_unwind(AssertUnwindSafe(|| job(part))).is_err() {
                board.panicked.store(true, Ordering::Release);
            }
        }
        board.pending.fetch_sub(1, Ordering::AcqRel);
    }
}

/// One wait of a spinning thread: a spin hint for the first [`SPIN`] since
/// `started`, naps after.
fn pause(started: Instant) {
    if started.elapsed() < SPIN {
        for _ in 0..SPIN_HINTS {
            std::hint::spin_loop();
        }
    } else {
        std::thread::park_timeout(NAP);
    }
}

/// Part `part`'s contiguous share of `0..len` split in `parts` parts.
pub fn share(part: usize, parts: usize, len: usize) -> Range<usize> {
    len * part / parts..len * (part + 1) / parts
}

/// The part whose [`share`] of `0..len` (split in `parts` parts) holds
/// `item`: the last part whose share starts at or before it.
pub fn owner(item: usize, parts: usize, len: usize) -> usize {
    ((item + 1) * parts - 1) / len
}

/// A slice the parts of a step write in disjoint ranges.
pub struct Disjoint<'a, T> {
    ptr: *mut T,
    len: usize,
    _slice: PhantomData<&'a mut [T]>,
}

// SAFETY: parts only take disjoint ranges (the contract of `range`).
unsafe impl<T: Send> Sync for Disjoint<'_, T> {}

impl<'a, T> Disjoint<'a, T> {
    /// `slice`, shared between the parts of a step.
    pub fn new(slice: &'a mut [T]) -> Self {
        Self { ptr: slice.as_mut_ptr(), len: slice.len(), _slice: PhantomData }
    }

    /// The items `range`.
    ///
    /// # Safety
    /// No other slice of the same items may be alive (parts of a step take
    /// disjoint ranges).
    #[allow(clippy::mut_from_ref, reason = "disjoint ranges are the caller's contract")]
    pub unsafe fn range(&self, range: Range<usize>) -> &mut [T] {
        assert!(range.start <= range.end && range.end <= self.len, "range {range:?} of {}", self.len);
        // SAFETY: in bounds (checked); unaliased by the caller's contract.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(range.start), range.len()) }
    }

    /// Item `i`.
    ///
    /// # Safety
    /// As [`Self::range`].
    #[allow(clippy::mut_from_ref, reason = "disjoint ranges are the caller's contract")]
    pub unsafe fn at(&self, i: usize) -> &mut T {
        // SAFETY: forwarded.
        unsafe { &mut self.range(i..i + 1)[0] }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_part_runs_once_per_step_and_the_step_waits_for_all() {
        for threads in [1, 2, 3, 5] {
            let counts: Vec<AtomicUsize> = (0..threads).map(|_| AtomicUsize::new(0)).collect();
            Crew::with(threads, |crew| {
                assert_eq!(crew.size(), threads);
                for step in 1..=50 {
                    crew.run(&|part| {
                        counts[part].fetch_add(1, Ordering::Relaxed);
                    });
                    assert!(counts.iter().all(|c| c.load(Ordering::Relaxed) == step));
                }
            });
        }
    }

    #[test]
    fn disjoint_writes_land_and_shares_cover_the_range() {
        let mut values = vec![0usize; 103];
        Crew::with(3, |crew| {
            let out = Disjoint::new(&mut values);
            crew.run(&|part| {
                for i in share(part, crew.size(), 103) {
                    // SAFETY: the shares are disjoint.
                    unsafe { *out.at(i) = i + 1 };
                }
            });
        });
        assert!(values.iter().enumerate().all(|(i, v)| *v == i + 1));
    }

    #[test]
    fn the_owner_of_an_item_is_the_part_whose_share_holds_it() {
        for len in 1..40 {
            for parts in 1..=len {
                for item in 0..len {
                    assert!(share(owner(item, parts, len), parts, len).contains(&item), "{item} of {len} in {parts}");
                }
            }
        }
    }

    #[test]
    fn each_runs_every_item_once_and_gives_a_part_the_same_share_every_step() {
        for threads in [1, 2, 3] {
            let owner: Vec<AtomicUsize> = (0..10).map(|_| AtomicUsize::new(usize::MAX)).collect();
            Crew::with(threads, |crew| {
                for _ in 0..20 {
                    let runs = AtomicUsize::new(0);
                    crew.each(10, &|part, item| {
                        runs.fetch_add(1, Ordering::Relaxed);
                        let before = owner[item].swap(part, Ordering::Relaxed);
                        assert!(before == usize::MAX || before == part, "item {item} moved from {before} to {part}");
                        assert!(share(part, crew.size(), 10).contains(&item));
                    });
                    assert_eq!(runs.load(Ordering::Relaxed), 10);
                }
            });
        }
    }

    #[test]
    fn a_members_panic_reaches_the_caller_after_every_part_is_done() {
        let finished = AtomicUsize::new(0);
        let caught = std::panic::catch_unwind(AssertUnwindSafe(|| {
            Crew::with(2, |crew| {
                crew.run(&|part| {
                    if part == 1 {
                        panic!("member fails");
                    }
                    std::thread::sleep(Duration::from_millis(5));
                    finished.fetch_add(1, Ordering::Relaxed);
                });
            })
        }));
        assert!(caught.is_err());
        assert_eq!(finished.load(Ordering::Relaxed), 1);
    }
}
