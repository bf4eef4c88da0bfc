//! Scale invariance (issue 15): every method of the matrix (`methods/mod.rs`: every registered
//! builder with its variants, every encoder, the compaction, every optimizer, every layout) builds
//! the same structure for a scene and the same scene in other units.
//!
//! 1. Times 2^k, k in -120..=120: scaling is exact in f32 there (the test scenes keep every
//!    coordinate in [1, 2), so no coordinate becomes subnormal), so the trees must be identical:
//!    same nodes, same leaves, same primitive order, boxes exactly scaled, SAH cost equal to 1e-9.
//! 2. Times 1e-30 .. 1e30: the coordinates round differently, so only the cost is compared (1 %).
//! 3. Near f32::MAX: every method gives a finite SAH cost on a valid tree.
mod methods;

use bvhlab_bvh::{metrics, Bvh, CostParams};
use bvhlab_geom::{load_scene, Scene, Triangle, Vec3};
use methods::{for_each_structure, Built, Input, Opts};
use proptest::prelude::*;
use std::collections::BTreeMap;

const COST: CostParams = CostParams { c_t: 3.0, c_i: 2.0 };

/// The generated scenes of the issue, small enough for a debug build.
const GENERATED: &[&str] = &[
    "gen:sphere:n=400",
    "gen:city:blocks=5",
    "gen:terrain:n=400",
    "gen:hairball:n=300",
];

/// The whole matrix (every encoder and parameter variant, optimizers capped at 3 passes, layouts).
const OPTS: Opts = Opts::FULL;

/// The scene mapped into [1, 1.999]^3 with one uniform factor (shape kept): every coordinate then
/// has exponent 0, and times 2^k it stays a normal f32 for k in -126..=127, so scaling is exact.
fn unit_binade(s: &Scene) -> Vec<Triangle> {
    let b = s.bounds();
    let e = b.extent_f64().max_element();
    let m = |v: Vec3| -> Vec3 {
        let f = |x: f32, lo: f32| (1.0 + (x as f64 - lo as f64) / e * 0.999) as f32;
        Vec3::new(f(v.x, b.min.x), f(v.y, b.min.y), f(v.z, b.min.z))
    };
    s.triangles.iter().map(|t| Triangle { v: t.v.map(m) }).collect()
}

/// Every coordinate times `f`, in f64, rounded once to f32.
fn scaled(tris: &[Triangle], f: f64) -> Vec<Triangle> {
    let m = |v: Vec3| Vec3::new((v.x as f64 * f) as f32, (v.y as f64 * f) as f32, (v.z as f64 * f) as f32);
    tris.iter().map(|t| Triangle { v: t.v.map(m) }).collect()
}

fn scene_of(tris: Vec<Triangle>) -> Scene {
    Scene { triangles: tris, ..Default::default() }
}

/// What the scale tests compare of a structure.
#[derive(Debug)]
#[allow(dead_code)] // fields are read through Debug in failure messages
enum Sig {
    /// Nodes (first, count), primitive order, node boxes, SAH cost.
    Tree { nodes: Vec<(u32, u32)>, prims: Vec<u32>, boxes: Vec<[f32; 6]>, sah: f64 },
    /// A layout: its total bytes and its SAH cost (over its own, possibly quantized, boxes).
    Layout { bytes: u64, sah: f64 },
    Refused(String),
    Panic(String),
}

impl Sig {
    fn sah(&self) -> Option<f64> {
        match self {
            Sig::Tree { sah, .. } | Sig::Layout { sah, .. } => Some(*sah),
            _ => None,
        }
    }
}

fn clone_sig(s: &Sig) -> Sig {
    match s {
        Sig::Tree { nodes, prims, boxes, sah } => Sig::Tree { nodes: nodes.clone(), prims: prims.clone(), boxes: boxes.clone(), sah: *sah },
        Sig::Layout { bytes, sah } => Sig::Layout { bytes: *bytes, sah: *sah },
        Sig::Refused(e) => Sig::Refused(e.clone()),
        Sig::Panic(p) => Sig::Panic(p.clone()),
    }
}

