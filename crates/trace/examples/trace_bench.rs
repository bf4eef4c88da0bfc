//! Trace throughput and counters on one scene:
//! `cargo run --release -p bvhlab-trace --example trace_bench -- SCENE [runs=5] [rays=640000] [heatmap.png]`
//! SCENE is a path (.obj / .obj.gz) or `gen:...`. Builds binned SAH (16 bins, leaf 2, c_T = 3,
//! c_I = 2; thesis 4.4 settings), then traces primary rays (800 x 800 by default, the thesis's
//! image size), their shadow rays and random rays (thesis 4.4), each `runs` times on 1 thread and
//! on all threads. One JSON line per ray set: median Mrays/s, mean steps and tests per ray, hit
//! rate. With a PNG path, also writes the primary-ray traversal-step heat map (Bittner 2013 fig. 1).
use bvhlab_builders::{binned_sah, TopDownConfig};
use bvhlab_bvh::Bvh;
use bvhlab_geom::stats::median;
use bvhlab_geom::Triangle;
use bvhlab_trace::{heatmap, primary_rays, random_rays, shadow_rays, trace, Camera, Ray};
use std::time::Instant;

/// Process CPU time (user + system) in seconds from /proc/self/stat (Linux), if readable. On a
/// shared, oversubscribed machine wall time inflates; CPU time of a 1-thread run does not.
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0) // USER_HZ is 100 on Linux
}

/// Mrays/s over `runs`: median by wall time, and mean by process CPU time (meaningful for 1 thread).
fn bench(
    bvh: &Bvh,
    tris: &[Triangle],
    rays: &[Ray],
    runs: usize,
    threads: usize,
) -> (f64, Option<f64>) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool");
    let mut wall = Vec::with_capacity(runs);
    let mut cpu = Vec::with_capacity(runs);
    for _ in 0..runs {
        let c = cpu_seconds();
        let t = Instant::now();
        let s = pool.install(|| trace(bvh, tris, rays));
        std::hint::black_box(&s);
        wall.push(t.elapsed().as_secs_f64());
        if let (Some(a), Some(b)) = (c, cpu_seconds()) {
            cpu.push(b - a);
        }
    }
    let mr = |t: f64| rays.len() as f64 / t / 1e6;
    // Summed, not median: /proc ticks are 10 ms, too coarse for one run.
    let cpu_total: f64 = cpu.iter().sum();
    let cpu = if cpu.len() == runs && cpu_total > 0.0 {
        Some(mr(cpu_total / runs as f64))
    } else {
        None
    };
    (mr(median(&wall)), cpu)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let Some(spec) = args.get(1) else {
        eprintln!("usage: trace_bench SCENE [runs=5] [rays=640000] [heatmap.png]");
        std::process::exit(2);
    };
    let num = |i: usize, d: usize| match args.get(i).map(|s| s.parse::<usize>()) {
        None => d,
        Some(Ok(v)) if v > 0 => v,
        Some(_) => {
            eprintln!("argument {i} must be a positive integer");
            std::process::exit(2);
        }
    };
    let runs = num(2, 5);
    let n_rays = num(3, 640_000);
    let scene = match bvhlab_geom::load_scene(spec) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    };
    let tris = &scene.triangles;
    let (boxes, centers) = scene.boxes_and_centers();
    let t = Instant::now();
    let bvh = binned_sah::build(&boxes, &centers, 16, &TopDownConfig::default());
    let build_ms = t.elapsed().as_secs_f64() * 1e3;
    let bounds = scene.bounds();
    let cam = Camera::from_bounds(&bounds);
    let side = (n_rays as f64).sqrt().round().max(1.0) as u32;
    let primary = primary_rays(&cam, side, side);
    let first = trace(&bvh, tris, &primary);
    let hit_t: Vec<f32> = first.hits.iter().map(|h| h.t).collect();
    let shadow = shadow_rays(&primary, &hit_t, cam.light(&bounds));
    let radius = bounds.enclosing_radius(centers.iter().copied());
    let random = random_rays(&bounds, radius, n_rays, 1);
    let threads = rayon::current_num_threads();
    println!(
        "{{\"scene\":\"{spec}\",\"triangles\":{},\"nodes\":{},\"build_ms\":{build_ms:.1},\"threads\":{threads}}}",
        tris.len(),
        bvh.nodes.len()
    );
    for (name, rays) in [
        ("primary", &primary),
        ("shadow", &shadow),
        ("random", &random),
    ] {
        let s = trace(&bvh, tris, rays);
        let n = rays.len().max(1) as f64;
        let (m1, m1_cpu) = bench(&bvh, tris, rays, runs, 1);
        let (mn, _) = bench(&bvh, tris, rays, runs, threads);
        let m1_cpu = m1_cpu.map_or("null".to_string(), |v| format!("{v:.3}"));
        println!(
            "{{\"rays\":\"{name}\",\"count\":{},\"mrays_per_s_1thread\":{m1:.3},\"mrays_per_s_1thread_cpu\":{m1_cpu},\"mrays_per_s\":{mn:.3},\"steps_per_ray\":{:.2},\"tests_per_ray\":{:.2},\"hit_rate\":{:.4}}}",
            rays.len(),
            s.total_steps as f64 / n,
            s.total_intersections as f64 / n,
            s.hit_count as f64 / n
        );
    }
    if let Some(path) = args.get(4) {
        let rgb = heatmap::heatmap_rgb(&first.steps, side, side);
        let written = rgb.and_then(|rgb| {
            image::save_buffer(path, &rgb, side, side, image::ColorType::Rgb8)
                .map_err(|e| format!("{path}: {e}"))
        });
        if let Err(e) = written {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
}
