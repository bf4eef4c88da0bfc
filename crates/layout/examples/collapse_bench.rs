//! Greedy (Wald et al. 2008) against SAH-optimal (Ylitie et al. 2017) collapse into bvh4 / bvh8:
//! `cargo run --release -p bvhlab-layout --example collapse_bench -- [--runs N] [--rays N] [--build B] SCENE...`
//! Per scene and collapse: collapse time (one run), wide nodes, the wide tree's SAH cost (c_T = 3, c_I = 2, `WideBvh::sah_cost`),
//! nodes entered / triangle tests per ray (exact traversal, 10^4 rays) and 1-thread Mrays/s of the timed
//! path on the bench-trace rays (median of `--runs` rounds, the configurations alternated in each round).
//! The binary tree: binned SAH, 16 bins (`--build all` bins all axes, 8 bins).
use bvhlab_bvh::CostParams;
use bvhlab_builders::binned_sah::{self, Axes, BinnedOptions};
use bvhlab_builders::TopDownConfig;
use bvhlab_geom::stats::median;
use bvhlab_layout::wide::{Collapse, CollapseCost, WideBvh};
use bvhlab_trace::{check_agreement, random_rays, Ray};

fn main() {
    let mut args = std::env::args().skip(1);
    let (mut runs, mut n_rays, mut build) = (5usize, 1_000_000usize, "largest".to_string());
    let mut scenes = Vec::new();
    while let Some(a) = args.next() {
        match a.as_str() {
            "--runs" => runs = args.next().and_then(|v| v.parse().ok()).expect("--runs N"),
            "--rays" => n_rays = args.next().and_then(|v| v.parse().ok()).expect("--rays N"),
            "--build" => build = args.next().expect("--build largest|all|sbvh"),
            _ => scenes.push(a),
        }
    }
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool");
    // VARIANTS: "c_node/c_leaf/max_leaf/block,..." (default "1/1/4/4,3/2/4/1").
    let spec = std::env::var("VARIANTS").unwrap_or_else(|_| "1/1/4/4,3/2/4/1".to_string());
    let variants: Vec<(String, Collapse)> = std::iter::once(("greedy".to_string(), Collapse::Greedy))
        .chain(spec.split(',').map(|v| {
            let f: Vec<f32> = v.split('/').map(|x| x.parse().expect("number")).collect();
            let c = CollapseCost { c_node: f[0], c_leaf: f[1], max_leaf: f[2] as u32, block: (f[3] as u32).max(1) };
            (format!("opt{v}"), Collapse::Optimal(c))
        }))
        .collect();
    for spec in &scenes {
        let scene = bvhlab_geom::load_scene(spec).expect("scene");
        let tris = &scene.triangles;
        let (boxes, centers) = scene.boxes_and_centers();
        let mut opts = BinnedOptions::new(16);
        if build == "all" {
            opts = BinnedOptions { bins: 8, axes: Axes::All, ..opts };
        }
        let bvh = if build == "sbvh" {
            bvhlab_builders::sbvh::build(tris, &bvhlab_builders::sbvh::SbvhConfig::default())
        } else {
            binned_sah::build_with_options(&boxes, &centers, &opts, &TopDownConfig::default())
        };
        let refs = if build == "sbvh" { bvhlab_bvh::Refs::Split } else { bvhlab_bvh::Refs::Unique };
        let b = scene.bounds();
        let radius = (0.5 * b.extent_f64().length()) as f32;
        let rays: Vec<Ray> =
            random_rays(&b, radius, n_rays, 7).into_iter().map(|r| Ray { tmax: f32::INFINITY, ..r }).collect();
        let sample = &rays[..rays.len().min(10_000)];
        let exact = bvhlab_trace::trace(&bvh, tris, sample).hits;
        let cost = CostParams::default();
        for width in [4usize, 8] {
            let mut build_ms = Vec::new();
            let built: Vec<(String, WideBvh)> = variants
                .iter()
                .map(|(name, c)| {
                    let t0 = std::time::Instant::now();
                    let w = WideBvh::build_with(&bvh, width, *c).expect("wide");
                    build_ms.push(t0.elapsed().as_secs_f64() * 1e3);
                    (name.clone(), w)
                })
                .collect();
            let stores: Vec<_> = built.iter().map(|(_, w)| w.store(tris)).collect();
            for ((name, w), s) in built.iter().zip(&stores) {
                w.validate_refs(tris, refs).expect("valid");
                check_agreement(tris, sample, &w.hits(s, sample), &exact, sample.len() / 1000 + 1)
                    .unwrap_or_else(|e| panic!("{name}: {e}"));
            }
            let mut t = vec![Vec::new(); built.len()];
            for _ in 0..runs {
                for (j, ((_, w), s)) in built.iter().zip(&stores).enumerate() {
                    let st = std::time::Instant::now();
                    pool.install(|| std::hint::black_box(w.hits(s, &rays)));
                    t[j].push(st.elapsed().as_secs_f64());
                }
            }
            for (j, (name, w)) in built.iter().enumerate() {
                let st = w.trace(tris, sample);
                let n = sample.len() as f64;
                println!(
                    "{:<18} bvh{width} {:<12} build {:>6.1} ms nodes {:>8} leaves {:>8} sah {:>8.2} steps {:>5.2} tests {:>5.2} mrays {:>6.2}",
                    std::path::Path::new(spec).file_name().unwrap().to_string_lossy(),
                    name,
                    build_ms[j],
                    w.nodes(),
                    w.leaves.len(),
                    w.sah_cost(cost),
                    st.total_steps as f64 / n,
                    st.total_intersections as f64 / n,
                    rays.len() as f64 / median(&t[j]) / 1e6
                );
            }
        }
    }
}
