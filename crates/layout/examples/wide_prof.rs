//! bvh8's (or bvh4's, bvh2's) timed traversal alone, for a profiler: `cargo run --release -p bvhlab-layout
//! --example wide_prof -- [--runs N] [--width 2|4|8] SCENE`. Binned SAH (16 bins) and 10^6 random rays
//! of the anchors' kind (seed 7, infinite tmax), as `bench_trace`; prints Mrays/s of each run.
//! `WIDE_PROF_STATS=1`: steps and tests per ray too. The layouts' memory is advised for huge pages as
//! in the measure stage (`bvhlab_trace::thp`); `BVHLAB_THP=0` leaves it on ordinary pages, and
//! `--thp-ab` times both in one process, alternated.
use bvhlab_builders::{binned_sah, TopDownConfig};
use bvhlab_layout::wide::WideBvh;
use bvhlab_geom::stats::median;
use bvhlab_trace::{random_rays, Ray};

fn main() {
    let mut args = std::env::args().skip(1);
    let (mut runs, mut width, mut scene, mut thp_ab) = (5usize, 8usize, None, false);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--runs" => runs = args.next().and_then(|v| v.parse().ok()).expect("--runs N"),
            "--width" => width = args.next().and_then(|v| v.parse().ok()).expect("--width 2|4|8"),
            "--thp-ab" => thp_ab = true,
            _ => scene = Some(a),
        }
    }
    let spec = scene.expect("usage: wide_prof [--runs N] [--width 2|4|8] [--thp-ab] SCENE");
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
    if thp_ab {
        return thp_ab_runs(&bvh, &scene.triangles, &rays, width, runs, &pool);
    }
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
    // As the measure stage times it: node rows and packs advised for huge pages (`BVHLAB_THP=0`: not).
    let w = WideBvh::build(&bvh, width).expect("wide").timed_copy();
    let store = w.store(&scene.triangles);
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

/// `--thp-ab`: the timed layout on ordinary pages against the same layout advised for huge pages
/// (`bvhlab_trace::thp`), both built in this process and timed alternately (the order swapped every
/// round), so a slow phase of the machine falls on both; prints each side's median and the median
/// of the per-round ratios.
fn thp_ab_runs(bvh: &bvhlab_bvh::Bvh, tris: &[bvhlab_geom::Triangle], rays: &[Ray], width: usize, runs: usize, pool: &rayon::ThreadPool) {
    type Pass<'a> = Box<dyn Fn() -> Vec<bvhlab_trace::Hit> + Sync + 'a>;
    let mut sides: Vec<Pass> = Vec::new();
    for on in [false, true] {
        bvhlab_trace::thp::set_enabled(on);
        if width == 2 {
            let f = bvhlab_trace::FastBvh2::new(bvh, tris);
            sides.push(Box::new(move || f.hits(rays)));
        } else {
            let w = WideBvh::build(bvh, width).expect("wide").timed_copy();
            let s = w.store(tris);
            sides.push(Box::new(move || w.hits(&s, rays)));
        }
    }
    let rollup = std::fs::read_to_string("/proc/self/smaps_rollup").unwrap_or_default();
    let huge = rollup.lines().find(|l| l.starts_with("AnonHugePages")).unwrap_or("AnonHugePages: ?").to_string();
    let mut secs = [Vec::new(), Vec::new()];
    for r in 0..runs.max(1) {
        for k in [r & 1, 1 - (r & 1)] {
            let s = std::time::Instant::now();
            std::hint::black_box(pool.install(|| sides[k]()));
            secs[k].push(s.elapsed().as_secs_f64());
        }
    }
    let ratios: Vec<f64> = secs[0].iter().zip(&secs[1]).map(|(a, b)| a / b).collect();
    let mrays = |v: &[f64]| rays.len() as f64 / median(v) * 1e-6;
    println!(
        "bvh{width}: 4 KiB pages {:.2}, huge pages {:.2} Mrays/s; per-round speed-up median {:.3}, faster in {} of {}; {huge}",
        mrays(&secs[0]),
        mrays(&secs[1]),
        median(&ratios),
        ratios.iter().filter(|&&r| r > 1.0).count(),
        ratios.len()
    );
}
