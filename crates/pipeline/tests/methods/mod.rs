//! The method matrix of the reliability suite (issue 6), shared by `tests/stress.rs`,
//! `tests/proptest_oracle.rs` and `examples/oracle_large.rs`: every registered builder (top-down
//! builders with their default and single-primitive leaves plus a few parameter variants; code
//! builders with every encoder variant), the SAH compaction of every built tree, every registered
//! optimizer, and every layout of `bvhlab_layout::LAYOUTS` with parameter variants. Enumerated from
//! the registry and `LAYOUTS`, so methods added later are covered without touching this file.
//!
//! Each method either yields hits (after its structure validated), or a clear error (`Refused`:
//! a layout's `Err`), or a failure (`Invalid`, `Panic`). Callers compare hits with brute force.
#![allow(dead_code)]
use bvhlab_builders::SortedCodes;
use bvhlab_bvh::{collapse::collapse, validate_refs, Aabb, Bvh, CostParams, Refs, Vec3};
use bvhlab_geom::rng::SplitMix64;
use bvhlab_geom::{Scene, Triangle};
use bvhlab_layout::{LayoutSpec, LAYOUTS};
use bvhlab_pipeline::registry::Registry;
use bvhlab_trace::{Hit, Ray};
use std::collections::BTreeMap;
use std::panic::{catch_unwind, AssertUnwindSafe};

/// (encoder, parameters) variants for the builders that take codes; the first is the default.
pub const ENCODERS: &[(&str, &[(&str, &str)])] = &[
    ("morton", &[]),
    ("morton", &[("bits", "1")]),
    ("morton", &[("bits", "10")]),
    ("morton", &[("bounds", "centroids")]),
    ("morton", &[("bounds", "concise")]),
    ("morton", &[("grid_bits", "9")]),
    ("morton", &[("grid_bits", "6"), ("grid_frame", "tight")]),
    ("emc64-sort", &[]),
    ("emc64-var", &[]),
    ("emc64-var", &[("bounds", "concise"), ("grid_bits", "9")]),
];

/// Builder parameter variants beyond the defaults and `leaf=1` (only for registered names).
pub const BUILDER_VARIANTS: &[(&str, &[(&str, &str)])] = &[
    ("binned-sah", &[("centroid_stop", "any-axis")]),
    ("binned-sah", &[("bins", "2"), ("leaf", "8")]),
    ("bonsai", &[("n", "16"), ("prune", "true")]),
    ("bonsai", &[("n", "16"), ("prune", "true"), ("t", "0.01")]),
    ("aac", &[("preset", "fast")]),
    ("ploc", &[("radius", "1")]),
    ("incremental", &[("batch", "7"), ("coh", "0")]),
];

/// Layout parameter variants beyond the defaults (only for names in `LAYOUTS`).
pub const LAYOUT_VARIANTS: &[(&str, &[(&str, &str)])] = &[
    ("qbvh_chunks", &[("bits", "1")]),
    ("qbvh_chunks", &[("bits", "1"), ("frame", "parent")]),
    ("qbvh_chunks", &[("frame", "parent")]),
    ("octree", &[("max_depth", "1")]),
    ("octree", &[("prim_threshold", "1"), ("max_depth", "12")]),
    ("octree_1bit", &[("fill", "dense")]),
    ("octree_1bit", &[("chunk_bytes", "16"), ("fill", "bfs")]),
    ("bvh4", &[("collapse", "greedy")]),
    ("bvh8", &[("collapse", "greedy")]),
    ("cwbvh", &[("collapse", "greedy")]),
];

pub fn raw(kv: &[(&str, &str)]) -> BTreeMap<String, String> {
    kv.iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect()
}

/// What a method gave.
pub enum Outcome {
    /// Closest hits, one per ray (the structure validated).
    Hits(Vec<Hit>),
    /// A clear error instead of a structure (allowed).
    Refused(String),
    /// Validation failed.
    Invalid(String),
    /// The method panicked.
    Panic(String),
}

