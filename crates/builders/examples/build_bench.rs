//! Times the builders on one scene:
//! `cargo run --release -p bvhlab-builders --example build_bench -- SCENE [runs=5] [threads=1] [BUILDERS]`
//! SCENE is a path (.obj / .obj.gz) or `gen:...`. Everything runs inside a rayon pool of `threads`
//! threads. BUILDERS is an optional comma-separated subset of: spatial-median, binned-sah,
//! binned-sah-any-axis, sweep-sah, binned-sah-par, lbvh, aac-hq, aac-fast, ploc-10, ploc-25,
//! ploc-100, bonsai-bp0, bonsai-bp1, bonsai-bp2 (default: all), or `binned-sah:k=v:k=v...` with any of
//! bins, axes (largest | all), leaf, stop (split-axis | any-axis), par (1: the parallel build). The Bonsai variants are thesis
//! table 3 (BP0: N = 512; BP1: N = 512, T = 0.1, pruning; BP2: N = 4096, T = 0.01, pruning) with the
//! same leaf threshold and SAH constants as the other top-down builders. Boxes and centres are computed once (not timed); each builder runs
//! `runs` times.
//!
//! The Morton-family times are the whole pipeline from boxes to a compacted tree: encode (Morton
//! codes + sort, `bvhlab_morton::encode` with each builder's paper default bits), and the bottom-up
//! build with its SAH compaction (thesis 3.6; `build_compacted`, which compacts the cluster tree
//! directly, as the pipeline does, so it has no time of its own); `build_ms_median` is the median of the per-run totals and the parts are reported
//! separately (each its own median).
//! One JSON line per builder with the eq. 4 SAH cost (c_T = 3, c_I = 2) of the final tree and
//! `bvh_fnv`, a hash of its canonical bytes (equal hashes = identical trees, e.g. the parallel
//! binned SAH vs the sequential one). A builder that panics (not implemented yet) gets an `error`
//! line and the others still run.
//!
//! `BUILD_BENCH_PAIR=PROGRAM` pairs every run with one build of another library in the same moments:
//! PROGRAM is started once with SCENE as its argument, answers `ready N` after loading it, and then
//! for each line it reads builds once and answers `MS SAH` (`scripts/anchors/tinybvh_buildavx_serve.cpp`,
//! tinybvh's BuildAVX; `scripts/bench-binned.sh` builds and passes it). Own build and partner build
//! alternate which goes first, and each line gains `anchor_ms_median`, `anchor_sah`, the median of the
//! per-run ratios `paired_ratio_median` and `paired_faster` (runs with a ratio below 1): this machine's
//! speed drifts by 20-40 % within minutes, and pairs milliseconds apart see the same phase.
use bvhlab_builders::aac::AacConfig;
use bvhlab_builders::binned_sah::{BinnedOptions, CentroidTermination};
use bvhlab_builders::bonsai::{self, BonsaiConfig};
use bvhlab_builders::ploc::PlocConfig;
use bvhlab_builders::{
    aac, binned_sah, lbvh, ploc, spatial_median, sweep_sah, SortedCodes, TopDownConfig,
};
use bvhlab_bvh::{metrics, validate, Aabb, Bvh, CostParams, Vec3};
use bvhlab_geom::stats::{median, min_max};
use bvhlab_morton::{AutoFor, Bits, EncodeConfig, Encoding};
use std::io::{BufRead, BufReader, Write};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::time::Instant;

/// The partner of `BUILD_BENCH_PAIR` (see the module doc): one build per request.
struct Partner {
    child: Child,
    out: BufReader<ChildStdout>,
}