fn tree_sig(b: &Bvh) -> Sig {
    Sig::Tree {
        nodes: b.nodes.iter().map(|n| (n.first, n.count)).collect(),
        prims: b.prim_indices.clone(),
        boxes: b
            .nodes
            .iter()
            .map(|n| [n.bounds.min.x, n.bounds.min.y, n.bounds.min.z, n.bounds.max.x, n.bounds.max.y, n.bounds.max.z])
            .collect(),
        sah: metrics(b, COST).sah_cost,
    }
}

/// Every method's structure on `tris` (no rays: the oracle suites check hits).
fn signatures(tris: &[Triangle]) -> BTreeMap<String, Sig> {
    signatures_with(tris, OPTS)
}

fn signatures_with(tris: &[Triangle], opts: Opts) -> BTreeMap<String, Sig> {
    let scene = scene_of(tris.to_vec());
    let input = Input::new(&scene, &[]);
    let mut out = BTreeMap::new();
    for_each_structure(&input, opts, &mut |label, built| {
        let sig = match built {
            Built::Bvh(b) => tree_sig(b),
            Built::Layout(Ok(l)) => Sig::Layout { bytes: l.memory().total_bytes, sah: l.sah_cost(COST) },
            Built::Layout(Err(e)) => Sig::Refused(e.clone()),
            Built::Panic(p) => Sig::Panic(p.clone()),
        };
        assert!(out.insert(label.to_string(), sig).is_none(), "duplicate label {label}");
    });
    out
}

fn rel(a: f64, b: f64) -> f64 {
    if a == b {
        0.0
    } else {
        (a - b).abs() / a.abs().max(b.abs())
    }
}

/// Compares the structures of a scene (`base`) and of the scene times 2^k: identical topology,
/// boxes exactly scaled, SAH cost equal to 1e-9. Returns the failures.
fn compare_pow2(base: &BTreeMap<String, Sig>, other: &BTreeMap<String, Sig>, k: i32) -> Vec<String> {
    let f = 2f32.powi(k);
    let mut bad = Vec::new();
    for (label, a) in base {
        let Some(b) = other.get(label) else {
            bad.push(format!("{label}: missing at 2^{k}"));
            continue;
        };
        match (a, b) {
            (
                Sig::Tree { nodes: n0, prims: p0, boxes: b0, sah: s0 },
                Sig::Tree { nodes: n1, prims: p1, boxes: b1, sah: s1 },
            ) => {
                if n0 != n1 || p0 != p1 {
                    bad.push(format!("{label}: topology differs at 2^{k}"));
                } else if b0.iter().zip(b1).any(|(x, y)| x.iter().zip(y).any(|(u, v)| u * f != *v)) {
                    bad.push(format!("{label}: boxes not exactly scaled at 2^{k}"));
                } else if !(rel(*s0, *s1) <= 1e-9) {
                    bad.push(format!("{label}: SAH {s0} vs {s1} at 2^{k}"));
                }
            }
            (Sig::Layout { bytes: m0, sah: s0 }, Sig::Layout { bytes: m1, sah: s1 }) => {
                // The one exception: qbvh_chunks's dequantization step (f32, extent / 2^bits) is subnormal
                // below 2^-126, i.e. for these unit-size scenes from k = -118 on, and loses bits
                // there (flat axes sooner); its boxes stay conservative (validated), the SAH moves by up to
                // 2e-4 (terrain at 2^-120). Left as it is: the SIMD traversal shares the f32 formula.
                let tol = if label.contains("qbvh_chunks") && k <= -110 { 1e-3 } else { 1e-9 };
                if m0 != m1 || !(rel(*s0, *s1) <= tol) {
                    bad.push(format!("{label}: layout {m0} B SAH {s0} vs {m1} B SAH {s1} at 2^{k}"));
                }
            }
            (Sig::Refused(_), Sig::Refused(_)) => {}
            (a, b) => bad.push(format!("{label}: {a:?} vs {b:?} at 2^{k}")),
        }
    }
    bad
}

struct Base {
    name: &'static str,
    tris: Vec<Triangle>,
    sigs: BTreeMap<String, Sig>,
}

fn bases() -> &'static Vec<Base> {
    static B: std::sync::OnceLock<Vec<Base>> = std::sync::OnceLock::new();
    B.get_or_init(|| {
        GENERATED
            .iter()
            .map(|name| {
                let tris = unit_binade(&load_scene(name).unwrap());
                let sigs = signatures(&tris);
                for (l, s) in &sigs {
                    assert!(!matches!(s, Sig::Panic(_)), "{name} {l}: {s:?}");
                }
                Base { name, tris, sigs }
            })
            .collect()
    })
}

