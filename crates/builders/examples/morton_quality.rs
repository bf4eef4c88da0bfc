//! Quick quality/speed check of the Morton-family builders on one scene, for developing them:
//! `cargo run --release -p bvhlab-builders --example morton_quality -- SCENE BUILDER [ENCODER] [THREADS]`
//! BUILDER: lbvh | aac-hq | aac-fast | aac:DELTA:EPS | ploc:R. ENCODER: auto (default: each
//! builder's paper default) | morton:BITS | emc64-sort | emc64-var, optionally `+concise`,
//! `+centroids`, `+grid9` (grid bits). Prints one JSON line: encode, build and collapse times (one
//! run each) and the SAH cost (c_T = 3, c_I = 2) before and after the SAH compaction.
use bvhlab_builders::aac::AacConfig;
use bvhlab_builders::ploc::PlocConfig;
use bvhlab_builders::{aac, lbvh, ploc, SortedCodes};
use bvhlab_bvh::{collapse::collapse, metrics, validate, CostParams};
use bvhlab_morton::{AutoFor, Bits, BoundsMode, EncodeConfig, Scheme};
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        eprintln!("usage: morton_quality SCENE BUILDER [ENCODER] [THREADS]");
        std::process::exit(2);
    }
    let (spec, builder) = (&args[1], args[2].as_str());
    let encoder = args.get(3).map(String::as_str).unwrap_or("auto");
    let threads: usize = args.get(4).and_then(|t| t.parse().ok()).unwrap_or(0);
    let scene = bvhlab_geom::load_scene(spec).unwrap_or_else(|e| {
        eprintln!("error: {e}");
        std::process::exit(1)
    });
    let (boxes, centers) = scene.boxes_and_centers();
    let auto = match builder {
        b if b.starts_with("aac") => AutoFor::Aac,
        b if b.starts_with("ploc") => AutoFor::Ploc,
        _ => AutoFor::Lbvh,
    };
    let mut parts = encoder.split('+');
    let mut cfg = EncodeConfig { bits: Bits::Auto(auto), ..Default::default() };
    match parts.next().unwrap_or("auto") {
        "auto" => {}
        "emc64-sort" => cfg.scheme = Scheme::Emc64Sort,
        "emc64-var" => cfg.scheme = Scheme::Emc64Var,
        m => match m.strip_prefix("morton:").and_then(|b| b.parse().ok()) {
            Some(b) => cfg.bits = Bits::Fixed(b),
            None if m == "morton" => {}
            None => panic!("unknown encoder {m}"),
        },
    }
    for p in parts {
        match p {
            "concise" => cfg.bounds = BoundsMode::Concise,
            "centroids" => cfg.bounds = BoundsMode::Centroids,
            g => cfg.grid_bits = g.strip_prefix("grid").and_then(|b| b.parse().ok()).expect("grid bits"),
        }
    }
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| {
        let t = Instant::now();
        let enc = bvhlab_morton::encode(&boxes, &centers, &cfg);
        let encode_ms = t.elapsed().as_secs_f64() * 1e3;
        let sorted = SortedCodes { order: &enc.order, codes: &enc.codes, code_bits: enc.code_bits };
        let t = Instant::now();
        let bvh = match builder {
            "lbvh" => lbvh::build(&boxes, &sorted),
            "aac-hq" => aac::build(&boxes, &sorted, &AacConfig::HQ),
            "aac-fast" => aac::build(&boxes, &sorted, &AacConfig::FAST),
            b if b.starts_with("aac:") => {
                let v: Vec<&str> = b.split(':').collect();
                aac::build(&boxes, &sorted, &AacConfig { delta: v[1].parse().unwrap(), epsilon: v[2].parse().unwrap() })
            }
            b if b.starts_with("ploc:") => ploc::build(&boxes, &sorted, &PlocConfig { radius: b[5..].parse().unwrap() }),
            b => panic!("unknown builder {b}"),
        };
        let build_ms = t.elapsed().as_secs_f64() * 1e3;
        let cost = CostParams::default();
        let t = Instant::now();
        let compact = collapse(&bvh, cost);
        let collapse_ms = t.elapsed().as_secs_f64() * 1e3;
        println!(
            "{{\"scene\":{spec:?},\"triangles\":{},\"builder\":\"{builder}\",\"encoder\":\"{encoder}\",\"code_bits\":{},\"duplicates\":{:.4},\"threads\":{},\"encode_ms\":{encode_ms:.1},\"build_ms\":{build_ms:.1},\"collapse_ms\":{collapse_ms:.1},\"sah_leaf1\":{:.2},\"sah\":{:.2},\"valid\":{:?}}}",
            boxes.len(),
            enc.code_bits,
            enc.duplicate_fraction(),
            rayon::current_num_threads(),
            metrics(&bvh, cost).sah_cost,
            metrics(&compact, cost).sah_cost,
            validate(&compact, &boxes).err().unwrap_or_else(|| "ok".into())
        );
    });
}