impl Partner {
    fn start(program: &str, scene: &str) -> Partner {
        let mut child = Command::new(program)
            .arg(scene)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| fail(&format!("cannot start {program}: {e}")));
        let mut out = BufReader::new(child.stdout.take().expect("piped stdout"));
        let mut line = String::new();
        out.read_line(&mut line).ok();
        if !line.starts_with("ready") {
            fail(&format!("{program} did not load {scene} (said {line:?})"));
        }
        Partner { child, out }
    }
    /// One build: its milliseconds and SAH cost.
    fn build(&mut self) -> (f64, f64) {
        let stdin = self.child.stdin.as_mut().expect("piped stdin");
        writeln!(stdin, "build").and_then(|_| stdin.flush()).unwrap_or_else(|e| fail(&format!("partner: {e}")));
        let mut line = String::new();
        self.out.read_line(&mut line).ok();
        let v: Vec<f64> = line.split_whitespace().filter_map(|t| t.parse().ok()).collect();
        match v[..] {
            [ms, sah] => (ms, sah),
            _ => fail(&format!("partner answered {line:?}")),
        }
    }
}

fn fail(msg: &str) -> ! {
    eprintln!("error: {msg}");
    std::process::exit(1);
}

pub(crate) const ALL: [&str; 14] = [
    "spatial-median",
    "binned-sah",
    "binned-sah-any-axis",
    "sweep-sah",
    "binned-sah-par",
    "lbvh",
    "aac-hq",
    "aac-fast",
    "ploc-10",
    "ploc-25",
    "ploc-100",
    "bonsai-bp0",
    "bonsai-bp1",
    "bonsai-bp2",
];

