//! Process settings for fast CPU tensor code, and the pool that spreads
//! work over the cores.

use std::sync::atomic::{AtomicUsize, Ordering};

/// Call once, early in `main`, before any other thread starts.
///
/// - Keeps large temporaries in the heap instead of fresh mappings: candle
///   allocates every op's output, and glibc's default thresholds return
///   buffers above 128 KiB to the kernel, so each op page-faults them back
///   (measured: a training step 27 ms -> 14 ms).
/// - Settles candle's thread count at `tensor_threads` (`None`: candle's
///   default, the physical cores), unless `RAYON_NUM_THREADS` is set.
///   Unsettled, candle parses `/proc/cpuinfo` on every CPU matmul; and the
///   planner's small products lose more to the threads' synchronisation
///   than they gain (measured, docs/LEARNED.md: 16-robot flow sampling
///   41 ms with the count unsettled, 33 ms settled at 2 threads, 23 ms at 1).
///
/// # Safety
/// No other thread may exist yet: the call writes the process environment.
pub unsafe fn configure(tensor_threads: Option<usize>) {
    // SAFETY: mallopt only adjusts allocator thresholds; it is called before
    // any thread of ours allocates concurrently.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 256 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 512 << 20);
    }
    if std::env::var_os("RAYON_NUM_THREADS").is_none() {
        let threads = tensor_threads.unwrap_or_else(candle_core::utils::get_num_threads).max(1);
        // SAFETY: the caller guarantees no other thread exists, so nothing
        // reads the environment concurrently.
        unsafe { std::env::set_var("RAYON_NUM_THREADS", threads.to_string()) };
    }
}

/// Runs `work(i)` for every `i` in `0..count` on `threads` threads, the
/// calling one and `threads - 1` scoped helpers (each free thread takes the
/// next `i` in order), and returns the `Some` results in index order; the
/// first error (or a panicked thread) fails the whole. The caller works
/// rather than waits: a helper on an idle core of these virtual machines
/// starts late (docs/LEARNED.md, "A warm-up to know about").
pub fn parallel<T: Send>(
    count: usize,
    threads: usize,
    work: impl Fn(usize) -> Result<Option<T>, crate::ModelError> + Sync,
) -> Result<Vec<T>, crate::ModelError> {
    let threads = threads.clamp(1, count.max(1));
    let next = AtomicUsize::new(0);
    let (work, next) = (&work, &next);
    let drain = move || -> Result<Vec<(usize, T)>, crate::ModelError> {
        let mut out = Vec::new();
        loop {
            let i = next.fetch_add(1, Ordering::Relaxed);
            if i >= count {
                return Ok(out);
            }
            if let Some(v) = work(i)? {
                out.push((i, v));
            }
        }
    };
    let results: Vec<Result<Vec<(usize, T)>, crate::ModelError>> =
        std::thread::scope(|scope| {
            let helpers: Vec<_> = (1..threads).map(|_| scope.spawn(drain)).collect();
            let mut results = vec![drain()];
            results.extend(helpers.into_iter().map(|h| {
                h.join().unwrap_or_else(|_| Err(crate::ModelError::Config("a worker thread panicked".into())))
            }));
            results
        });
    let mut all = Vec::new();
    for r in results {
        all.extend(r?);
    }
    all.sort_by_key(|(i, _)| *i);
    Ok(all.into_iter().map(|(_, v)| v).collect())
}