fn check_pow2(b: &Base, k: i32) {
    let f = 2f64.powi(k);
    let tris = scaled(&b.tris, f);
    // Exact scaling is the premise: every coordinate comes back bit for bit.
    let back = scaled(&tris, 1.0 / f);
    assert!(back.iter().zip(&b.tris).all(|(x, y)| x.v == y.v), "{} 2^{k}: scaling not exact", b.name);
    let bad = compare_pow2(&b.sigs, &signatures(&tris), k);
    assert!(bad.is_empty(), "{} x 2^{k}: {} of {} methods differ:\n{}", b.name, bad.len(), b.sigs.len(), bad.join("\n"));
}

/// The extremes and a few fixed exponents, on every generated scene.
#[test]
fn pow2_scaling_keeps_every_structure_fixed_exponents() {
    for b in bases() {
        for k in [-120, -64, -1, 1, 37, 120] {
            check_pow2(b, k);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, failure_persistence: None, ..ProptestConfig::default() })]
    /// Random exponents in -120..=120 on a random generated scene.
    #[test]
    fn pow2_scaling_keeps_every_structure(k in -120i32..=120, scene in 0usize..4) {
        check_pow2(&bases()[scene], k);
    }
}

const FACTORS: [f64; 6] = [1e-30, 1e-20, 1e-8, 1e8, 1e18, 1e30];

/// The decimal test's scenes, as generated (not moved into [1, 2)) and larger: the cost of a
/// 400-triangle tree hangs on a handful of decisions, of a few thousand on their average.
fn decimal_scenes() -> Vec<(String, Vec<Triangle>)> {
    let n: usize = std::env::var("SCALE_N").ok().and_then(|v| v.parse().ok()).unwrap_or(3000);
    let blocks = ((n as f64 / 12.0).sqrt() as usize).max(2);
    [
        format!("gen:sphere:n={n}"),
        format!("gen:city:blocks={blocks}"),
        format!("gen:terrain:n={n}"),
        format!("gen:hairball:n={n}"),
    ]
    .into_iter()
    .map(|name| {
        let t = load_scene(&name).unwrap().triangles;
        (name, t)
    })
    .collect()
}

/// Every builder (default parameters and leaf=1, default encoder), the compaction, every optimizer
/// and every layout: the decimal test's matrix (the variants are the power-of-two test's).
const DECIMAL_OPTS: Opts = Opts { all_encoders: false, variants: false, ..OPTS };

/// Factors that are not powers of two round every coordinate differently, so trees may differ in
/// details: the SAH cost stays within 1 % for every method, or, for a method whose trees already
/// move more than that under a perturbation of the same size at scale 1 (coordinates times
/// 1 +- 2^-e, e = 20..=23: rounding only), within twice that spread. The greedy bottom-up
/// builders (aac, ploc) and insertion order (incremental) break the many exact ties of regular
/// meshes (sphere, terrain grid) by float noise, whatever the scale; see the closing note of
/// issue 15 for the measured spreads. A scale failure (f32 overflow or underflow) is far outside
/// either bound (one leaf: +4000 %).
/// Largest relative SAH change per method under rounding-level perturbations at scale 1.
fn spread_at_scale_one(tris: &[Triangle], base: &BTreeMap<String, Sig>) -> BTreeMap<String, f64> {
    let mut spread: BTreeMap<String, f64> = BTreeMap::new();
    for p in (20..=23).flat_map(|e| [1.0 + 2f64.powi(-e), 1.0 - 2f64.powi(-e)]) {
        let other = signatures_with(&scaled(tris, p), DECIMAL_OPTS);
        for (label, a) in base {
            if let (Some(x), Some(y)) = (a.sah(), other.get(label).and_then(Sig::sah)) {
                let e = spread.entry(label.clone()).or_default();
                *e = e.max(rel(x, y));
            }
        }
    }
    spread
}

