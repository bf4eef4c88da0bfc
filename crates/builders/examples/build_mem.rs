//! Peak memory of one builder on one scene (issue 19.4: "peak memory of every builder reported"):
//! `cargo run --release -p bvhlab-builders --example build_mem -- SCENE BUILDER [threads=1]`
//! BUILDER is any name `build_bench` takes (the Morton family includes encode and compaction, as
//! there, and drops the centres once encoded, as the pipeline's build stage has none for them).
//! One builder per process, since the kernel's high-water mark (VmHWM) only grows. Prints one
//! JSON line: the process's peak RSS after loading the scene and computing boxes and centres,
//! and after one build; the heap growth during the build (a counting allocator: the builder's own
//! peak, its output included); and the final peak RSS per triangle. Blocks of 1 MiB and more are
//! mapped and unmapped on their own (see [`fixed_mmap_threshold`]).
#[allow(dead_code)]
#[path = "build_bench.rs"]
mod bench;

use bvhlab_builders::TopDownConfig;
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};

static CURRENT: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

/// Live heap bytes and their high-water mark (as `bvhlab_pipeline::memtrack`, which this example
/// cannot link: the builders crate is below the pipeline).
struct Counting;

// SAFETY: every call is forwarded to `System` unchanged; the counters do not allocate.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let p = System.alloc(l);
        if !p.is_null() {
            grow(l.size());
        }
        p
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        let p = System.alloc_zeroed(l);
        if !p.is_null() {
            grow(l.size());
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        System.dealloc(p, l);
        CURRENT.fetch_sub(l.size(), Relaxed);
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        let q = System.realloc(p, l, n);
        if !q.is_null() {
            if n >= l.size() {
                grow(n - l.size());
            } else {
                CURRENT.fetch_sub(l.size() - n, Relaxed);
            }
        }
        q
    }
}

fn grow(n: usize) {
    let now = CURRENT.fetch_add(n, Relaxed) + n;
    PEAK.fetch_max(now, Relaxed);
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// A `kB` field of /proc/self/status (0 where there is none, e.g. not Linux).
fn status_kib(field: &str) -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with(field))
                .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        })
        .unwrap_or(0)
}

/// Every allocation of 1 MiB or more mapped on its own and unmapped when freed. glibc's default
/// moves this threshold up to the size of the last such block freed, after which big arrays come
/// from the heap and may stay resident when freed: the same build then peaked at 121 or 131 MB on
/// the dragon from one run to the next, by what the loader's threads happened to free first. Fixed,
/// the peak RSS is that of the live data (five runs within 0.1 %).
fn fixed_mmap_threshold() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes the allocator's policy for later allocations.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 20);
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        eprintln!("usage: build_mem SCENE BUILDER [threads=1]");
        std::process::exit(2);
    }
    let (spec, name) = (&args[1], args[2].as_str());
    fixed_mmap_threshold();
    let threads: usize = args.get(3).and_then(|t| t.parse().ok()).unwrap_or(1);
    let scene = bvhlab_geom::load_scene(spec).unwrap_or_else(|e| {
        eprintln!("error: {e}");
        std::process::exit(1)
    });
    let (boxes, centers) = scene.boxes_and_centers();
    let n = boxes.len().max(1);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("rayon pool");
    let (hwm_load, rss_load) = (status_kib("VmHWM:"), status_kib("VmRSS:"));
    let base = CURRENT.load(Relaxed);
    PEAK.store(base, Relaxed);
    let cfg = TopDownConfig::default();
    let bvh = if !bench::BOTTOM_UP.contains(&name) {
        pool.install(|| bench::run(name, &boxes, &centers, &cfg)).0
    } else {
        // A bottom-up builder reads boxes and codes only: as in the pipeline, whose build stage
        // gets no centres for it (the encode stage, a separate step, had its own).
        let enc = pool.install(|| bench::encode_for(name, &boxes, &centers));
        drop(centers);
        pool.install(|| bench::bottom_up(name, &boxes, &enc, cfg.cost))
    };
    let heap_peak = PEAK.load(Relaxed) - base;
    let hwm = status_kib("VmHWM:");
    println!(
        "{{\"scene\":{spec:?},\"triangles\":{n},\"builder\":\"{name}\",\"threads\":{threads},\"nodes\":{},\
         \"rss_after_load_kib\":{rss_load},\"peak_rss_after_load_kib\":{hwm_load},\"peak_rss_kib\":{hwm},\
         \"peak_rss_bytes_per_triangle\":{:.1},\"build_heap_peak_bytes\":{heap_peak},\
         \"build_heap_peak_bytes_per_triangle\":{:.1}}}",
        bvh.nodes.len(),
        hwm as f64 * 1024.0 / n as f64,
        heap_peak as f64 / n as f64,
    );
}
