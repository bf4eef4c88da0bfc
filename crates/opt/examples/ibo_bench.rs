//! Times the insertion-based optimization against the sweep-SAH build it starts from.
//!
//! `cargo run --release -p bvhlab-opt --example ibo_bench -- SCENE [runs=3] [measure=comb]
//!  [start=sweep|median|binned] [pt=10] [pr=5] [frac=0.01] [keep_best=true] [max_passes=0] [seed=1]
//!  [trace=false] [chain=N]`
//!
//! Builds the start tree with leaf=1, then alternates build and ibo `runs` times (the machine is
//! noisy), reports medians, the costs before / after / after `collapse`, passes, stop reason, the
//! ratio ibo / build time, and the passes needed for 90% of the final reduction. `chain=N` runs ibo
//! N more times on its own output (different seeds) to look for lower costs.
use bvhlab_geom::stats::median;
use bvhlab_builders::TopDownConfig;
use bvhlab_bvh::{collapse::collapse, metrics, Bvh, CostParams};
use bvhlab_opt::ibo::{optimize, IboConfig, Measure};
use std::time::Instant;

/// Process CPU seconds (user + system, all threads) from /proc/self/stat: the machine is shared,
/// so wall time alone overstates both programs unevenly.
fn cpu_seconds() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let rest = s.rsplit(") ").next().unwrap_or("");
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    // Fields after the command: state is index 0, utime index 11, stime index 12; 100 ticks/s.
    (ticks(11) + ticks(12)) / 100.0
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let spec = args.first().expect("scene path or gen spec").clone();
    let get = |k: &str, d: &str| -> String {
        args.iter().skip(1).find_map(|a| a.strip_prefix(&format!("{k}=")).map(str::to_string)).unwrap_or(d.to_string())
    };
    let runs: usize = get("runs", "3").parse().unwrap();
    let cost = CostParams::default();
    let mut cfg = IboConfig::default();
    cfg.measure = Measure::parse(&get("measure", "comb")).expect("measure");
    cfg.pt = get("pt", "10").parse().unwrap();
    cfg.pr = get("pr", "5").parse().unwrap();
    cfg.frac = get("frac", "0.01").parse().unwrap();
    cfg.keep_best = get("keep_best", "true").parse().unwrap();
    cfg.max_passes = get("max_passes", "0").parse().unwrap();
    cfg.seed = get("seed", "1").parse().unwrap();
    let start = get("start", "sweep");
    let chain: u32 = get("chain", "0").parse().unwrap();
    let show_trace: bool = get("trace", "false").parse().unwrap();
    // chain: collapse before each further ibo run (ibo then moves the multi-primitive leaves).
    let chain_collapse: bool = get("chain_collapse", "false").parse().unwrap();
    // ... or only from this chain step on (1-based; 0 = never unless chain_collapse).
    let chain_collapse_from: u32 = get("chain_collapse_from", "0").parse().unwrap();
    let chain_pt: u32 = get("chain_pt", &cfg.pt.to_string()).parse().unwrap();
    let chain_measure = Measure::parse(&get("chain_measure", cfg.measure.as_str())).expect("chain_measure");

    let scene = bvhlab_geom::load_scene(&spec).expect("load");
    let (boxes, centers) = scene.boxes_and_centers();
    println!("scene {spec}: {} triangles", boxes.len());
    let tcfg = TopDownConfig { leaf: 1, cost };
    let build = || -> Bvh {
        match start.as_str() {
            "sweep" => bvhlab_builders::sweep_sah::build(&boxes, &centers, &tcfg),
            "median" => bvhlab_builders::spatial_median::build(&boxes, &centers, &tcfg),
            "binned" => bvhlab_builders::binned_sah::build(&boxes, &centers, 32, &tcfg),
            s => panic!("start {s}"),
        }
    };
    let (mut tb, mut to) = (Vec::new(), Vec::new());
    let (mut cb, mut co) = (Vec::new(), Vec::new());
    let mut last = None;
    for _ in 0..runs {
        let (t, c) = (Instant::now(), cpu_seconds());
        let bvh = build();
        tb.push(t.elapsed().as_secs_f64());
        cb.push(cpu_seconds() - c);
        let (t, c) = (Instant::now(), cpu_seconds());
        let o = optimize(&bvh, &cfg);
        to.push(t.elapsed().as_secs_f64());
        co.push(cpu_seconds() - c);
        if let Some((_, ref prev)) = last {
            let prev: &bvhlab_opt::Optimized = prev;
            assert_eq!(prev.bvh, o.bvh, "ibo is not deterministic");
        }
        last = Some((bvh, o));
    }
    let (bvh, o) = last.unwrap();
    let (mb, mo) = (median(&tb), median(&to));
    let (mcb, mco) = (median(&cb), median(&co));
    println!("cpu: build {mcb:.2}s ibo {mco:.2}s ratio {:.2}", mco / mcb.max(0.01));
    let c_before = metrics(&bvh, cost).sah_cost;
    let c_after = metrics(&o.bvh, cost).sah_cost;
    let c_coll = metrics(&collapse(&o.bvh, cost), cost).sah_cost;
    let c_coll0 = metrics(&collapse(&bvh, cost), cost).sah_cost;
    let passes = o.trace.len() - 1;
    let last_c = o.trace.last().unwrap().sah_cost;
    let target = c_before - 0.9 * (c_before - c_after);
    let p90 = o.trace.iter().find(|r| r.sah_cost <= target).map(|r| r.pass).unwrap_or(0);
    let moved: u64 = o.trace.iter().map(|r| r.moved).sum();
    println!(
        "wall: start {start} build {:.3}s  ibo {} {:.3}s  ratio {:.2}  passes {passes} (returned {}, stop {}, moved {moved}, 90% at pass {p90})",
        mb,
        cfg.measure.as_str(),
        mo,
        mo / mb,
        o.returned_pass,
        o.stop.as_str()
    );
    println!(
        "cost before {c_before:.4} (collapsed {c_coll0:.4})  after {c_after:.4} ({:+.2}%)  last pass {last_c:.4}  collapsed {c_coll:.4}  inner-SA ratio before {:.4} after {:.4}",
        100.0 * (c_after / c_before - 1.0),
        metrics(&bvh, cost).inner_sa_ratio,
        metrics(&o.bvh, cost).inner_sa_ratio
    );
    if show_trace {
        for r in &o.trace {
            println!("  pass {:4} {:8.3}s cost {:.4} moved {:6} {}", r.pass, r.seconds, r.sah_cost, r.moved, r.phase);
        }
    }
    let mut cur = o.bvh;
    // after=hc|sa: Kensler rotations on the ibo output (optionally collapsed first: after_collapse).
    let after = get("after", "");
    if !after.is_empty() {
        let mut kc = bvhlab_opt::kensler::KenslerConfig::default();
        kc.anneal = after == "sa";
        kc.max_seconds = get("after_seconds", "60").parse().unwrap();
        let input = if get("after_collapse", "false") == "true" { collapse(&cur, cost) } else { cur.clone() };
        let t = Instant::now();
        let k = bvhlab_opt::kensler::optimize(&input, &kc);
        println!(
            "after kensler-{after} ({}): {:.3}s passes {} cost {:.3} collapsed {:.3}",
            if input.nodes.len() == cur.nodes.len() { "leaf=1" } else { "collapsed" },
            t.elapsed().as_secs_f64(),
            k.trace.len() - 1,
            metrics(&k.bvh, cost).sah_cost,
            metrics(&collapse(&k.bvh, cost), cost).sah_cost
        );
    }
    for i in 0..chain {
        let mut c2 = cfg;
        c2.seed = cfg.seed + 1 + i as u64;
        c2.pt = chain_pt;
        c2.measure = chain_measure;
        if chain_collapse || (chain_collapse_from > 0 && i + 1 >= chain_collapse_from) {
            cur = collapse(&cur, cost);
        }
        let t = Instant::now();
        let o2 = optimize(&cur, &c2);
        let c = metrics(&o2.bvh, cost).sah_cost;
        println!(
            "chain {}: {:.3}s passes {} cost {c:.3} collapsed {:.3}",
            i + 1,
            t.elapsed().as_secs_f64(),
            o2.trace.len() - 1,
            metrics(&collapse(&o2.bvh, cost), cost).sah_cost
        );
        cur = o2.bvh;
    }
}