#[derive(Clone, Copy)]
pub struct Opts {
    /// Every encoder variant for code builders (else the default encoder only).
    pub all_encoders: bool,
    /// Builder and layout parameter variants (else defaults + leaf=1 only).
    pub variants: bool,
    pub optimizers: bool,
    /// `max_passes` of the optimizers (bounded: convergence is their own tests' job).
    pub max_passes: u32,
    pub layouts: bool,
    /// Compaction of every built tree.
    pub collapse: bool,
    /// Builders not run (e.g. quadratic ones on a huge input that another test covers).
    pub skip_builders: &'static [&'static str],
}

impl Opts {
    pub const FULL: Opts = Opts {
        all_encoders: true,
        variants: true,
        optimizers: true,
        max_passes: 3,
        layouts: true,
        collapse: true,
        skip_builders: &[],
    };
}

fn panic_text(e: Box<dyn std::any::Any + Send>) -> String {
    e.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| e.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "non-string panic".into())
}

/// A scene prepared for the matrix.
pub struct Input<'a> {
    pub tris: &'a [Triangle],
    pub boxes: Vec<Aabb>,
    pub centers: Vec<Vec3>,
    pub rays: &'a [Ray],
}

impl<'a> Input<'a> {
    pub fn new(scene: &'a Scene, rays: &'a [Ray]) -> Input<'a> {
        let (boxes, centers) = scene.boxes_and_centers();
        Input {
            tris: &scene.triangles,
            boxes,
            centers,
            rays,
        }
    }

    fn bvh_outcome(&self, bvh: &Bvh, refs: Refs) -> Outcome {
        if let Err(e) = validate_refs(bvh, &self.boxes, refs) {
            return Outcome::Invalid(e);
        }
        Outcome::Hits(bvhlab_trace::trace(bvh, self.tris, self.rays).hits)
    }
}

/// Runs `f` catching panics; a panic becomes `Err(Outcome::Panic)`.
fn guarded<T>(f: impl FnOnce() -> T) -> Result<T, Outcome> {
    catch_unwind(AssertUnwindSafe(f)).map_err(|e| Outcome::Panic(panic_text(e)))
}

/// What a method built: a BVH (builders, compaction, optimizers), a layout (or its refusal), or a
/// panic.
pub enum Built {
    Bvh(Bvh),
    Layout(Result<bvhlab_layout::Layout, String>),
    Panic(String),
}

/// Runs every method on `input`, calling `report(label, outcome)` for each.
pub fn run_all(input: &Input, opts: Opts, report: &mut dyn FnMut(&str, Outcome)) {
    for_each_structure(input, opts, &mut |label, built| {
        let o = match built {
            Built::Bvh(bvh) => input.bvh_outcome(bvh, refs_of(label)),
            Built::Layout(Err(e)) => Outcome::Refused(e.clone()),
            Built::Layout(Ok(l)) => layout_hits(l, input, refs_of(label)),
            Built::Panic(p) => Outcome::Panic(p.clone()),
        };
        report(label, o)
    })
}

