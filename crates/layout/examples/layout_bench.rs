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
mod common;
use common::{same_hit, Setup};
use bvhlab_geom::stats::median;
use bvhlab_bvh::CostParams;
use bvhlab_layout::{build, Layout, LayoutSpec};
use bvhlab_trace::TraceStats;
use std::time::Instant;

/// CPU time of the calling thread in seconds (Linux schedstat, ns resolution), if readable.
fn thread_cpu() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    Some(s.split_whitespace().next()?.parse::<f64>().ok()? * 1e-9)
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

/// Memory, accuracy and trace time of layouts against bvh2.
#[derive(clap::Parser)]
struct Args {
    #[arg(long, default_value_t = 2)]
    leaf: u32,
    #[command(flatten)]
    run: common::RunArgs,
    /// Scenes (a path or `gen:...`), then layouts (`name` or `name:k=v,...`).
    #[arg(required = true, num_args = 2..)]
    items: Vec<String>,
}

fn main() {
    let a = <Args as clap::Parser>::parse();
    let (leaf, n_rays, rounds, threads) = (a.leaf, a.run.rays, a.run.rounds, a.run.threads);
    let (scenes, specs) = common::scenes_and_layouts(&a.items);
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
        let Setup { name, scene, bvh, rays } = Setup::new(path, leaf, n_rays, 42);
        let tris = &scene.triangles;
        let bvh2 = build(&LayoutSpec::from_spec("bvh2").unwrap(), &bvh, tris).unwrap();
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
            let diff = sl
                .hits
                .iter()
                .zip(&s2.hits)
                .filter(|(a, b)| !same_hit(a, b))
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
