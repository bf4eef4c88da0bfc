//! Times the builders on one scene: `cargo run --release -p bvhlab-build --example build_bench -- SCENE [runs=5]`.
//! SCENE is a path (.obj / .obj.gz) or `gen:...`. Boxes and centres are computed once (not timed);
//! each builder runs `runs` times; one JSON line per builder with median/min ms and the eq. 4 SAH
//! cost (c_T = 3, c_I = 2) of the built tree.
use bvhlab_build::binned_sah::CentroidTermination;
use bvhlab_build::{binned_sah, spatial_median, sweep_sah, TopDownConfig};
use bvhlab_bvh::{metrics, validate, Bvh};
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let Some(spec) = args.get(1) else {
        eprintln!("usage: build_bench SCENE [runs=5]");
        std::process::exit(2);
    };
    let runs: usize = match args.get(2).map(|s| s.parse()) {
        None => 5,
        Some(Ok(r)) if r > 0 => r,
        Some(_) => {
            eprintln!("runs must be a positive integer");
            std::process::exit(2);
        }
    };
    let scene = match bvhlab_geom::load_scene(spec) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    };
    let (boxes, centers) = scene.boxes_and_centers();
    let cfg = TopDownConfig::default();
    type Builder<'a> = Box<dyn Fn() -> Bvh + 'a>;
    let builders: Vec<(&str, Builder)> = vec![
        (
            "spatial-median",
            Box::new(|| spatial_median::build(&boxes, &centers, &cfg)),
        ),
        (
            "binned-sah",
            Box::new(|| binned_sah::build(&boxes, &centers, 16, &cfg)),
        ),
        // The thesis' literal centroid termination (any dimension below 1e-7), for its BIN column.
        (
            "binned-sah-any-axis",
            Box::new(|| {
                binned_sah::build_with_termination(
                    &boxes,
                    &centers,
                    16,
                    &cfg,
                    CentroidTermination::AnyAxis,
                )
            }),
        ),
        (
            "sweep-sah",
            Box::new(|| sweep_sah::build(&boxes, &centers, &cfg)),
        ),
    ];
    for (name, build) in &builders {
        let mut ms = Vec::with_capacity(runs);
        let mut bvh = Bvh::default();
        for _ in 0..runs {
            let t = Instant::now();
            bvh = std::hint::black_box(build());
            ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
        ms.sort_by(f64::total_cmp);
        let valid = validate(&bvh, &boxes).err().unwrap_or_else(|| "ok".into());
        let m = metrics(&bvh, cfg.cost);
        println!(
            "{{\"scene\":{:?},\"triangles\":{},\"builder\":\"{name}\",\"runs\":{runs},\"build_ms_median\":{:.2},\"build_ms_min\":{:.2},\"sah_cost\":{:.3},\"leaves\":{},\"refs_per_leaf\":{:.3},\"depth\":{},\"valid\":{:?}}}",
            spec,
            boxes.len(),
            ms[runs / 2],
            ms[0],
            m.sah_cost,
            m.leaves,
            m.refs_per_leaf,
            m.depth,
            valid
        );
    }
}
