//! Counting heap allocations on the acting path of a running process.
//!
//! A binary that wants the count installs [`CountingAllocator`] as its global allocator; the
//! acting loop then wraps each decision in [`count_here`], and allocations made on that thread
//! while the guard lives are counted ([`counted`]). Other threads (the planner) and code
//! outside the guard are not counted. Without the allocator installed, [`installed`] is false
//! and the count stays 0 — reports then say "not measured" rather than "zero".
//!
//! ```
//! use tes_runtime::alloc_count;
//!
//! // (In a binary: #[global_allocator] static A: alloc_count::CountingAllocator =
//! //  alloc_count::CountingAllocator;)
//! let before = alloc_count::counted();
//! {
//!     let _guard = alloc_count::count_here();
//!     let _v: Vec<u8> = Vec::with_capacity(8); // counted if the allocator is installed
//! }
//! assert!(alloc_count::counted() >= before);
//! ```

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

static COUNTED: AtomicU64 = AtomicU64::new(0);
static INSTALLED: AtomicBool = AtomicBool::new(false);

thread_local! {
    static ARMED: Cell<bool> = const { Cell::new(false) };
}

/// The system allocator, counting allocations made inside [`count_here`].
#[derive(Debug, Clone, Copy, Default)]
pub struct CountingAllocator;

impl CountingAllocator {
    #[inline]
    fn note(&self) {
        INSTALLED.store(true, Ordering::Relaxed);
        // `try_with`: a thread being torn down has no thread-locals left; it is not acting.
        if ARMED.try_with(Cell::get).unwrap_or(false) {
            COUNTED.fetch_add(1, Ordering::Relaxed);
        }
    }
}

// SAFETY: every call is forwarded unchanged to `System`; the bookkeeping touches only atomics
// and a const-initialised thread-local `Cell`, neither of which allocates.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        self.note();
        // SAFETY: the caller's contract for `alloc` is passed on as is.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        self.note();
        // SAFETY: as for `alloc`.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        self.note();
        // SAFETY: as for `alloc`; `ptr` came from this allocator, i.e. from `System`.
        unsafe { System.realloc(ptr, layout, new_size) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from this allocator, i.e. from `System`.
        unsafe { System.dealloc(ptr, layout) }
    }
}

/// Counts this thread's allocations until the guard is dropped.
#[must_use = "allocations are counted only while the guard lives"]
#[derive(Debug)]
pub struct CountGuard {
    was_armed: bool,
}

/// Starts counting this thread's allocations (see the module docs).
pub fn count_here() -> CountGuard {
    let was_armed = ARMED.try_with(|a| a.replace(true)).unwrap_or(false);
    CountGuard { was_armed }
}

impl Drop for CountGuard {
    fn drop(&mut self) {
        let _ = ARMED.try_with(|a| a.set(self.was_armed));
    }
}

/// Allocations counted so far, all threads' guarded sections together.
pub fn counted() -> u64 {
    COUNTED.load(Ordering::Relaxed)
}

/// Whether [`CountingAllocator`] is this process's global allocator (it has seen an
/// allocation).
pub fn installed() -> bool {
    INSTALLED.load(Ordering::Relaxed)
}
