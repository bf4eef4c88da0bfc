//! Times the incremental builder (Bittner 2015; thesis 3.5.1) and Kensler's rotations (hill
//! climbing, simulated annealing) on a sweep-SAH leaf=1 tree.
//!
//! `cargo run --release -p bvhlab-opt --example inc_bench -- SCENE [runs=3] [batch=8000]
//!  [ofrac=0.01] [coh=1.5] [order=input|shuffle|morton|reverse] [kensler=none|hc|sa|both]
//!  [sa_seconds=60] [sa_passes=100] [t0=0.01] [cooling=0.9] [inc=true] [tscale=root|node] [changed_only=false]
//!  [k_of_tree=false] [final_pass=false] [batch_of_insertions=false]`
//!
//! Incremental: median build time of `runs` builds, the SAH cost of the raw tree (one primitive
//! per leaf) and after SAH compaction (`collapse`, c_T=3, c_I=2, thesis table 10's number), and
//! the build counters. `order` permutes the input before inserting (to measure how much the
//! result depends on the file's order). Kensler: sweep-SAH leaf=1 build, then hill climbing
//! (`runs` times, median) and/or one annealing run capped by `sa_seconds`.
use bvhlab_geom::stats::median;
use bvhlab_builders::TopDownConfig;
use bvhlab_bvh::{collapse::collapse, metrics, Aabb, Bvh, CostParams};
use bvhlab_builders::incremental::{build_variant, IncConfig, Variant};
use bvhlab_opt::kensler::{optimize, optimize_scaled, KenslerConfig, TempScale};
use bvhlab_opt::SplitMix64;
use std::time::Instant;