/// Milliseconds of one run, split into the pipeline parts (encode is 0 for the top-down builders,
/// which take boxes and centres directly and make multi-primitive leaves).
#[derive(Clone, Copy, Default)]
pub(crate) struct Parts {
    encode: f64,
    build: f64,
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// One run of `name`: the final tree and its timed parts.
pub(crate) fn run(
    name: &str,
    boxes: &[Aabb],
    centers: &[Vec3],
    cfg: &TopDownConfig,
) -> (Bvh, Parts) {
    let mut p = Parts::default();
    let t = Instant::now();
    if let Some(spec) = name.strip_prefix("binned-sah:") {
        let (opts, cfg, par) = binned_spec(spec, cfg);
        let bvh = if par {
            binned_sah::build_parallel_with_options(boxes, centers, &opts, &cfg)
        } else {
            binned_sah::build_with_options(boxes, centers, &opts, &cfg)
        };
        p.build = ms_since(t);
        return (bvh, p);
    }
    let top_down = match name {
        "spatial-median" => Some(spatial_median::build(boxes, centers, cfg)),
        "binned-sah" => Some(binned_sah::build(boxes, centers, 16, cfg)),
        // The thesis' literal centroid termination (any dimension below 1e-7), for its BIN column.
        "binned-sah-any-axis" => Some(binned_sah::build_with_termination(
            boxes,
            centers,
            16,
            cfg,
            CentroidTermination::AnyAxis,
        )),
        "sweep-sah" => Some(sweep_sah::build(boxes, centers, cfg)),
        "binned-sah-par" => Some(binned_sah::build_parallel(
            boxes,
            centers,
            16,
            cfg,
            CentroidTermination::default(),
        )),
        "bonsai-bp0" | "bonsai-bp1" | "bonsai-bp2" => {
            let preset = match name {
                "bonsai-bp0" => BonsaiConfig::BP0,
                "bonsai-bp1" => BonsaiConfig::BP1,
                _ => BonsaiConfig::BP2,
            };
            let bc = BonsaiConfig {
                top: *cfg,
                ..preset
            };
            Some(bonsai::build(boxes, centers, &bc))
        }
        _ => None,
    };
    if let Some(bvh) = top_down {
        p.build = ms_since(t);
        return (bvh, p);
    }
    assert!(BOTTOM_UP.contains(&name), "unknown builder {name}");
    let t = Instant::now();
    let enc = encode_for(name, boxes, centers);
    p.encode = ms_since(t);
    let t = Instant::now();
    let bvh = bottom_up(name, boxes, &enc, cfg.cost);
    p.build = ms_since(t);
    (bvh, p)
}

/// The builders over Morton codes ([`encode_for`], [`bottom_up`]).
pub(crate) const BOTTOM_UP: [&str; 6] = ["lbvh", "aac-hq", "aac-fast", "ploc-10", "ploc-25", "ploc-100"];

/// The Morton codes a bottom-up builder runs on (each builder's paper default bits).
pub(crate) fn encode_for(name: &str, boxes: &[Aabb], centers: &[Vec3]) -> Encoding {
    let auto = match name {
        "lbvh" => AutoFor::Lbvh,
        "aac-hq" | "aac-fast" => AutoFor::Aac,
        _ => AutoFor::Ploc,
    };
    let enc_cfg = EncodeConfig {
        bits: Bits::Auto(auto),
        ..Default::default()
    };
    bvhlab_morton::encode(boxes, centers, &enc_cfg)
}

/// A bottom-up builder with its SAH compaction, over codes (no centres).
pub(crate) fn bottom_up(name: &str, boxes: &[Aabb], enc: &Encoding, cost: CostParams) -> Bvh {
    let sorted = SortedCodes {
        order: &enc.order,
        codes: &enc.codes,
        code_bits: enc.code_bits,
    };
    match name {
        "lbvh" => lbvh::build_compacted(boxes, &sorted, cost),
        "aac-hq" => aac::build_compacted(boxes, &sorted, &AacConfig::HQ, cost),
        "aac-fast" => aac::build_compacted(boxes, &sorted, &AacConfig::FAST, cost),
        "ploc-10" => ploc::build_compacted(boxes, &sorted, &PlocConfig { radius: 10 }, cost),
        "ploc-25" => ploc::build_compacted(boxes, &sorted, &PlocConfig { radius: 25 }, cost),
        "ploc-100" => ploc::build_compacted(boxes, &sorted, &PlocConfig { radius: 100 }, cost),
        other => unreachable!("unknown builder {other}"),
    }
}

/// `binned-sah:k=v:k=v...` (keys bins, axes = largest | all, leaf, stop = split-axis | any-axis,
/// par = 0 | 1): the binned SAH with any of its parameters (defaults as the method's).
fn binned_spec(spec: &str, cfg: &TopDownConfig) -> (BinnedOptions, TopDownConfig, bool) {
    let mut opts = BinnedOptions::new(16);
    let mut cfg = *cfg;
    let mut par = false;
    for kv in spec.split(':').filter(|s| !s.is_empty()) {
        let (k, v) = kv
            .split_once('=')
            .unwrap_or_else(|| usage(&format!("bad {kv:?}")));
        match k {
            "bins" => {
                opts.bins = v
                    .parse()
                    .unwrap_or_else(|_| usage(&format!("bad value in {kv:?}")))
            }
            "axes" => {
                opts.axes = v
                    .parse()
                    .unwrap_or_else(|_| usage(&format!("bad value in {kv:?}")))
            }
            "stop" => {
                opts.term = v
                    .parse()
                    .unwrap_or_else(|_| usage(&format!("bad value in {kv:?}")))
            }
            "leaf" => {
                cfg.leaf = v
                    .parse()
                    .unwrap_or_else(|_| usage(&format!("bad value in {kv:?}")))
            }
            "par" => par = v == "1",
            _ => usage(&format!("unknown key in {kv:?}")),
        }
    }
    (opts, cfg, par)
}

/// 64-bit FNV-1a of the canonical bytes: enough to tell identical trees apart in a benchmark log.
fn fnv(bvh: &Bvh) -> u64 {
    bvh.canonical_bytes()
        .iter()
        .fold(0xcbf29ce484222325, |h, &b| {
            (h ^ b as u64).wrapping_mul(0x100000001b3)
        })
}

fn usage(msg: &str) -> ! {
    eprintln!("{msg}\nusage: build_bench SCENE [runs=5] [threads=1] [BUILDERS (comma list)]");
    eprintln!("builders: {}", ALL.join(","));
    std::process::exit(2);
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let Some(spec) = args.get(1) else {
        usage("missing SCENE")
    };
    let positive = |i: usize, what: &str, default: usize| match args.get(i).map(|s| s.parse()) {
        None => default,
        Some(Ok(r)) if r > 0 => r,
        Some(_) => usage(&format!("{what} must be a positive integer")),
    };
    let runs = positive(2, "runs", 5);
    let threads = positive(3, "threads", 1);
    let selected: Vec<&str> = match args.get(4).map(String::as_str) {
        None | Some("all") => ALL.to_vec(),
        Some(list) => list
            .split(',')
            .map(|b| {
                if b.starts_with("binned-sah:") {
                    return b;
                }
                ALL.iter()
                    .copied()
                    .find(|a| *a == b)
                    .unwrap_or_else(|| usage(&format!("unknown builder {b:?}")))
            })
            .collect(),
    };
    let scene = match bvhlab_geom::load_scene(spec) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    };
    let (boxes, centers) = scene.boxes_and_centers();
    let cfg = TopDownConfig::default();
    let cost = CostParams::default();
    let mut partner = std::env::var("BUILD_BENCH_PAIR").ok().map(|p| Partner::start(&p, spec));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("rayon pool");
    for name in selected {
        let head = format!(
            "\"scene\":{spec:?},\"triangles\":{},\"builder\":\"{name}\",\"threads\":{threads},\"runs\":{runs}",
            boxes.len()
        );
        let mut parts = Vec::with_capacity(runs);
        let mut anchor = Vec::with_capacity(runs);
        let mut bvh = Bvh::default();
        let mut first_hash = None;
        let mut deterministic = true;
        let outcome = catch_unwind(AssertUnwindSafe(|| {
            for i in 0..runs {
                // With a partner: its build right before (odd runs) or after (even runs) ours.
                let mut theirs = || partner.as_mut().map(Partner::build);
                let before = if i % 2 == 1 { theirs() } else { None };
                let (b, p) = pool.install(|| run(name, &boxes, &centers, &cfg));
                anchor.extend(before.or_else(theirs));
                parts.push(p);
                bvh = std::hint::black_box(b);
                let h = fnv(&bvh);
                deterministic &= *first_hash.get_or_insert(h) == h;
            }
        }));
        if let Err(e) = outcome {
            let msg = e
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| e.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default();
            println!("{{{head},\"error\":{:?}}}", format!("panicked: {msg}"));
            continue;
        }
        let total: Vec<f64> = parts
            .iter()
            .map(|p| p.encode + p.build)
            .collect();
        let enc: Vec<f64> = parts.iter().map(|p| p.encode).collect();
        let bld: Vec<f64> = parts.iter().map(|p| p.build).collect();
        let total_med = median(&total);
        let paired = if anchor.is_empty() {
            String::new()
        } else {
            let ratios: Vec<f64> = total.iter().zip(&anchor).map(|(t, a)| t / a.0).collect();
            let a_ms: Vec<f64> = anchor.iter().map(|a| a.0).collect();
            format!(
                ",\"anchor_ms_median\":{:.2},\"anchor_sah\":{:.3},\"paired_ratio_median\":{:.3},\"paired_faster\":\"{}/{}\"",
                median(&a_ms),
                anchor[0].1,
                median(&ratios),
                ratios.iter().filter(|&&r| r < 1.0).count(),
                ratios.len()
            )
        };
        let valid = validate(&bvh, &boxes).err().unwrap_or_else(|| "ok".into());
        let m = metrics(&bvh, cost);
        println!(
            "{{{head},\"build_ms_median\":{total_med:.2},\"build_ms_min\":{:.2},\"encode_ms_median\":{:.2},\"build_part_ms_median\":{:.2},\"sah_cost\":{:.3},\"leaves\":{},\"refs_per_leaf\":{:.3},\"depth\":{},\"bvh_fnv\":\"{:016x}\",\"deterministic\":{deterministic},\"valid\":{valid:?}{paired}}}",
            min_max(total.iter().copied()).0,
            median(&enc),
            median(&bld),
            m.sah_cost,
            m.leaves,
            m.refs_per_leaf,
            m.depth,
            fnv(&bvh),
        );
    }
}
