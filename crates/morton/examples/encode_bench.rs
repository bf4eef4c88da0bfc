//! Encode-stage speed: `cargo run --release -p bvhlab-morton --example encode_bench [SCENE] [RUNS]`
//! (default ../shared/scenes/stanford_dragon.obj.gz, 5 runs). Median encode time (codes + sort)
//! per configuration at 1 and 2 threads, one line each.
use bvhlab_morton::{encode, AutoFor, Bits, BoundsMode, EncodeConfig, Scheme};
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let spec = args.get(1).cloned().unwrap_or_else(|| "../shared/scenes/stanford_dragon.obj.gz".into());
    let runs: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(5);
    let scene = bvhlab_geom::load_scene(&spec).expect("scene");
    let (boxes, centers) = scene.boxes_and_centers();
    let d = EncodeConfig::default();
    let configs = [
        ("morton:auto-lbvh(30)", EncodeConfig { bits: Bits::Auto(AutoFor::Lbvh), ..d }),
        ("morton:auto-ploc(60)", EncodeConfig { bits: Bits::Auto(AutoFor::Ploc), ..d }),
        ("emc64-sort", EncodeConfig { scheme: Scheme::Emc64Sort, ..d }),
        ("emc64-var", EncodeConfig { scheme: Scheme::Emc64Var, ..d }),
        ("morton:10+concise", EncodeConfig { bounds: BoundsMode::Concise, ..d }),
        ("morton:10+grid12", EncodeConfig { grid_bits: 12, ..d }),
        ("emc64-var+grid9", EncodeConfig { scheme: Scheme::Emc64Var, grid_bits: 9, ..d }),
    ];
    for threads in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            for (name, cfg) in &configs {
                let mut t: Vec<f64> = (0..runs)
                    .map(|_| {
                        let s = Instant::now();
                        let e = encode(&boxes, &centers, cfg);
                        std::hint::black_box(&e);
                        s.elapsed().as_secs_f64() * 1e3
                    })
                    .collect();
                t.sort_by(f64::total_cmp);
                println!("{spec} n={} {name:<22} threads={threads} median_ms={:.1}", boxes.len(), t[t.len() / 2]);
            }
        });
    }
}
