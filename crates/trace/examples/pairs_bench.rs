//! bvh2's timed traversal on child pairs against the flat 32-byte nodes, alternated in one process:
//! `cargo run --release -p bvhlab-trace --example pairs_bench -- [--runs N] SCENE...`
//!
//! Per scene: binned SAH (16 bins, the thesis' settings, as `bench_trace`), 10^6 random rays of the
//! anchors' kind (seed 7, infinite tmax), 1 thread; median Mrays/s of `--runs` rounds, the two
//! traversals alternated within each round. Checks first that both give the same hits.
use bvhlab_builders::{binned_sah, TopDownConfig};
use bvhlab_geom::stats::median;
use bvhlab_trace::{random_rays, FastBvh2, Hit, Ray};

fn main() {
    let mut args = std::env::args().skip(1);
    let mut runs = 5usize;
    let mut scenes = Vec::new();
    while let Some(a) = args.next() {
        match a.as_str() {
            "--runs" => runs = args.next().and_then(|v| v.parse().ok()).expect("--runs N"),
            _ => scenes.push(a),
        }
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("thread pool");
    for spec in &scenes {
        let scene = match bvhlab_geom::load_scene(spec) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("{spec}: {e}");
                continue;
            }
        };
        let tris = &scene.triangles;
        let (boxes, centers) = scene.boxes_and_centers();
        let opts = binned_sah::BinnedOptions::new(16);
        let bvh =
            binned_sah::build_with_options(&boxes, &centers, &opts, &TopDownConfig::default());
        let b = scene.bounds();
        let radius = (0.5 * b.extent_f64().length()) as f32;
        let rays: Vec<Ray> = random_rays(&b, radius, 1_000_000, 7)
            .into_iter()
            .map(|r| Ray {
                tmax: f32::INFINITY,
                ..r
            })
            .collect();
        let f = FastBvh2::new(&bvh, tris);
        if f.hits(&rays) != f.hits_flat(&rays) {
            eprintln!("{spec}: pairs and flat nodes disagree");
            std::process::exit(1);
        }
        let time = |g: &(dyn Fn() -> Vec<Hit> + Sync)| {
            let s = std::time::Instant::now();
            std::hint::black_box(pool.install(g));
            s.elapsed().as_secs_f64()
        };
        let (mut flat, mut pairs) = (Vec::new(), Vec::new());
        for _ in 0..runs {
            flat.push(time(&|| f.hits_flat(&rays)));
            pairs.push(time(&|| f.hits(&rays)));
        }
        let m = |t: &[f64]| rays.len() as f64 / median(t) / 1e6;
        println!(
            "{spec}: flat {:.2} Mrays/s, pairs {:.2} ({:+.0} %)",
            m(&flat),
            m(&pairs),
            100.0 * (m(&pairs) / m(&flat) - 1.0)
        );
    }
}
