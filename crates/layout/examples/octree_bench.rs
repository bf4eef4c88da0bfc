//! Octree layouts (Kilian 2021 ch. 4 and 6) against a binned-SAH bvh2, in one run:
//! `cargo run --release -p bvhlab-layout --example octree_bench -- [--rays 100000] [--rounds 5]
//!  [--threads 1] [--sweep] [--kv k=v,...] SCENE...`
//!
//! Default mode, per scene: octree nodes, leaves, primitive multiplication factor (references /
//! triangles, Kilian fig. 6.5), build time; per chunk size 16/32/64/128 and fill bfs/dense: chunks,
//! fill, topology bits per node; then the median (over `--rounds` alternated rounds) trace time of
//! `--rays` random rays with bvh2 (binned SAH, 16 bins, leaf 2), octree, octree_1bit 16 B bfs and dense
//! (and `--all-chunks`: every chunk size), steps and tests per ray, hits differing from bvh2
//! (must be 0).
//! `--sweep`: Kilian 4.1.4: mult_threshold 1.3..2.4 (prim_threshold 20) and prim_threshold 5..35
//! (mult 2.0): nodes, references, octree and octree_1bit (16 B bfs) topology bytes, trace time.
mod common;
use common::{same_hit, Setup};
use bvhlab_geom::stats::median;
use bvhlab_layout::octree::{self, Octree};
use bvhlab_layout::octree_1bit::{self, Fill, Octree1Bit};
use bvhlab_layout::{bvh2::Bvh2, Memory};
use bvhlab_trace::{Ray, TraceStats};
use std::time::Instant;

type Tracer<'a> = (String, Box<dyn Fn(&[Ray]) -> TraceStats + Sync + 'a>);

/// Median wall seconds of each tracer over `rounds` rounds, tracers alternated inside a round;
/// plus the stats of the last run of each.
fn race(
    pool: &rayon::ThreadPool,
    ts: &[Tracer],
    rays: &[Ray],
    rounds: usize,
) -> Vec<(f64, TraceStats)> {
    let mut times = vec![Vec::new(); ts.len()];
    let mut last: Vec<Option<TraceStats>> = vec![None; ts.len()];
    for r in 0..rounds {
        for i in 0..ts.len() {
            // Rotate the order every round so no variant always runs first after a cold cache.
            let j = (i + r) % ts.len();
            let t = Instant::now();
            let s = pool.install(|| (ts[j].1)(rays));
            times[j].push(t.elapsed().as_secs_f64());
            last[j] = Some(s);
        }
    }
    times
        .into_iter()
        .zip(last)
        .map(|(t, s)| (median(&t), s.unwrap()))
        .collect()
}

fn octree_cfg(kv: &[(String, String)]) -> octree::Config {
    let mut c = octree::Config::default();
    for (k, v) in kv {
        match k.as_str() {
            "prim_threshold" => c.prim_threshold = v.parse().unwrap(),
            "mult_threshold" => c.mult_threshold = v.parse().unwrap(),
            "max_depth" => c.max_depth = v.parse().unwrap(),
            "overlap" => {
                c.overlap = match v.as_str() {
                    "aabb" => octree::Overlap::Aabb,
                    _ => octree::Overlap::Sat,
                }
            }
            _ => panic!("unknown octree parameter {k}"),
        }
    }
    c
}

/// Octree layouts against a binned-SAH bvh2.
#[derive(clap::Parser)]
struct Args {
    #[command(flatten)]
    run: common::RunArgs,
    /// Kilian 4.1.4's threshold sweep instead of the default comparison.
    #[arg(long)]
    sweep: bool,
    /// Every chunk size of octree_1bit, not only 16 B.
    #[arg(long)]
    all_chunks: bool,
    /// Octree parameters `k=v,...` (prim_threshold, mult_threshold, max_depth, overlap).
    #[arg(long, value_delimiter = ',')]
    kv: Vec<String>,
    #[arg(required = true)]
    scenes: Vec<String>,
}