/// Runs every method on `input` and hands each structure to `report` (the matrix of [`run_all`];
/// the scale tests compare the structures themselves).
pub fn for_each_structure(input: &Input, opts: Opts, report: &mut dyn FnMut(&str, &Built)) {
    let reg = Registry::standard();
    let cost = CostParams::default();
    let mut opt_inputs: Vec<(String, Bvh)> = Vec::new();
    let mut layout_inputs: Vec<(String, Bvh)> = Vec::new();

    let tree = |label: String, bvh: Bvh, report: &mut dyn FnMut(&str, &Built)| {
        let b = Built::Bvh(bvh);
        report(&label, &b);
        let Built::Bvh(bvh) = b else { unreachable!() };
        if opts.collapse {
            match guarded(|| collapse(&bvh, cost)) {
                Ok(c) => report(&format!("{label} +collapse"), &Built::Bvh(c)),
                Err(o) => report(&format!("{label} +collapse"), &panic_of(o)),
            }
        }
        bvh
    };

    // Peers are checked in crates/peers/tests and tests/peers.rs (they need the triangles).
    for info in reg.builders.iter().filter(|b| b.peer.is_none() && !opts.skip_builders.contains(&b.name)) {
        let mut param_sets: Vec<BTreeMap<String, String>> = vec![raw(&[])];
        if info.codes.is_none() && info.params.iter().any(|p| p.name == "leaf") {
            param_sets.push(raw(&[("leaf", "1")]));
        }
        if opts.variants {
            for (name, kv) in BUILDER_VARIANTS {
                if *name == info.name {
                    param_sets.push(raw(kv));
                }
            }
        }
        for params in &param_sets {
            if info.codes.is_none() {
                let r = reg
                    .resolve(info.name, params, cost)
                    .unwrap_or_else(|e| panic!("{} {params:?}: {e}", info.name));
                let label = format!("{} [{}]", info.name, kv_string(params));
                match guarded(|| info.construct(input.tris, &input.boxes, &input.centers, None, &r)) {
                    Ok(bvh) => {
                        let bvh = tree(label.clone(), bvh, report);
                        let leaf1 = params.get("leaf").map(String::as_str) == Some("1");
                        if params.is_empty() && (info.name == "binned-sah" || info.refs == Refs::Split) {
                            layout_inputs.push((label.clone(), bvh.clone()));
                        }
                        if leaf1 && (info.name == "sweep-sah" || info.name == "spatial-median" || info.refs == Refs::Split) {
                            opt_inputs.push((label.clone(), bvh.clone()));
                        }
                        if params.is_empty() && info.name == "incremental" {
                            // One primitive per leaf and possibly very deep: a layout stress input.
                            layout_inputs.push((label, bvh));
                        }
                    }
                    Err(o) => report(&label, &panic_of(o)),
                }
                continue;
            }
            let encoders = if opts.all_encoders {
                ENCODERS
            } else {
                &ENCODERS[..1]
            };
            for (enc, eparams) in encoders {
                let mut all = params.clone();
                all.extend(raw(eparams));
                let (r, e) = reg
                    .resolve_chain(info.name, Some(enc), None, &all, cost)
                    .unwrap_or_else(|e| panic!("{} {enc} {all:?}: {e}", info.name))
                    .parts();
                let e = e.expect("code builders have an encoder");
                let label = format!("{} [{}] {}", info.name, kv_string(params), reg.encoder_label(&e));
                let built = guarded(|| {
                    let enc = bvhlab_morton::encode(&input.boxes, &input.centers, &e.config);
                    let codes = SortedCodes {
                        order: &enc.order,
                        codes: &enc.codes,
                        code_bits: enc.code_bits,
                    };
                    // The raw single-primitive-leaf tree, then what the build stage stores.
                    let raw_tree = (info.run)(&input.boxes, &input.centers, Some(&codes), &r);
                    let built = info.construct(input.tris, &input.boxes, &input.centers, Some(&codes), &r);
                    (raw_tree, built)
                });
                match built {
                    Ok((raw_tree, built)) => {
                        report(&format!("{label} raw"), &Built::Bvh(raw_tree));
                        tree(label, built, report);
                    }
                    Err(o) => report(&label, &panic_of(o)),
                }
            }
        }
    }

    if opts.optimizers {
        for (base, bvh) in &opt_inputs {
            for info in &reg.optimizers {
                let o = reg
                    .resolve_optimizer(
                        info.name,
                        &raw(&[("max_passes", &opts.max_passes.to_string())]),
                        cost,
                    )
                    .unwrap();
                let label = format!("{} <- {base}", reg.optimizer_label(&o));
                match guarded(|| (info.run)(bvh, &o)) {
                    Ok(out) => {
                        tree(label, out.bvh, report);
                    }
                    Err(p) => report(&label, &panic_of(p)),
                }
            }
        }
    }

    if opts.layouts {
        for name in LAYOUTS {
            let mut specs = vec![raw(&[])];
            if opts.variants {
                for (n, kv) in LAYOUT_VARIANTS {
                    if *n == name {
                        specs.push(raw(kv));
                    }
                }
            }
            // Octrees are built from the triangles alone: one base tree is enough.
            let bases = if bvhlab_layout::uses_bvh(name) {
                &layout_inputs[..]
            } else {
                &layout_inputs[..layout_inputs.len().min(1)]
            };
            for given in &specs {
                let spec = LayoutSpec::parse(name, given)
                    .unwrap_or_else(|e| panic!("layout {name} {given:?}: {e}"));
                for (base, bvh) in bases {
                    let label = format!("layout {name} [{}] <- {base}", kv_string(given));
                    let built = guarded(|| bvhlab_layout::build(&spec, bvh, input.tris));
                    report(&label, &built.map(Built::Layout).unwrap_or_else(|o| panic_of(o)));
                }
            }
        }
    }
}