/// Every method's SAH in `other` within max(`tol`, 2 x its scale-1 spread; for a layout, 1.5 x its
/// input BVH's change) of `base`. Failures
/// are returned; cells above `tol` but within the spread go to `report`.
fn compare_sah(
    ctx: &str,
    base: &BTreeMap<String, Sig>,
    other: &BTreeMap<String, Sig>,
    spread: &BTreeMap<String, f64>,
    tol: f64,
    report: &mut Vec<String>,
) -> Vec<String> {
    let mut bad = Vec::new();
    for (label, a) in base {
        let sp = spread.get(label).copied().unwrap_or(0.0);
        // A layout's tree is computed from its input BVH, so it moves with it: a layout may move by
        // 1.5 times its input's change (a wide collapse re-decides which nodes to pull up; measured:
        // sphere +10^3 extents, incremental +1.8 %, its optimal bvh8 collapse +2.5 %).
        let input = label.strip_prefix("layout ").and_then(|l| l.split_once(" <- ")).map(|(_, i)| i);
        let moved = input
            .and_then(|i| Some(rel(base.get(i)?.sah()?, other.get(i)?.sah()?)))
            .unwrap_or(0.0);
        let lim = tol.max(2.0 * sp).max(1.5 * moved);
        match (a.sah(), other.get(label).and_then(Sig::sah)) {
            (Some(x), Some(y)) => {
                let d = rel(x, y);
                let line = format!("{ctx} {label}: SAH {x:.4} vs {y:.4} ({:+.2} %, spread at scale 1 {:.2} %)", 100.0 * (y - x) / x, 100.0 * sp);
                if !(d <= lim) {
                    bad.push(line);
                } else if d > tol {
                    report.push(line);
                }
            }
            (None, None) => {}
            (x, y) => bad.push(format!("{ctx} {label}: {x:?} vs {y:?}")),
        }
    }
    bad
}

fn check_decimal(name: &str, tris: &[Triangle], report: &mut Vec<String>) -> Vec<String> {
    let base = signatures_with(tris, DECIMAL_OPTS);
    let spread = spread_at_scale_one(tris, &base);
    let mut bad = Vec::new();
    for f in FACTORS {
        let other = signatures_with(&scaled(tris, f), DECIMAL_OPTS);
        bad.extend(compare_sah(&format!("{name} x{f:e}"), &base, &other, &spread, 0.01, report));
    }
    bad
}

/// A scene moved by 10^k times its own extent (k = 0..=6): while f32 still resolves its detail
/// (`precision_loss` <= the warning level) every method's SAH stays within 2 % (or its scale-1
/// spread); beyond, the row carries a warning naming the precision loss.
#[test]
fn translation_keeps_sah_or_warns() {
    let (mut bad, mut over, mut seen) = (Vec::new(), Vec::new(), Vec::new());
    for (name, tris) in decimal_scenes() {
        let base = signatures_with(&tris, DECIMAL_OPTS);
        let spread = spread_at_scale_one(&tris, &base);
        let e = scene_of(tris.clone()).bounds().extent_f64().max_element();
        for k in 0..=6 {
            let off = 10f64.powi(k) * e;
            let moved: Vec<Triangle> = tris
                .iter()
                .map(|t| Triangle { v: t.v.map(|v| (v.as_dvec3() + glam::DVec3::splat(off)).as_vec3()) })
                .collect();
            let loss = scene_of(moved.clone()).precision_loss();
            let warning = bvhlab_pipeline::stages::precision_warning(&name, loss);
            seen.push(format!("{name} +10^{k} extent: precision_loss {loss:.2e}, warning {}", warning.is_some()));
            if warning.is_none() {
                let mut other = signatures_with(&moved, DECIMAL_OPTS);
                // Kilian's octrees are the exception, reported not asserted: their overlap margin is
                // 2^-19 of the largest coordinate magnitude (what keeps their f32 traversal exact
                // far from the origin), so moved by 10^k extents, deep cells take in triangles within
                // 10^k times more of their neighbourhood (sphere +3.8 % at 10^2, +22 % at 10^3).
                other.retain(|label, s| {
                    let octree = label.starts_with("layout octree");
                    if octree {
                        if let (Some(x), Some(y)) = (base.get(label).and_then(Sig::sah), s.sah()) {
                            over.push(format!("{name} +10^{k} {label}: octree margin: {:+.2} %", 100.0 * (y - x) / x));
                        }
                    }
                    !octree
                });
                let base_bvh: BTreeMap<String, Sig> =
                    base.iter().filter(|(l, _)| !l.starts_with("layout octree")).map(|(l, s)| (l.clone(), clone_sig(s))).collect();
                bad.extend(compare_sah(&format!("{name} +10^{k}"), &base_bvh, &other, &spread, 0.02, &mut over));
            } else {
                assert!(warning.unwrap().contains("f32 precision"));
            }
        }
    }
    eprintln!("{}\n{} cells above 2 % but within the scale-1 spread:\n{}", seen.join("\n"), over.len(), over.join("\n"));
    assert!(bad.is_empty(), "{} differences:\n{}", bad.len(), bad.join("\n"));
}

