//! Memory, accuracy and trace time of layouts against bvh2 (Kilian 2021 ch. 5-6):
//! `cargo run --release -p bvhlab-layout --example layout_bench -- [--leaf 2] [--rays 100000]
//!  [--rounds 5] [--threads 1] SCENE... SPEC...`
//!
//! SCENE is a path (.obj / .obj.gz) or `gen:...`; SPEC is `name` or `name:k=v,k=v` (e.g.
//! `qbvh_chunks:chunk_bytes=128,frame=parent`). Per scene: binned SAH (16 bins, leaf 2 by default), bvh2,
//! then per layout: topology and total bytes per triangle, topology bits per node, chunks, fill,
//! SAH with the layout's boxes against the exact SAH, and the median trace time of `--rays` random
//! rays (as in tests/common) alternated with bvh2 in every round, the slowdown (median layout /
//! median bvh2, by wall time and by the tracing thread's CPU time when on 1 thread), extra steps and
//! extra triangle tests per ray against bvh2, and hits differing from bvh2 (must be 0).
use bvhlab_geom::stats::median;
use bvhlab_builders::{binned_sah, TopDownConfig};
use bvhlab_bvh::CostParams;
use bvhlab_geom::load_scene;
use bvhlab_layout::{build, Layout, LayoutSpec};
use bvhlab_trace::{random_rays, Hit, Ray, TraceStats};
use std::collections::BTreeMap;
use std::time::Instant;

/// CPU time of the calling thread in seconds (Linux schedstat, ns resolution), if readable.
fn thread_cpu() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    Some(s.split_whitespace().next()?.parse::<f64>().ok()? * 1e-9)
}

pub fn parse_spec(s: &str) -> Result<LayoutSpec, String> {
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

/// (wall seconds, thread CPU seconds) of one trace.
fn timed(
    pool: &rayon::ThreadPool,
    f: impl Fn() -> TraceStats + Send + Sync,
) -> (f64, f64, TraceStats) {
    pool.install(|| {
        let c = thread_cpu().unwrap_or(f64::NAN);
        let t = Instant::now();
        let s = f();
        let w = t.elapsed().as_secs_f64();
        (w, thread_cpu().unwrap_or(f64::NAN) - c, s)
    })
}

fn main() {
    let mut leaf = 2u32;
    let mut n_rays = 100_000usize;
    let mut rounds = 5usize;
    let mut threads = 1usize;
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
            "--rounds" => rounds = num("--rounds"),
            "--threads" => threads = num("--threads"),
            s if s.starts_with("gen:") || s.contains(".obj") || s.contains('/') => {
                scenes.push(s.to_string())
            }
            s => specs.push(parse_spec(s).unwrap_or_else(|e| panic!("{e}"))),
        }
    }
    if scenes.is_empty() || specs.is_empty() {
        eprintln!("usage: layout_bench [--leaf 2] [--rays 100000] [--rounds 5] [--threads 1] SCENE... SPEC...");
        std::process::exit(2);
    }
    let mut b = rayon::ThreadPoolBuilder::new().num_threads(threads);
    if threads == 1 {
        b = b.use_current_thread();
    }
    let pool = b.build().expect("thread pool");
    let cost = CostParams::default();
    println!("# leaf={leaf} rays={n_rays} rounds={rounds} threads={threads}; times: median ms over rounds, layout and bvh2 alternated");
    println!(
        "{:<24} {:<38} {:>8} {:>8} {:>7} {:>7} {:>6} {:>8} {:>8} {:>8} {:>8} {:>7} {:>7} {:>7} {:>7} {:>5}",
        "scene", "layout", "topo/tri", "tot/tri", "bits/n", "chunks", "fill", "sah", "sah_ex", "ms", "bvh2_ms",
        "slow", "slowcpu", "+steps", "+tests", "diff"
    );
    for path in &scenes {
        let t0 = Instant::now();
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
        let bounds = scene.bounds();
        let radius = bounds.enclosing_radius(centers.iter().copied());
        let rays: Vec<Ray> = random_rays(&bounds, radius, n_rays, 42);
        let name = std::path::Path::new(path)
            .file_name()
            .map(|s| {
                s.to_string_lossy()
                    .replace(".obj.gz", "")
                    .replace(".obj", "")
            })
            .unwrap_or_else(|| path.clone());
        let bvh2 = build(&parse_spec("bvh2").unwrap(), &bvh, tris).unwrap();
        let exact_sah = bvh2.sah_cost(cost);
        let nt = tris.len().max(1) as f64;
        let m2 = bvh2.memory();
        eprintln!(
            "{name}: {} tris, {} nodes, loaded+built in {:.1} s",
            tris.len(),
            bvh.nodes.len(),
            t0.elapsed().as_secs_f64()
        );
        println!(
            "{:<24} {:<38} {:>8.2} {:>8.2} {:>7.1} {:>7} {:>6} {:>8.2} {:>8.2}",
            name,
            "bvh2",
            m2.topology_bytes as f64 / nt,
            m2.total_bytes as f64 / nt,
            m2.topology_bits_per_node(),
            0,
            "-",
            exact_sah,
            exact_sah
        );
        for spec in &specs {
            let tb = Instant::now();
            let l: Layout = build(spec, &bvh, tris).unwrap_or_else(|e| panic!("{e}"));
            let build_s = tb.elapsed().as_secs_f64();
            let m = l.memory();
            let sah = l.sah_cost(cost);
            let (mut wl, mut w2, mut cl, mut c2) = (vec![], vec![], vec![], vec![]);
            let mut stats: Option<(TraceStats, TraceStats)> = None;
            for _ in 0..rounds {
                let (w, c, sl) = timed(&pool, || l.trace(tris, &rays));
                wl.push(w);
                cl.push(c);
                let (w, c, s2) = timed(&pool, || bvh2.trace(tris, &rays));
                w2.push(w);
                c2.push(c);
                stats.get_or_insert((sl, s2));
            }
            let (sl, s2) = stats.unwrap();
            let same = |a: &Hit, b: &Hit| {
                a.prim == b.prim
                    || (a.is_hit() && b.is_hit() && (a.t - b.t).abs() <= 1e-6 * b.t.abs())
            };
            let diff = sl
                .hits
                .iter()
                .zip(&s2.hits)
                .filter(|(a, b)| !same(a, b))
                .count();
            let per_ray = |a: u64, b: u64| (a as f64 - b as f64) / rays.len().max(1) as f64;
            let (ml, m2w) = (median(&wl), median(&w2));
            let slow_cpu = median(&cl) / median(&c2);
            let label = format!("{}:{}", spec.name, spec.params_string());
            println!(
                "{:<24} {:<38} {:>8.2} {:>8.2} {:>7.1} {:>7} {:>6.3} {:>8.2} {:>8.2} {:>8.1} {:>8.1} {:>7.3} {:>7.3} {:>7.2} {:>7.2} {:>5}",
                name,
                label,
                m.topology_bytes as f64 / nt,
                m.total_bytes as f64 / nt,
                m.topology_bits_per_node(),
                m.chunks,
                m.chunk_fill,
                sah,
                exact_sah,
                ml * 1e3,
                m2w * 1e3,
                ml / m2w,
                slow_cpu,
                per_ray(sl.total_steps, s2.total_steps),
                per_ray(sl.total_intersections, s2.total_intersections),
                diff
            );
            eprintln!(
                "  {label}: built in {build_s:.2} s, topology/bvh2 nodes = {:.3}",
                m.topology_bytes as f64 / m2.topology_bytes as f64
            );
        }
    }
}
