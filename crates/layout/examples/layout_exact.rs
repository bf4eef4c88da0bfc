//! Exactness of every layout against brute force (issue 5: zero differences on 10^5 random rays):
//! `cargo run --release -p bvhlab-layout --example layout_exact -- [--leaf 2] [--rays 100000]
//!  SCENE... SPEC...`
//!
//! SCENE is a path (.obj / .obj.gz) or `gen:...`; SPEC is `name` or `name:k=v,k=v` (bvh2, qbvh_chunks,
//! octree, octree_1bit). Per scene: binned SAH (16 bins, leaf 2 by default; the BVH layouts store it),
//! random rays as in tests/common, brute force ONCE (parallel), then every layout is built,
//! validated and traced, and its hits compared with brute force (same triangle, or t within 1e-6
//! relative). One line per (scene, layout): differences (must be 0), validation, times.
mod common;
use common::{same_hit, Setup};
use bvhlab_layout::build;
use bvhlab_trace::brute_force;
use std::time::Instant;

/// Exactness of every layout against brute force.
#[derive(clap::Parser)]
struct Args {
    #[arg(long, default_value_t = 2)]
    leaf: u32,
    #[arg(long, default_value_t = 100_000)]
    rays: usize,
    /// Scenes (a path or `gen:...`), then layouts (`name` or `name:k=v,...`).
    #[arg(required = true, num_args = 2..)]
    items: Vec<String>,
}

fn main() {
    let a = <Args as clap::Parser>::parse();
    let (leaf, n_rays) = (a.leaf, a.rays);
    let (scenes, specs) = common::scenes_and_layouts(&a.items);
    println!("# leaf={leaf} rays={n_rays}; diff = rays whose closest hit differs from brute force");
    println!(
        "{:<24} {:<56} {:>6} {:>9} {:>8} {:>8} validate",
        "scene", "layout", "diff", "hits", "build_s", "trace_s"
    );
    let mut total_diff = 0usize;
    let mut failures = 0usize;
    for path in &scenes {
        let Setup { name, scene, bvh, rays } = Setup::new(path, leaf, n_rays, 7);
        let tris = &scene.triangles;
        let t = Instant::now();
        let want = brute_force(tris, &rays);
        eprintln!(
            "{name}: {} tris, brute force {:.1} s",
            tris.len(),
            t.elapsed().as_secs_f64()
        );
        for spec in &specs {
            let label = format!("{}:{}", spec.name, spec.params_string());
            let t = Instant::now();
            let l = match build(spec, &bvh, tris) {
                Ok(l) => l,
                Err(e) => {
                    failures += 1;
                    println!("{name:<24} {label:<56} build failed: {e}");
                    continue;
                }
            };
            let build_s = t.elapsed().as_secs_f64();
            let valid = match l.validate(tris) {
                Ok(()) => "ok".to_string(),
                Err(e) => {
                    failures += 1;
                    format!("INVALID: {e}")
                }
            };
            let t = Instant::now();
            let got = l.trace(tris, &rays);
            let trace_s = t.elapsed().as_secs_f64();
            let diff = got
                .hits
                .iter()
                .zip(&want)
                .filter(|(g, w)| !same_hit(g, w))
                .count();
            total_diff += diff;
            println!(
                "{name:<24} {label:<56} {diff:>6} {:>9} {build_s:>8.2} {trace_s:>8.2} {valid}",
                got.hit_count
            );
        }
    }
    println!("# total differences {total_diff}, failed builds/validations {failures}");
    if total_diff > 0 || failures > 0 {
        std::process::exit(1);
    }
}
