//! Large-scene oracle (issue 6): on each scene, 10^5 random rays (thesis 4.4), brute force once,
//! then every registered builder (default and single-primitive leaves; default encoder), its SAH
//! compaction, the optimizers (with --optimizers, bounded passes) and every layout; prints the rays
//! on which each method differs from brute force (must be 0) and its time.
//!
//! `cargo run --release -p bvhlab-pipeline --example oracle_large -- [--rays N] [--optimizers] [SCENE...]`
//! (`just oracle-large`); scenes default to the shared conference, sponza, bunny and dragon.
#[path = "../tests/methods/mod.rs"]
mod methods;

use std::time::Instant;

fn main() {
    let mut rays_n = 100_000usize;
    let mut optimizers = false;
    let mut scenes = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--rays" => rays_n = args.next().and_then(|v| v.parse().ok()).expect("--rays N"),
            "--optimizers" => optimizers = true,
            _ => scenes.push(a),
        }
    }
    if scenes.is_empty() {
        scenes = ["conference", "sponza_dabrovic", "stanford_bunny", "stanford_dragon"]
            .iter()
            .map(|s| format!("../shared/scenes/{s}.obj.gz"))
            .collect();
    }
    let mut total_failures = 0usize;
    for spec in &scenes {
        let t = Instant::now();
        let scene = match bvhlab_geom::load_scene(spec) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("{spec}: {e}");
                total_failures += 1;
                continue;
            }
        };
        let b = scene.bounds();
        let radius = b.enclosing_radius(scene.triangles.iter().map(|t| t.bounds().center()));
        let rays = bvhlab_trace::random_rays(&b, radius, rays_n, 42);
        let load_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let want = bvhlab_trace::brute_force(&scene.triangles, &rays);
        let hits = want.iter().filter(|h| h.is_hit()).count();
        println!(
            "== {spec}: {} triangles ({} dropped), {} rays ({hits} hit), load {load_s:.1} s, brute force {:.1} s",
            scene.triangles.len(),
            scene.dropped_triangles,
            rays.len(),
            t.elapsed().as_secs_f64()
        );
        let input = methods::Input::new(&scene, &rays);
        let opts = methods::Opts {
            all_encoders: false,
            variants: false,
            optimizers,
            max_passes: 2,
            layouts: true,
            collapse: true,
            skip_builders: &[],
        };
        let mut last = Instant::now();
        let mut tally = methods::Tally::default();
        methods::run_all(&input, opts, &mut |label, o| {
            let secs = last.elapsed().as_secs_f64();
            let (diff, note) = match &o {
                methods::Outcome::Hits(h) => (
                    (0..want.len()).filter(|&i| !methods::same_hit(&h[i], &want[i])).count().to_string(),
                    String::new(),
                ),
                methods::Outcome::Refused(e) => ("-".into(), format!("refused: {e}")),
                methods::Outcome::Invalid(e) => ("INVALID".into(), e.clone()),
                methods::Outcome::Panic(e) => ("PANIC".into(), e.clone()),
            };
            println!("  {diff:>7} differences  {secs:7.2} s  {label} {note}");
            tally.add(spec, label, o, &want);
            last = Instant::now();
        });
        println!("  -> {}", tally.summary().lines().next().unwrap_or(""));
        total_failures += tally.failures.len();
    }
    if total_failures > 0 {
        eprintln!("{total_failures} failing methods");
        std::process::exit(1);
    }
}