fn main() {
    let a = <Args as clap::Parser>::parse();
    let (n_rays, rounds, threads, sweep, all_chunks, scenes) = (a.run.rays, a.run.rounds, a.run.threads, a.sweep, a.all_chunks, a.scenes);
    let kv: Vec<(String, String)> = a.kv.iter().map(|p| {
        let (k, v) = p.split_once('=').expect("--kv takes k=v,...");
        (k.to_string(), v.to_string())
    }).collect();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let base = octree_cfg(&kv);
    println!(
        "# octree_bench rays={n_rays} rounds={rounds} threads={threads} octree={base:?} (times: median wall ms)"
    );
    for spec in &scenes {
        let Setup { name, scene, bvh, rays } = Setup::new(spec, 2, n_rays, 42);
        let (name, tris) = (name.as_str(), &scene.triangles);
        let bvh2 = Bvh2::build(&bvh);
        if sweep {
            run_sweep(&pool, name, tris, &bvh2, &rays, rounds);
            continue;
        }
        let t = Instant::now();
        let o = pool.install(|| Octree::build(tris, &base)).unwrap();
        let build_s = t.elapsed().as_secs_f64();
        o.validate(tris).unwrap();
        let m = o.memory();
        let leaves = o.leaves();
        let empty = (0..o.nodes.len())
            .filter(|&n| o.nodes[n] & 1 == 0 && o.sizes[n] == 0)
            .count();
        println!(
            "\n## {name}: {} tris, octree nodes {} leaves {} (empty {}) refs {} mult {:.2} build {:.2} s; topology {:.2} B/tri, total {:.2} B/tri; bvh2 nodes {} topology {:.2} B/tri",
            tris.len(),
            m.nodes,
            leaves,
            empty,
            m.prim_refs,
            m.prim_refs as f64 / tris.len() as f64,
            build_s,
            m.topology_bytes as f64 / tris.len() as f64,
            m.total_bytes as f64 / tris.len() as f64,
            bvh.nodes.len(),
            bvh2.memory().topology_bytes as f64 / tris.len() as f64,
        );
        println!("chunk fill   chunks    fill%  bits/node  topoB/tri  totalB/tri");
        let mut ones = Vec::new();
        for cb in [16u32, 32, 64, 128] {
            for fill in [Fill::Bfs, Fill::Dense] {
                let cfg = octree_1bit::Config {
                    base: base.clone(),
                    chunk_bytes: cb,
                    fill,
                };
                let l = Octree1Bit::from_octree(&o, &cfg).unwrap();
                l.validate(tris).unwrap();
                let mm: Memory = l.memory();
                println!(
                    "{cb:5} {:5} {:8} {:8.1} {:10.3} {:10.3} {:11.3}",
                    if fill == Fill::Bfs { "bfs" } else { "dense" },
                    mm.chunks,
                    100.0 * mm.chunk_fill,
                    mm.topology_bits_per_node(),
                    mm.topology_bytes as f64 / tris.len() as f64,
                    mm.total_bytes as f64 / tris.len() as f64
                );
                if cb == 16 || all_chunks {
                    ones.push((format!("octree_1bit-{cb}-{fill:?}"), l));
                }
            }
        }
        let mut ts: Vec<Tracer> = vec![
            ("bvh2".into(), Box::new(|r: &[Ray]| bvh2.trace(tris, r))),
            ("octree".into(), Box::new(|r: &[Ray]| o.trace(tris, r))),
        ];
        for (n, l) in &ones {
            ts.push((n.clone(), Box::new(move |r: &[Ray]| l.trace(tris, r))));
        }
        let res = race(&pool, &ts, &rays, rounds);
        let (t_bvh, ref_stats) = (&res[0].0, &res[0].1);
        let t_oct = res[1].0;
        println!("variant            ms   x_bvh2  x_octree  steps/ray  tests/ray  diff_hits");
        for ((n, _), (t, s)) in ts.iter().zip(&res) {
            let diff = s
                .hits
                .iter()
                .zip(&ref_stats.hits)
                .filter(|(g, w)| !same_hit(g, w))
                .count();
            println!(
                "{n:16} {:7.1} {:7.2} {:8.3} {:10.2} {:10.2} {:9}",
                t * 1e3,
                t / t_bvh,
                t / t_oct,
                s.total_steps as f64 / rays.len() as f64,
                s.total_intersections as f64 / rays.len() as f64,
                diff
            );
        }
    }
}

fn run_sweep(
    pool: &rayon::ThreadPool,
    name: &str,
    tris: &[bvhlab_geom::Triangle],
    bvh2: &Bvh2,
    rays: &[Ray],
    rounds: usize,
) {
    let mut cfgs = Vec::new();
    for i in 0..12 {
        let m = 1.3 + 0.1 * i as f64;
        cfgs.push(octree::Config {
            mult_threshold: (m * 10.0).round() / 10.0,
            ..Default::default()
        });
    }
    for p in [5u32, 10, 15, 20, 25, 30, 35] {
        cfgs.push(octree::Config {
            prim_threshold: p,
            ..Default::default()
        });
    }
    println!("\n## sweep {name}: {} tris", tris.len());
    println!("pt  mult  nodes     refs      mult_f  octreeKB  octree_1bit_16KB  bvh2_ms  octree_ms  octree_1bit_ms  steps/ray  tests/ray");
    for cfg in cfgs {
        let o = pool.install(|| Octree::build(tris, &cfg)).unwrap();
        let l = Octree1Bit::from_octree(
            &o,
            &octree_1bit::Config {
                base: cfg.clone(),
                chunk_bytes: 16,
                fill: Fill::Bfs,
            },
        )
        .unwrap();
        let ts: Vec<Tracer> = vec![
            ("bvh2".into(), Box::new(|r: &[Ray]| bvh2.trace(tris, r))),
            ("octree".into(), Box::new(|r: &[Ray]| o.trace(tris, r))),
            ("octree_1bit".into(), Box::new(|r: &[Ray]| l.trace(tris, r))),
        ];
        let res = race(pool, &ts, rays, rounds);
        let (m, m1) = (o.memory(), l.memory());
        let s = &res[1].1;
        println!(
            "{:2} {:5.1} {:8} {:9} {:7.2} {:9.1} {:13.1} {:8.1} {:10.1} {:11.1} {:10.2} {:10.2}",
            cfg.prim_threshold,
            cfg.mult_threshold,
            m.nodes,
            m.prim_refs,
            m.prim_refs as f64 / tris.len() as f64,
            m.topology_bytes as f64 / 1024.0,
            m1.topology_bytes as f64 / 1024.0,
            res[0].0 * 1e3,
            res[1].0 * 1e3,
            res[2].0 * 1e3,
            s.total_steps as f64 / rays.len() as f64,
            s.total_intersections as f64 / rays.len() as f64,
        );
    }
}