fn panic_of(o: Outcome) -> Built {
    match o {
        Outcome::Panic(p) => Built::Panic(p),
        _ => unreachable!("guarded only fails with a panic"),
    }
}

/// Structures built from an SBVH (the builder, its compaction, optimizers and layouts on it) may
/// repeat references (Stich et al. 2009); every other structure references each triangle once.
pub fn refs_of(label: &str) -> Refs {
    if label.contains("sbvh") {
        Refs::Split
    } else {
        Refs::Unique
    }
}

fn layout_hits(l: &bvhlab_layout::Layout, input: &Input, refs: Refs) -> Outcome {
    guarded(|| {
        if let Err(e) = l.validate_refs(input.tris, refs) {
            return Outcome::Invalid(e);
        }
        Outcome::Hits(l.trace(input.tris, input.rays).hits)
    })
    .unwrap_or_else(|o| o)
}

pub fn layout_outcome(spec: &LayoutSpec, bvh: &Bvh, input: &Input) -> Outcome {
    let r = guarded(|| -> Outcome {
        let l = match bvhlab_layout::build(spec, bvh, input.tris) {
            Ok(l) => l,
            Err(e) => return Outcome::Refused(e),
        };
        if let Err(e) = l.validate(input.tris) {
            return Outcome::Invalid(e);
        }
        Outcome::Hits(l.trace(input.tris, input.rays).hits)
    });
    r.unwrap_or_else(|o| o)
}

fn kv_string(kv: &BTreeMap<String, String>) -> String {
    kv.iter()
        .map(|(k, v)| format!("{k}={v}"))
        .collect::<Vec<_>>()
        .join(",")
}

/// Same triangle, or both hit at the same t within 1e-6 relative (ties between coincident
/// triangles).
pub fn same_hit(g: &Hit, w: &Hit) -> bool {
    g.prim == w.prim || (g.is_hit() && w.is_hit() && (g.t - w.t).abs() <= 1e-6 * w.t.abs())
}

/// `n` rays for any scene, computed in f64 so huge (1e30) and tiny (1e-30) scenes get usable
/// rays: even rays are chords of the sphere around the scene box (tmax = chord length), odd rays
/// start on that sphere and aim at a random point inside a random triangle (tmax = infinity).
pub fn stress_rays(tris: &[Triangle], n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = SplitMix64::new(seed);
    let (mut lo, mut hi) = ([f64::MAX; 3], [f64::MIN; 3]);
    for t in tris {
        for v in t.v {
            for a in 0..3 {
                lo[a] = lo[a].min(v[a] as f64);
                hi[a] = hi[a].max(v[a] as f64);
            }
        }
    }
    if tris.is_empty() {
        (lo, hi) = ([0.0; 3], [1.0; 3]);
    }
    let c: [f64; 3] = std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]));
    let r = (0..3)
        .map(|a| (hi[a] - lo[a]) * (hi[a] - lo[a]))
        .sum::<f64>()
        .sqrt()
        .max(c.iter().map(|x| x.abs()).fold(0.0, f64::max) * 1e-6)
        .max(1e-300)
        * 0.6;
    let sphere = |rng: &mut SplitMix64| -> [f64; 3] {
        loop {
            let p: [f64; 3] = std::array::from_fn(|_| rng.f64() * 2.0 - 1.0);
            let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            if l > 0.1 && l <= 1.0 {
                return std::array::from_fn(|a| c[a] + r * p[a] / l);
            }
        }
    };
    let v3 = |p: [f64; 3]| Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32);
    (0..n)
        .map(|i| {
            let o = sphere(&mut rng);
            let (target, tmax) = if i % 2 == 1 && !tris.is_empty() {
                let t = &tris[rng.below(tris.len() as u64) as usize];
                let (mut u, mut v) = (rng.f64(), rng.f64());
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                let p = |k: usize, a: usize| t.v[k][a] as f64;
                let x: [f64; 3] =
                    std::array::from_fn(|a| p(0, a) + u * (p(1, a) - p(0, a)) + v * (p(2, a) - p(0, a)));
                (x, f32::INFINITY)
            } else {
                let p = sphere(&mut rng);
                let len = (0..3).map(|a| (p[a] - o[a]).powi(2)).sum::<f64>().sqrt();
                (p, len as f32)
            };
            let d: [f64; 3] = std::array::from_fn(|a| target[a] - o[a]);
            let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            if !(l > 0.0) {
                return Ray {
                    origin: v3(o),
                    dir: Vec3::X,
                    tmax: 0.0,
                };
            }
            Ray {
                origin: v3(o),
                dir: v3(std::array::from_fn(|a| d[a] / l)),
                tmax,
            }
        })
        .collect()
}

