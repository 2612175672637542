//! A global allocator that counts allocations and reallocations, for the
//! allocation tests of the planner and of the daemon (each test binary
//! that declares `mod counting;` counts its own).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Allocations and reallocations so far in this test binary, on every
/// thread.
#[allow(dead_code)]
pub static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    /// Allocations and reallocations so far on this thread.
    static HERE: Cell<usize> = const { Cell::new(0) };
}

/// Allocations and reallocations so far on the calling thread: a count
/// that threads the process runs beside it (a background solver, a cold
/// planner) cannot change.
#[allow(dead_code)]
pub fn on_this_thread() -> usize {
    HERE.with(Cell::get)
}

/// Counts one allocation or reallocation.
fn count() {
    ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
    // `try_with`, not `with`: never a panic inside the allocator (a
    // `const` `Cell` has no destructor, so it does not fail).
    let _ = HERE.try_with(|here| here.set(here.get() + 1));
}

/// The system allocator, counting allocations and reallocations.
struct Counting;

// SAFETY: forwards every call to the system allocator unchanged.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: forwarded.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: forwarded.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: forwarded.
        unsafe { System.realloc(ptr, layout, new_size) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;
