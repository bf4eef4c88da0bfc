//! Memory of the timed traversals on transparent huge pages (Linux `madvise(MADV_HUGEPAGE)`).
//!
//! Random rays through a scene larger than the caches miss the TLB at almost every step: the
//! dragon's bvh2 arena is ~75 MB, 18 k pages of 4 KiB. Embree asks the kernel for huge pages for
//! its BVHs (common/sys/alloc.cpp: `os_malloc` maps with `MAP_HUGETLB` or advises
//! `MADV_HUGEPAGE`; the embree-anchor's process holds ~67 MB of `AnonHugePages` while it traces
//! the dragon), so bvhlab's timed layouts do the same: without it the comparison measured the
//! operating system's page size, not the traversal (dragon, 1 thread, bvh2 1.51-1.63 -> 1.73-1.77
//! Mrays/s, bvh8 2.29-2.43 -> 2.72-2.83, docs/decisions.md). Only an advice: the kernel may
//! ignore it (THP mode `never`, no free huge page), and the bytes and the hits are the same.
//! A buffer is advised before it is first written and collapsed after it is filled
//! (`MADV_COLLAPSE`, Linux 6.1+): memory malloc recycles from the heap may already be backed by
//! small pages, which the advice alone would leave to the kernel's background merging, in the
//! middle of a measurement or never. `BVHLAB_THP=0` turns huge pages off for the whole process and
//! the programs it starts (`PR_SET_THP_DISABLE`: Embree's own advice included, and THP mode
//! `always`), for A/B measurements; [`set_enabled`] switches only this module's advice (in-process
//! A/B, then with `MADV_NOHUGEPAGE`).

use std::sync::atomic::{AtomicU8, Ordering::Relaxed};

/// 2 MiB: the x86-64 huge page, the unit the advice is aligned to.
const HUGE: usize = 2 << 20;

/// 0: not decided yet, 1: on, 2: off.
static STATE: AtomicU8 = AtomicU8::new(0);

/// False when the environment says `BVHLAB_THP=0` (read at the first call, which then also
/// disables huge pages for the process: `PR_SET_THP_DISABLE`) or after `set_enabled(false)`.
pub fn enabled() -> bool {
    match STATE.load(Relaxed) {
        0 => {
            let on = std::env::var_os("BVHLAB_THP").is_none_or(|v| v != "0");
            STATE.store(if on { 1 } else { 2 }, Relaxed);
            #[cfg(target_os = "linux")]
            if !on {
                // SAFETY: a process attribute; no memory is touched. Failure leaves THP as it was.
                unsafe { libc::prctl(libc::PR_SET_THP_DISABLE, 1 as libc::c_ulong, 0 as libc::c_ulong, 0 as libc::c_ulong, 0 as libc::c_ulong) };
            }
            on
        }
        s => s == 1,
    }
}

/// Turns the advice on or off for what is allocated from now on (A/B measurements in one process).
pub fn set_enabled(on: bool) {
    STATE.store(if on { 1 } else { 2 }, Relaxed);
}

/// An empty vector with room for `n` items whose whole 2 MiB-aligned part of the allocation is
/// advised before anything touches it (the pages are backed when first written, which is when the
/// kernel picks their size); call [`settle`] once it is filled. Allocations below 2 MiB are left
/// alone.
pub fn with_capacity<T>(n: usize) -> Vec<T> {
    let v: Vec<T> = Vec::with_capacity(n);
    #[cfg(target_os = "linux")]
    let advice = if enabled() { libc::MADV_HUGEPAGE } else { libc::MADV_NOHUGEPAGE };
    #[cfg(not(target_os = "linux"))]
    let advice = 0;
    madvise(v.as_ptr() as usize, n.saturating_mul(std::mem::size_of::<T>()), advice);
    v
}

/// Has the kernel back the filled buffer `v` (from [`with_capacity`]) with huge pages now
/// (`MADV_COLLAPSE`), where parts of it were already backed by small pages before the advice.
pub fn settle<T>(v: &[T]) {
    if enabled() {
        madvise(v.as_ptr() as usize, std::mem::size_of_val(v), MADV_COLLAPSE);
    }
}

/// A copy of `src` in memory advised as [`with_capacity`]'s, settled.
pub fn copy<T: Copy>(src: &[T]) -> Vec<T> {
    let mut v = with_capacity(src.len());
    v.extend_from_slice(src);
    settle(&v);
    v
}

/// `n` copies of `x` in memory advised as [`with_capacity`]'s, settled.
pub fn filled<T: Clone>(x: T, n: usize) -> Vec<T> {
    let mut v = with_capacity(n);
    v.resize(n, x);
    settle(&v);
    v
}

/// Linux's `MADV_COLLAPSE` (6.1+; the same number on every architecture). Older kernels refuse it.
const MADV_COLLAPSE: i32 = 25;

/// `madvise(advice)` on the 2 MiB-aligned pages inside `[start, start + len)`; failures are ignored
/// (a hint; an old kernel refuses `MADV_COLLAPSE`).
fn madvise(start: usize, len: usize, advice: i32) {
    let (s, e) = (start.next_multiple_of(HUGE), (start.saturating_add(len)) & !(HUGE - 1));
    #[cfg(target_os = "linux")]
    if e > s {
        // SAFETY: [s, e) lies inside one live allocation of the caller and is page-aligned; these
        // advices change no contents and no mapping, only the size of the pages backing it.
        unsafe {
            libc::madvise(s as *mut libc::c_void, e - s, advice);
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = (s, e, advice);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn copies_and_fills_keep_the_values() {
        let src: Vec<u64> = (0..(3 * HUGE / 8) as u64).collect();
        assert_eq!(copy(&src), src);
        let f = filled(7u32, HUGE);
        assert_eq!(f.len(), HUGE);
        assert!(f.iter().all(|&x| x == 7));
        assert!(copy::<u8>(&[]).is_empty());
    }

    /// Linux with THP not `never`: a large advised buffer comes back (at least partly) as huge
    /// pages, seen in /proc/self/smaps_rollup. Skipped where the kernel does not offer them.
    #[cfg(target_os = "linux")]
    #[test]
    fn advised_memory_gets_huge_pages_where_offered() {
        let mode = std::fs::read_to_string("/sys/kernel/mm/transparent_hugepage/enabled").unwrap_or_default();
        // THP disabled for this process (prctl, a cgroup or the environment's BVHLAB_THP=0).
        let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
        if !enabled() || mode.is_empty() || mode.contains("[never]") || status.contains("THP_enabled:\t0") {
            return;
        }
        let anon_huge = || -> Option<u64> {
            let s = std::fs::read_to_string("/proc/self/smaps_rollup").ok()?;
            s.lines().find(|l| l.starts_with("AnonHugePages:")).and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        };
        let Some(before) = anon_huge() else { return };
        let v = filled(1u8, 16 * HUGE);
        let after = anon_huge().unwrap_or(0);
        std::hint::black_box(&v);
        // 4 of the 16: a margin for another test thread freeing huge pages meanwhile; a kernel out
        // of free huge pages fails it (then the timed paths do not get them either: worth knowing).
        assert!(after >= before + 4 * (HUGE as u64 / 1024), "AnonHugePages {before} -> {after} kB");
    }
}
