//! Exactness of every layout against brute force (issue 5: zero differences on 10^5 random rays):
//! `cargo run --release -p bvhlab-layout --example layout_exact -- [--leaf 2] [--rays 100000]
//!  SCENE... SPEC...`
//!
//! SCENE is a path (.obj / .obj.gz) or `gen:...`; SPEC is `name` or `name:k=v,k=v` (bvh2, qbvh_chunks,
//! octree, octree_1bit). Per scene: binned SAH (16 bins, leaf 2 by default; the BVH layouts store it),
//! random rays as in tests/common, brute force ONCE (parallel), then every layout is built,
//! validated and traced, and its hits compared with brute force (same triangle, or t within 1e-6
//! relative). One line per (scene, layout): differences (must be 0), validation, times.
use bvhlab_builders::{binned_sah, TopDownConfig};
use bvhlab_geom::load_scene;
use bvhlab_layout::{build, LayoutSpec};
use bvhlab_trace::{brute_force, random_rays, Hit};
use std::collections::BTreeMap;
use std::time::Instant;

fn parse_spec(s: &str) -> Result<LayoutSpec, String> {
    let (name, rest) = s.split_once(':').unwrap_or((s, ""));
    let mut kv = BTreeMap::new();
    for p in rest.split(',').filter(|p| !p.is_empty()) {
        let (k, v) = p
            .split_once('=')
            .ok_or_else(|| format!("`{p}` in `{s}` is not k=v"))?;
        kv.insert(k.to_string(), v.to_string());
    }
    LayoutSpec::parse(name, &kv)
}

fn same_hit(g: &Hit, w: &Hit) -> bool {
    g.prim == w.prim || (g.is_hit() && w.is_hit() && (g.t - w.t).abs() <= 1e-6 * w.t.abs())
}

fn main() {
    let mut leaf = 2u32;
    let mut n_rays = 100_000usize;
    let mut scenes = Vec::new();
    let mut specs = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut num = |name: &str| -> usize {
            args.next()
                .and_then(|v| v.parse().ok())
                .filter(|&v: &usize| v > 0)
                .unwrap_or_else(|| panic!("{name} needs a positive integer"))
        };
        match a.as_str() {
            "--leaf" => leaf = num("--leaf") as u32,
            "--rays" => n_rays = num("--rays"),
            s if s.starts_with("gen:") || s.contains(".obj") || s.contains('/') => {
                scenes.push(s.to_string())
            }
            s => specs.push(parse_spec(s).unwrap_or_else(|e| panic!("{e}"))),
        }
    }
    if scenes.is_empty() || specs.is_empty() {
        eprintln!("usage: layout_exact [--leaf 2] [--rays 100000] SCENE... SPEC...");
        std::process::exit(2);
    }
    println!("# leaf={leaf} rays={n_rays}; diff = rays whose closest hit differs from brute force");
    println!(
        "{:<24} {:<56} {:>6} {:>9} {:>8} {:>8} validate",
        "scene", "layout", "diff", "hits", "build_s", "trace_s"
    );
    let mut total_diff = 0usize;
    let mut failures = 0usize;
    for path in &scenes {
        let scene = load_scene(path).unwrap_or_else(|e| panic!("{path}: {e:?}"));
        let tris = &scene.triangles;
        let (boxes, centers) = scene.boxes_and_centers();
        let bvh = binned_sah::build(
            &boxes,
            &centers,
            16,
            &TopDownConfig {
                leaf,
                ..Default::default()
            },
        );
        let b = scene.bounds();
        let radius = b.enclosing_radius(centers.iter().copied());
        let rays = random_rays(&b, radius, n_rays, 7);
        let t = Instant::now();
        let want = brute_force(tris, &rays);
        let name = std::path::Path::new(path)
            .file_name()
            .map(|s| {
                s.to_string_lossy()
                    .replace(".obj.gz", "")
                    .replace(".obj", "")
            })
            .unwrap_or_else(|| path.clone());
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