/// Tally of one matrix run: failures (panic, invalid, wrong hit) are listed, refusals counted.
#[derive(Default)]
pub struct Tally {
    pub methods: usize,
    pub rays_checked: u64,
    pub failures: Vec<String>,
    pub refused: BTreeMap<String, usize>,
}

impl Tally {
    /// Compares one outcome with the brute-force hits `want`; `ctx` names the scene.
    pub fn add(&mut self, ctx: &str, label: &str, o: Outcome, want: &[Hit]) {
        self.methods += 1;
        match o {
            Outcome::Hits(h) => {
                let wrong: Vec<usize> = (0..want.len()).filter(|&i| !same_hit(&h[i], &want[i])).collect();
                self.rays_checked += want.len() as u64;
                if let Some(&i) = wrong.first() {
                    self.failures.push(format!(
                        "{ctx} | {label}: {} wrong hits of {}, first ray {i}: got {:?}, brute force {:?}",
                        wrong.len(),
                        want.len(),
                        h[i],
                        want[i]
                    ));
                }
            }
            Outcome::Refused(e) => {
                assert!(!e.trim().is_empty(), "{ctx} | {label}: empty error message");
                // Group by method (without the scene) and the first words of the reason.
                let m = label.split(" <- ").next().unwrap_or(label);
                *self.refused.entry(format!("{m}: {}", clip(&e))).or_default() += 1;
            }
            Outcome::Invalid(e) => self.failures.push(format!("{ctx} | {label}: invalid: {e}")),
            Outcome::Panic(e) => self.failures.push(format!("{ctx} | {label}: PANIC: {e}")),
        }
    }

    pub fn summary(&self) -> String {
        let mut s = format!(
            "{} method runs, {} rays compared, {} failures, {} refusals\n",
            self.methods,
            self.rays_checked,
            self.failures.len(),
            self.refused.values().sum::<usize>()
        );
        for (k, n) in &self.refused {
            s.push_str(&format!("  refused x{n}: {k}\n"));
        }
        let mut per_scene: BTreeMap<&str, usize> = BTreeMap::new();
        for f in &self.failures {
            *per_scene.entry(f.split(" | ").next().unwrap_or("")).or_default() += 1;
        }
        for (scene, n) in per_scene {
            s.push_str(&format!("  failing methods on {scene}: {n}\n"));
        }
        // The first few failures of each scene.
        let mut shown: BTreeMap<&str, usize> = BTreeMap::new();
        for f in &self.failures {
            let n = shown.entry(f.split(" | ").next().unwrap_or("")).or_default();
            *n += 1;
            if *n <= 4 {
                s.push_str(&format!("  FAIL {f}\n"));
            }
        }
        s
    }
}

fn clip(s: &str) -> String {
    s.chars().take(80).collect()
}
