//! Peak heap measurement for the BVH stages (build, optimize, compact) and the layout stage: a
//! counting global allocator around
//! `std::alloc::System` (live bytes and their high-water mark, Relaxed atomics: one add per
//! allocation, a load and a rare `fetch_max` for the peak).
//!
//! The counters are **process-wide**: every thread's allocations count, so a measurement taken while
//! other work allocates concurrently (a parallel test, another stage) includes that work. The
//! pipeline runs stages one at a time, so `peak_build_bytes` (layout) and `build_heap_bytes` (build)
//! are the stage's own heap growth (its rayon workers included) plus the noise of whatever else the process does meanwhile.
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};

static CURRENT: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

/// The counting allocator (installed for every binary linking the pipeline).
pub struct Counting;

#[inline]
fn grow(n: usize) {
    let now = CURRENT.fetch_add(n, Relaxed) + n;
    // A plain load first: the read-modify-write only happens while a new peak is being set.
    if now > PEAK.load(Relaxed) {
        PEAK.fetch_max(now, Relaxed);
    }
}

#[inline]
fn shrink(n: usize) {
    CURRENT.fetch_sub(n, Relaxed);
}

// SAFETY: every call is forwarded to `System` unchanged; the counters do not allocate.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc(layout);
        if !p.is_null() {
            grow(layout.size());
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc_zeroed(layout);
        if !p.is_null() {
            grow(layout.size());
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout);
        shrink(layout.size());
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = System.realloc(ptr, layout, new_size);
        if !p.is_null() {
            if new_size >= layout.size() {
                grow(new_size - layout.size());
            } else {
                shrink(layout.size() - new_size);
            }
        }
        p
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Live heap bytes of the process (allocated through the global allocator, not yet freed).
pub fn current() -> usize {
    CURRENT.load(Relaxed)
}

/// Start of a measurement: the live bytes now (the peak is reset to them).
#[derive(Clone, Copy, Debug)]
pub struct Mark {
    base: usize,
}

/// Resets the high-water mark to the current live bytes and returns the baseline.
pub fn reset_peak() -> Mark {
    let base = CURRENT.load(Relaxed);
    PEAK.store(base, Relaxed);
    Mark { base }
}

/// Peak live bytes since `mark` minus the baseline: the heap growth of what ran in between
/// (process-wide, see the module doc).
pub fn peak_since(mark: Mark) -> u64 {
    PEAK.load(Relaxed).saturating_sub(mark.base) as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_a_large_allocation() {
        let m = reset_peak();
        let v = vec![1u8; 8 << 20];
        std::hint::black_box(&v);
        drop(v);
        let p = peak_since(m);
        // Other test threads may allocate meanwhile; the 8 MiB are a lower bound.
        assert!(p >= 8 << 20, "{p}");
    }
}
