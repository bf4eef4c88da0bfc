//! Searches chains of registry builders and optimizers for low final SAH cost (issue 4, "beyond
//! the anchors": conference below 78).
//!
//! `cargo run --release -p bvhlab-pipeline --example chase78 -- SCENE CHAIN [CHAIN...]`
//!
//! A CHAIN is stages separated by `/`: first the builder `NAME[,k=v...]` (builder, encoder and
//! cost parameters; `encode=NAME` picks the encoder of a code builder), then any of
//! `ibo[,k=v...]`, `kensler-hc[,k=v...]`, `kensler-sa[,k=v...]`, `collapse`. The builder's RAW
//! tree is used (the registry's `construct` would collapse lbvh/aac/ploc before the optimizer);
//! write `collapse` as the second stage to start from the tree the pipeline optimizes.
//! Prints the cost after each stage and one summary line per chain; the final tree is always
//! collapsed (`bvhlab_bvh::collapse`) and validated. Any stage takes `c_t=` / `c_i=` to run with
//! other cost constants than the chain's (an experiment; costs are reported with the chain's).
//!
//! Conference (c_T=3, c_I=2), measured 2026-11-21: best `sweep-sah/ibo,pt=100,ibo_frac=0.05,
//! measure=area,seed=3/kensler-hc/collapse` = 78.2824 (same at 1 thread; seeds 1..6: 78.28-78.40).
//! The start tree's leaf=2 pairs matter most: the same chain from sweep-sah leaf=1 ends at 79.26,
//! and from the raw ploc/aac/lbvh/incremental trees at 79.0-80.1. Below 78 was not reached.
use bvhlab_bvh::{collapse::collapse, metrics, validate_refs, Bvh, CostParams};
use bvhlab_pipeline::registry::Registry;
use std::collections::BTreeMap;
use std::time::Instant;

fn parse_stage(s: &str) -> (String, BTreeMap<String, String>) {
    let mut it = s.split(',');
    let name = it.next().unwrap_or("").to_string();
    let mut raw = BTreeMap::new();
    for kv in it {
        let (k, v) = kv
            .split_once('=')
            .unwrap_or_else(|| panic!("bad parameter `{kv}` in `{s}`"));
        raw.insert(k.to_string(), v.to_string());
    }
    (name, raw)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let spec = args.first().expect("scene path or gen spec").clone();
    let cost = CostParams::default();
    let scene = bvhlab_geom::load_scene(&spec).expect("load");
    let (boxes, centers) = scene.boxes_and_centers();
    println!("scene {spec}: {} triangles", boxes.len());
    let reg = Registry::standard();
    for chain in &args[1..] {
        let t_chain = Instant::now();
        let stages: Vec<&str> = chain.split('/').collect();
        let (builder, mut braw) = parse_stage(stages[0]);
        let encode = braw.remove("encode");
        let ch = match reg.resolve_chain(&builder, encode.as_deref(), None, &braw, cost) {
            Ok(c) => c,
            Err(e) => {
                println!("{chain}: error {e}");
                continue;
            }
        };
        let t = Instant::now();
        let info = reg.get(&builder).expect("builder");
        let enc = ch
            .encoder
            .as_ref()
            .map(|e| bvhlab_morton::encode_cells(&boxes, &centers, &e.config, e.cell_frame));
        let codes = enc.as_ref().map(|e| bvhlab_builders::SortedCodes {
            order: &e.order,
            codes: &e.codes,
            code_bits: e.code_bits,
        });
        let mut bvh: Bvh = match info.triangles {
            Some(run) => run(&scene.triangles, &ch.build),
            None => (info.run)(&boxes, &centers, codes.as_ref(), &ch.build),
        };
        let build_cost = metrics(&bvh, ch.build.cost).sah_cost;
        println!(
            "  {chain} | build {builder}: {build_cost:.3} ({:.1}s)",
            t.elapsed().as_secs_f64()
        );
        let mut costs = vec![format!("{build_cost:.3}")];
        for st in &stages[1..] {
            let t = Instant::now();
            let (name, mut raw) = parse_stage(st);
            // EXPERIMENT (not in the papers): a stage may run with its own c_t / c_i (the final
            // collapse and all reported costs keep the chain's constants).
            let mut sc = ch.build.cost;
            if let Some(v) = raw.remove("c_t") {
                sc.c_t = v.parse().expect("c_t");
            }
            if let Some(v) = raw.remove("c_i") {
                sc.c_i = v.parse().expect("c_i");
            }
            if name == "collapse" {
                bvh = collapse(&bvh, sc);
            } else {
                let r = match reg.resolve_optimizer(&name, &raw, sc) {
                    Ok(r) => r,
                    Err(e) => {
                        println!("{chain}: error {e}");
                        break;
                    }
                };
                let o = (reg.optimizer(&name).expect("optimizer").run)(&bvh, &r);
                println!(
                    "    {st}: passes {} returned {} stop {:?}",
                    o.trace.len(),
                    o.returned_pass,
                    o.stop
                );
                bvh = o.bvh;
            }
            let c = metrics(&bvh, ch.build.cost).sah_cost;
            println!(
                "  {chain} | {st}: {c:.3} ({:.1}s)",
                t.elapsed().as_secs_f64()
            );
            costs.push(format!("{c:.3}"));
        }
        let fin = collapse(&bvh, ch.build.cost);
        let fc = metrics(&fin, ch.build.cost).sah_cost;
        let ok = match validate_refs(&fin, &boxes, info.refs) {
            Ok(()) => "valid".to_string(),
            Err(e) => format!("INVALID: {e}"),
        };
        println!(
            "CHAIN {chain} | {} | final collapsed {fc:.4} | {ok} | {:.1}s",
            costs.join(" -> "),
            t_chain.elapsed().as_secs_f64()
        );
    }
}