#[test]
fn decimal_scaling_keeps_sah_generated() {
    let (mut bad, mut over) = (Vec::new(), Vec::new());
    for (name, tris) in decimal_scenes() {
        bad.extend(check_decimal(&name, &tris, &mut over));
    }
    eprintln!("{} cells above 1 % but within the scale-1 spread:\n{}", over.len(), over.join("\n"));
    assert!(bad.is_empty(), "{} differences:\n{}", bad.len(), bad.join("\n"));
}

/// The shared scenes (../shared/scenes), each thinned to about 3000 triangles (every k-th, so the
/// debug build stays quick; `just scale` runs them at 30k triangles). Skips when ../shared is absent.
#[test]
fn decimal_scaling_keeps_sah_shared() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes");
    let Ok(rd) = std::fs::read_dir(&dir) else {
        eprintln!("skipped: {} not found", dir.display());
        return;
    };
    let mut files: Vec<_> = rd.filter_map(|e| e.ok()).map(|e| e.path()).filter(|p| p.to_string_lossy().ends_with(".obj.gz")).collect();
    files.sort();
    let target: usize = std::env::var("SCALE_N").ok().and_then(|v| v.parse().ok()).unwrap_or(3000);
    let (mut bad, mut over) = (Vec::new(), Vec::new());
    for f in files {
        let s = bvhlab_geom::obj::load_obj(&f).unwrap();
        let stride = (s.triangles.len() / target).max(1);
        let tris: Vec<Triangle> = s.triangles.iter().step_by(stride).copied().collect();
        let name = f.file_name().unwrap().to_string_lossy().to_string();
        bad.extend(check_decimal(&name, &tris, &mut over));
    }
    eprintln!("{} cells above 1 % but within the scale-1 spread:\n{}", over.len(), over.join("\n"));
    assert!(bad.is_empty(), "{} differences:\n{}", bad.len(), bad.join("\n"));
}

/// Coordinates near f32::MAX (the box spans about 2^128 on each axis): every method gives a valid
/// tree with a finite SAH cost (found: `sah_cost: null` with `valid: true` at 3e38), and the
/// top-down SAH builders keep the quality of the unit-size scene.
#[test]
fn near_f32_max_costs_are_finite() {
    let b = &bases()[0];
    // [1, 2) times 2^127 reaches 3.4e38 = f32::MAX; centred so that min and max both are huge.
    let tris: Vec<Triangle> = b
        .tris
        .iter()
        .map(|t| Triangle { v: t.v.map(|v| ((v - Vec3::splat(1.5)) * 2.0 * 2f32.powi(127)).clamp(Vec3::splat(-f32::MAX), Vec3::splat(f32::MAX))) })
        .collect();
    assert!(tris.iter().all(|t| t.is_finite()));
    let sigs = signatures_with(&tris, DECIMAL_OPTS);
    let mut bad = Vec::new();
    for (label, s) in &sigs {
        match s {
            Sig::Tree { sah, .. } | Sig::Layout { sah, .. } if sah.is_finite() && *sah > 0.0 => {}
            Sig::Refused(_) => {}
            other => bad.push(format!("{label}: {other:?}")),
        }
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
    let unit = signatures_with(&b.tris, DECIMAL_OPTS);
    // Every builder keeps its quality (3 %: aac and ploc move that much under rounding alone).
    let mut worse = Vec::new();
    for (m, x) in &unit {
        let is_builder = !m.starts_with("layout") && !m.contains(" <- ") && !m.ends_with(" raw");
        if let (true, Some(x), Some(y)) = (is_builder, x.sah(), sigs.get(m).and_then(Sig::sah)) {
            if !(rel(x, y) <= 0.03) {
                worse.push(format!("{m}: {x:.3} at unit size, {y:.3} near f32::MAX"));
            }
        }
    }
    assert!(worse.is_empty(), "{}", worse.join("\n"));
}