fn morton3(c: [f32; 3], lo: [f32; 3], ext: [f32; 3]) -> u64 {
    let mut code = 0u64;
    let q: Vec<u64> = (0..3)
        .map(|a| {
            if ext[a] > 0.0 {
                (((c[a] - lo[a]) / ext[a]) * 1023.999).max(0.0) as u64
            } else {
                0
            }
        })
        .collect();
    for bit in (0..10).rev() {
        for a in 0..3 {
            code = (code << 1) | ((q[a] >> bit) & 1);
        }
    }
    code
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let spec = args.first().expect("scene path or gen spec").clone();
    let get = |k: &str, d: &str| -> String {
        args.iter()
            .skip(1)
            .find_map(|a| a.strip_prefix(&format!("{k}=")).map(str::to_string))
            .unwrap_or(d.to_string())
    };
    let runs: usize = get("runs", "3").parse().unwrap();
    let cost = CostParams::default();
    let icfg = IncConfig {
        batch: get("batch", "8000").parse().unwrap(),
        ofrac: get("ofrac", "0.01").parse().unwrap(),
        coh: get("coh", "1.5").parse().unwrap(),
        cost,
    };
    let order = get("order", "input");
    let kensler = get("kensler", "none");
    let do_inc: bool = get("inc", "true").parse().unwrap();
    let var = Variant {
        changed_only: get("changed_only", "false").parse().unwrap(),
        k_of_tree: get("k_of_tree", "false").parse().unwrap(),
        final_pass: get("final_pass", "false").parse().unwrap(),
        batch_of_insertions: get("batch_of_insertions", "false").parse().unwrap(),
    };

    let scene = bvhlab_geom::load_scene(&spec).expect("load");
    let (boxes, centers) = scene.boxes_and_centers();
    println!("scene {spec}: {} triangles", boxes.len());

    if do_inc {
        let mut perm: Vec<usize> = (0..boxes.len()).collect();
        match order.as_str() {
            "input" => {}
            "reverse" => perm.reverse(),
            "shuffle" => {
                let mut rng = SplitMix64::new(12345);
                for i in (1..perm.len()).rev() {
                    perm.swap(i, rng.below(i as u64 + 1) as usize);
                }
            }
            "morton" => {
                let b = scene.bounds();
                let (lo, ext) = (b.min.to_array(), (b.max - b.min).to_array());
                let codes: Vec<u64> = centers
                    .iter()
                    .map(|c| morton3(c.to_array(), lo, ext))
                    .collect();
                perm.sort_by_key(|&i| (codes[i], i));
            }
            o => panic!("order {o}"),
        }
        let ordered: Vec<Aabb> = perm.iter().map(|&i| boxes[i]).collect();
        let mut times = Vec::new();
        let mut last: Option<(Bvh, _)> = None;
        for _ in 0..runs {
            let t = Instant::now();
            let r = build_variant(&ordered, &icfg, var);
            times.push(t.elapsed().as_secs_f64());
            last = Some(r);
        }
        let (bvh, stats) = last.unwrap();
        let raw = metrics(&bvh, cost).sah_cost;
        let t = Instant::now();
        let col = collapse(&bvh, cost);
        let tc = t.elapsed().as_secs_f64();
        let m = metrics(&col, cost);
        println!(
            "incremental order={order} batch={} ofrac={} coh={} {var:?}: build {:.3} s (median of {runs}), collapse {:.3} s, \
             cost raw {raw:.2}, collapsed {:.2}",
            icfg.batch,
            icfg.ofrac,
            icfg.coh,
            median(&times),
            tc,
            metrics(&col, cost).sah_cost
        );
        println!(
            "  clusters {} passes {} updated {} moved {} search visits/insert {:.1}",
            stats.clusters,
            stats.passes,
            stats.updated,
            stats.moved,
            stats.visited as f64 / (boxes.len() as f64 - stats.clusters as f64).max(1.0)
        );
        println!(
            "  collapsed: inner SA ratio {:.1} (thesis table 18), leaf SA ratio {:.1} (table 19), refs/leaf {:.2} \
             (table 17), depth {}",
            m.inner_sa_ratio, m.leaf_sa_ratio, m.refs_per_leaf, m.depth
        );
    }

    if kensler != "none" {
        let t = Instant::now();
        let sweep =
            bvhlab_builders::sweep_sah::build(&boxes, &centers, &TopDownConfig { leaf: 1, cost });
        let tb = t.elapsed().as_secs_f64();
        let c0 = metrics(&sweep, cost).sah_cost;
        let o0 = metrics(&collapse(&sweep, cost), cost).sah_cost;
        println!("sweep-sah leaf=1: build {tb:.3} s, cost {c0:.2}, collapsed {o0:.2}");
        if kensler == "hc" || kensler == "both" {
            let cfg = KenslerConfig {
                cost,
                ..KenslerConfig::default()
            };
            let mut times = Vec::new();
            let mut last = None;
            for _ in 0..runs {
                let t = Instant::now();
                let r = optimize(&sweep, &cfg);
                times.push(t.elapsed().as_secs_f64());
                last = Some(r);
            }
            let r = last.unwrap();
            let c = metrics(&r.bvh, cost).sah_cost;
            let o = metrics(&collapse(&r.bvh, cost), cost).sah_cost;
            println!(
                "kensler-hc: {:.3} s (median of {runs}), {} passes, stop {}, cost {c:.2}, collapsed {o:.2}, rotations {}",
                median(&times),
                r.trace.len() - 1,
                r.stop.as_str(),
                r.trace.iter().map(|p| p.moved).sum::<u64>()
            );
        }
        if kensler == "sa" || kensler == "both" {
            let cfg = KenslerConfig {
                anneal: true,
                t0: get("t0", "0.01").parse().unwrap(),
                cooling: get("cooling", "0.9").parse().unwrap(),
                max_passes: get("sa_passes", "100").parse().unwrap(),
                max_seconds: get("sa_seconds", "60").parse().unwrap(),
                cost,
                ..KenslerConfig::default()
            };
            let scale = if get("tscale", "root") == "node" {
                TempScale::Node
            } else {
                TempScale::Root
            };
            let t = Instant::now();
            let r = optimize_scaled(&sweep, &cfg, scale);
            let ts = t.elapsed().as_secs_f64();
            let c = metrics(&r.bvh, cost).sah_cost;
            let o = metrics(&collapse(&r.bvh, cost), cost).sah_cost;
            let last = r.trace.last().unwrap();
            println!(
                "kensler-sa t0={} cooling={} {scale:?}: {ts:.2} s, {} passes, stop {}, returned pass {}, cost {c:.2}, collapsed \
                 {o:.2} (last pass cost {:.2})",
                cfg.t0,
                cfg.cooling,
                r.trace.len() - 1,
                r.stop.as_str(),
                r.returned_pass,
                last.sah_cost
            );
            let t = Instant::now();
            let q = optimize(
                &r.bvh,
                &KenslerConfig {
                    cost,
                    ..KenslerConfig::default()
                },
            );
            println!(
                "  + hill climbing on the annealed tree: {:.2} s, {} passes, cost {:.2}, collapsed {:.2}",
                t.elapsed().as_secs_f64(),
                q.trace.len() - 1,
                metrics(&q.bvh, cost).sah_cost,
                metrics(&collapse(&q.bvh, cost), cost).sah_cost
            );
            for p in r.trace.iter().step_by((r.trace.len() / 10).max(1)) {
                println!(
                    "    pass {:4} {:8.2} s cost {:9.3} moved {}",
                    p.pass, p.seconds, p.sah_cost, p.moved
                );
            }
        }
    }
}
