//! bvh8's (or bvh4's, bvh2's) timed traversal alone, for a profiler: `cargo run --release -p bvhlab-layout
//! --example wide_prof -- [--runs N] [--width 2|4|8] SCENE`. Binned SAH (16 bins) and 10^6 random rays
//! of the anchors' kind (seed 7, infinite tmax), as `bench_trace`; prints Mrays/s of each run.
//! `WIDE_PROF_STATS=1`: steps and tests per ray too. `WIDE_PROF_HUGEPAGES=1`: the nodes and triangle
//! packs copied into memory backed by transparent huge pages (Linux; an experiment, see
//! docs/decisions.md).
use bvhlab_builders::{binned_sah, TopDownConfig};
use bvhlab_layout::wide::WideBvh;
use bvhlab_trace::{random_rays, Ray};

fn main() {
    let mut args = std::env::args().skip(1);
    let (mut runs, mut width, mut scene) = (5usize, 8usize, None);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--runs" => runs = args.next().and_then(|v| v.parse().ok()).expect("--runs N"),
            "--width" => width = args.next().and_then(|v| v.parse().ok()).expect("--width 2|4|8"),
            _ => scene = Some(a),
        }
    }
    let spec = scene.expect("usage: wide_prof [--runs N] [--width 2|4|8] SCENE");
    let scene = bvhlab_geom::load_scene(&spec).unwrap_or_else(|e| panic!("{spec}: {e}"));
    let (boxes, centers) = scene.boxes_and_centers();
    let bvh = binned_sah::build_with_options(
        &boxes,
        &centers,
        &binned_sah::BinnedOptions::new(16),
        &TopDownConfig::default(),
    );
    let b = scene.bounds();
    let radius = (0.5 * b.extent_f64().length()) as f32;
    let rays: Vec<Ray> =
        random_rays(&b, radius, 1_000_000, 7).into_iter().map(|r| Ray { tmax: f32::INFINITY, ..r }).collect();
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool");
    if width == 2 {
        // bvh2's timed path (child pairs).
        let f = bvhlab_trace::FastBvh2::new(&bvh, &scene.triangles);
        for _ in 0..runs.max(1) + 1 {
            let s = std::time::Instant::now();
            std::hint::black_box(pool.install(|| f.hits(&rays)));
            println!("bvh2: {:.2} Mrays/s", rays.len() as f64 / s.elapsed().as_secs_f64() * 1e-6);
        }
        return;
    }
    let mut w = WideBvh::build(&bvh, width).expect("wide");
    let mut store = w.store(&scene.triangles);
    if std::env::var_os("WIDE_PROF_HUGEPAGES").is_some() {
        w.data = huge(&w.data);
        store.packs = huge(&store.packs);
        let rollup = std::fs::read_to_string("/proc/self/smaps_rollup").unwrap_or_default();
        eprintln!("huge pages advised: {}", rollup.lines().filter(|l| l.contains("AnonHuge")).collect::<String>());
    }
    let hits = pool.install(|| w.hits(&store, &rays));
    println!("hit fraction {:.4}", hits.iter().filter(|h| h.is_hit()).count() as f64 / rays.len() as f64);
    if std::env::var_os("WIDE_PROF_STATS").is_some() {
        // The counting pass (exact test, untimed): steps = wide nodes and leaves entered.
        let st = pool.install(|| w.trace(&scene.triangles, &rays));
        let n = rays.len() as f64;
        println!(
            "steps/ray {:.2}, triangle tests/ray {:.2}",
            st.total_steps as f64 / n,
            st.total_intersections as f64 / n
        );
    }
    for _ in 0..runs {
        let s = std::time::Instant::now();
        std::hint::black_box(pool.install(|| w.hits(&store, &rays)));
        println!("bvh{width}: {:.2} Mrays/s", rays.len() as f64 / s.elapsed().as_secs_f64() * 1e-6);
    }
}

/// A copy of `src` whose 2 MiB-aligned part the kernel is asked to back with transparent huge pages
/// (Linux `madvise(MADV_HUGEPAGE)`, before the copy first touches the pages).
fn huge<T: Copy>(src: &[T]) -> Vec<T> {
    const H: usize = 2 << 20;
    let mut v: Vec<T> = Vec::with_capacity(src.len());
    let a = v.as_ptr() as usize;
    let e = a + std::mem::size_of_val(src);
    let (s, t) = ((a + H - 1) & !(H - 1), e & !(H - 1));
    #[cfg(target_os = "linux")]
    if t > s {
        // SAFETY: [s, t) lies inside `v`'s allocation (page-aligned, so a valid madvise range).
        let r = unsafe { libc::madvise(s as *mut libc::c_void, t - s, libc::MADV_HUGEPAGE) };
        if r != 0 {
            eprintln!("madvise(MADV_HUGEPAGE) failed: {}", std::io::Error::last_os_error());
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = (s, t);
    v.extend_from_slice(src);
    v
}
