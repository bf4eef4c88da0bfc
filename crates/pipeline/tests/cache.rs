//! Cache behaviour of the runner, independent of the real loaders/builders: scenes, the builder,
//! metrics, validation and compaction are injected test doubles, so these tests exercise only
//! keys, counting, the store and corruption handling (encode and focus stages included).
use bvhlab_builders::SortedCodes;
use bvhlab_bvh::{Aabb, Bvh, CostParams, Metrics, Node, Vec3};
use bvhlab_geom::{LoadError, Scene, Triangle};
use bvhlab_layout::{bvh2::Bvh2, Layout, LayoutSpec};
use bvhlab_morton::{AutoFor, Bits, EncodeConfig, Encoding, Scheme};
use bvhlab_pipeline::registry::{
    BuilderInfo, Kind, Optimizer, OptimizerInfo, ParamSpec, Resolved, ResolvedOptimizer,
};
use bvhlab_pipeline::stages::Ops;
use bvhlab_pipeline::{ChainSpec, Counts, Key, Registry, ResultRow, Runner, Store, Versions};
use std::path::Path;

/// `gen:grid:n=N` -> N small triangles on a line; anything else fails like a loader would.
fn test_load(spec: &str) -> Result<Scene, LoadError> {
    let n: usize = spec
        .strip_prefix("gen:grid:n=")
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| LoadError {
            file: spec.into(),
            line: None,
            reason: "test loader".into(),
        })?;
    Ok(Scene::from_triangles((0..n).map(|i| {
        let x = i as f32;
        Triangle::new(
            Vec3::new(x, 0.0, 0.0),
            Vec3::new(x + 0.5, 1.0, 0.0),
            Vec3::new(x, 0.0, 1.0),
        )
    })))
}

fn test_build(boxes: &[Aabb], centers: &[Vec3], r: &Resolved) -> Bvh {
    let leaf = r.u32("leaf").max(1) as usize;
    let mut idx: Vec<u32> = (0..boxes.len() as u32).collect();
    let mut nodes = vec![Node::leaf(Aabb::EMPTY, 0, 1)];
    fn rec(
        n: usize,
        lo: usize,
        hi: usize,
        leaf: usize,
        b: &[Aabb],
        c: &[Vec3],
        idx: &mut [u32],
        nodes: &mut Vec<Node>,
    ) {
        let mut bb = Aabb::EMPTY;
        for &i in &idx[lo..hi] {
            bb.grow(&b[i as usize]);
        }
        if hi - lo <= leaf {
            nodes[n] = Node::leaf(bb, lo as u32, (hi - lo) as u32);
            return;
        }
        let axis = bb.largest_axis();
        idx[lo..hi].sort_by(|&a, &b2| {
            c[a as usize][axis]
                .total_cmp(&c[b2 as usize][axis])
                .then(a.cmp(&b2))
        });
        let mid = (lo + hi) / 2;
        let left = nodes.len();
        nodes.push(Node::leaf(Aabb::EMPTY, 0, 1));
        nodes.push(Node::leaf(Aabb::EMPTY, 0, 1));
        nodes[n] = Node::inner(bb, left as u32);
        rec(left, lo, mid, leaf, b, c, idx, nodes);
        rec(left + 1, mid, hi, leaf, b, c, idx, nodes);
    }
    let n = boxes.len();
    rec(0, 0, n, leaf, boxes, centers, &mut idx, &mut nodes);
    Bvh {
        nodes,
        prim_indices: idx,
    }
}

/// Codes = quantized centroid x (bits per the config; EMC: 21), sorted, ties by index.
fn test_encode(
    boxes: &[Aabb],
    centers: &[Vec3],
    cfg: &EncodeConfig,
    _frame: bvhlab_morton::CellFrame,
) -> Encoding {
    let bits = match (cfg.scheme, cfg.bits) {
        (Scheme::Morton, Bits::Fixed(b)) => b,
        (Scheme::Morton, Bits::Auto(AutoFor::Ploc)) => 20,
        (Scheme::Morton, Bits::Auto(_)) => 10,
        _ => 21,
    };
    let codes: Vec<u64> = centers
        .iter()
        .map(|c| (c.x.max(0.0) as u64).min((1u64 << bits) - 1))
        .collect();
    let mut order: Vec<u32> = (0..boxes.len() as u32).collect();
    order.sort_by_key(|&i| (codes[i as usize], i));
    let sorted: Vec<u64> = order.iter().map(|&i| codes[i as usize]).collect();
    Encoding {
        order,
        codes: sorted,
        code_bits: bits,
        frame: Aabb::EMPTY,
        layout: "x".repeat(bits as usize),
    }
}

/// A code-using test builder: one leaf holding every primitive in code order.
fn test_code_build(boxes: &[Aabb], _: &[Vec3], s: Option<&SortedCodes>, _: &Resolved) -> Bvh {
    let s = s.expect("codes");
    let mut b = Aabb::EMPTY;
    for x in boxes {
        b.grow(x);
    }
    Bvh {
        nodes: vec![Node::leaf(b, 0, s.order.len() as u32)],
        prim_indices: s.order.to_vec(),
    }
}

/// Layout double: every layout is stored as a bvh2 (real flat BVH, real traversal) of the input
/// BVH, or for the scene-only layouts (octrees) of one leaf over all triangles.
fn test_layout(
    spec: &LayoutSpec,
    bvh: &Bvh,
    tris: &[Triangle],
    _deadline: Option<std::time::Instant>,
) -> Result<Layout, String> {
    if bvhlab_layout::uses_bvh(&spec.name) {
        assert!(!bvh.nodes.is_empty(), "BVH layouts get the final BVH");
        return Ok(Layout::Bvh2(Bvh2::build(bvh)));
    }
    assert!(
        bvh.nodes.is_empty(),
        "octrees are built from the triangles alone"
    );
    let mut b = Aabb::EMPTY;
    for t in tris {
        b.grow(&t.bounds());
    }
    Ok(Layout::Bvh2(Bvh2::build(&Bvh {
        nodes: vec![Node::leaf(b, 0, tris.len() as u32)],
        prim_indices: (0..tris.len() as u32).collect(),
    })))
}

fn test_metrics(b: &Bvh, cost: CostParams) -> Metrics {
    let leaves = b.nodes.iter().filter(|n| n.is_leaf()).count() as u64;
    Metrics {
        sah_cost: cost.c_t as f64 * b.nodes.len() as f64,
        leaves,
        inner_nodes: b.nodes.len() as u64 - leaves,
        bytes: b.bytes(),
        ..Default::default()
    }
}

fn test_runner(root: &Path, versions: Versions) -> Runner {
    let mut r = Runner::new(Store::open(root).unwrap());
    r.versions = versions;
    r.ops = Ops {
        load: test_load,
        canonical_gen: |g| Ok(g.to_string()),
        metrics: test_metrics,
        validate: |_, _, _| Ok(()),
        // A real change, so compact artifacts differ from build artifacts.
        collapse: |b, _| {
            let mut b = b.clone();
            b.prim_indices.reverse();
            b
        },
        encode: test_encode,
        layout: test_layout,
    };
    let code_builder = |name, auto| {
        BuilderInfo::top_down(name, "test double over codes", vec![], test_code_build).with_codes(auto)
    };
    r.registry = Registry {
        builders: vec![
            BuilderInfo::top_down(
                "test-median",
                "test double",
                vec![
                    ParamSpec {
                        name: "bins",
                        default: "16",
                        kind: Kind::UInt { min: 2, max: 64 },
                        about: "",
                        in_label: true,
                    },
                    ParamSpec {
                        name: "leaf",
                        default: "2",
                        kind: Kind::UInt { min: 1, max: 8 },
                        about: "",
                        in_label: false,
                    },
                ],
                |b, c, _, r| test_build(b, c, r),
            ),
            code_builder("test-codes", AutoFor::Lbvh),
            code_builder("test-codes2", AutoFor::Ploc),
        ],
        encoders: Registry::standard_encoders(),
        optimizers: vec![OptimizerInfo::custom(
            "test-opt",
            "test double: reverses the leaf order `passes` times",
            vec![ParamSpec {
                name: "passes",
                default: "2",
                kind: Kind::UInt { min: 0, max: 9 },
                about: "",
                in_label: true,
            }],
            Optimizer { run: test_optimize },
        )],
        layouts: Registry::standard_layouts(),
    };
    r
}

/// Optimizer double: a changed tree (prim order rotated) and a trace of `passes` passes.
fn test_optimize(b: &Bvh, o: &ResolvedOptimizer) -> bvhlab_opt::Optimized {
    let passes = o.u32("passes");
    let mut bvh = b.clone();
    bvh.prim_indices.rotate_left(1);
    let rec = |pass: u32| bvhlab_opt::PassRecord {
        pass,
        seconds: 0.0,
        sah_cost: 100.0 - pass as f64,
        moved: pass as u64,
        phase: "test".into(),
    };
    bvhlab_opt::Optimized {
        bvh,
        trace: (0..=passes).map(rec).collect(),
        stop: bvhlab_opt::Stop::Converged,
        returned_pass: passes,
    }
}

/// 2 scenes x (bins 4 and 8) x (none, collapse).
fn chains(bins: &[&str]) -> Vec<ChainSpec> {
    let mut out = Vec::new();
    for scene in ["gen:grid:n=50", "gen:grid:n=77"] {
        for b in bins {
            for compact in ["none", "collapse"] {
                let mut c = ChainSpec::new(scene, "test-median");
                c.params.insert("bins".into(), b.to_string());
                c.compact = compact.into();
                c.repeat = 3;
                out.push(c);
            }
        }
    }
    out
}

fn run_all(root: &Path, versions: Versions, chains: &[ChainSpec]) -> (Vec<ResultRow>, Counts) {
    let mut r = test_runner(root, versions);
    let rows = chains
        .iter()
        .map(|c| r.run_chain(c, "t").unwrap())
        .collect();
    (rows, r.counts.clone())
}

fn stage(c: &Counts, s: &str) -> (u64, u64) {
    let x = c.stage(s);
    (x.computed, x.cached)
}

/// Rows without timings (which legitimately change when a stage is recomputed).
fn untimed(rows: &[ResultRow]) -> Vec<ResultRow> {
    rows.iter().map(ResultRow::untimed).collect()
}

#[test]
fn cold_then_warm() {
    let dir = tempfile::tempdir().unwrap();
    let ch = chains(&["4", "8"]);
    let (cold_rows, cold) = run_all(dir.path(), Versions::default(), &ch);
    // 2 loads, 4 builds, 4 compactions.
    assert_eq!((cold.computed, cold.cached), (10, 0));
    assert_eq!(stage(&cold, "load"), (2, 0));
    assert_eq!(stage(&cold, "build"), (4, 0));
    assert_eq!(stage(&cold, "compact"), (4, 0));
    let (warm_rows, warm) = run_all(dir.path(), Versions::default(), &ch);
    assert_eq!((warm.computed, warm.cached), (0, 10));
    assert_eq!(
        warm_rows, cold_rows,
        "cached rows are identical, timings included"
    );
    assert_eq!(cold_rows[0].triangles, 50);
    assert_eq!(cold_rows[0].method, "test-median bins=4");
    assert_eq!(cold_rows[1].method, "test-median bins=4 +collapse");
    assert_ne!(cold_rows[0].bvh_hash, cold_rows[1].bvh_hash);
    // Nothing temporary is left behind.
    for d in std::fs::read_dir(dir.path()).unwrap().flatten() {
        for f in std::fs::read_dir(d.path()).unwrap().flatten() {
            assert!(
                !f.file_name().to_string_lossy().starts_with(".tmp"),
                "{:?}",
                f.path()
            );
        }
    }
}

#[test]
fn default_and_explicit_parameters_share_keys() {
    let dir = tempfile::tempdir().unwrap();
    let mut a = ChainSpec::new("gen:grid:n=10", "test-median");
    a.repeat = 1;
    let mut b = a.clone();
    b.params.insert("bins".into(), "16".into());
    b.params.insert("c_i".into(), "2.0".into());
    let (_, c1) = run_all(dir.path(), Versions::default(), &[a]);
    assert_eq!(c1.computed, 2);
    let (_, c2) = run_all(dir.path(), Versions::default(), &[b]);
    assert_eq!((c2.computed, c2.cached), (0, 2));
}

#[test]
fn changing_one_parameter_recomputes_only_dependents() {
    let dir = tempfile::tempdir().unwrap();
    run_all(dir.path(), Versions::default(), &chains(&["4", "8"]));
    let (_, c) = run_all(dir.path(), Versions::default(), &chains(&["4", "16"]));
    assert_eq!(stage(&c, "load"), (0, 2));
    assert_eq!(stage(&c, "build"), (2, 2), "bins=16 is new in both scenes");
    assert_eq!(stage(&c, "compact"), (2, 2));
    // A cost constant feeds build and compact (and metrics) of every chain.
    let mut ch = chains(&["4"]);
    for c in &mut ch {
        c.params.insert("c_t".into(), "1.5".into());
    }
    let (_, c) = run_all(dir.path(), Versions::default(), &ch);
    assert_eq!(stage(&c, "load"), (0, 2));
    assert_eq!(stage(&c, "build"), (2, 0));
    assert_eq!(stage(&c, "compact"), (2, 0));
}

#[test]
fn version_bump_invalidates_stage_and_downstream_only() {
    let dir = tempfile::tempdir().unwrap();
    let ch = chains(&["4", "8"]);
    run_all(dir.path(), Versions::default(), &ch);
    let v = Versions {
        compact: Versions::default().compact + 1,
        ..Versions::default()
    };
    let (_, c) = run_all(dir.path(), v, &ch);
    assert_eq!(
        (stage(&c, "load"), stage(&c, "build"), stage(&c, "compact")),
        ((0, 2), (0, 4), (4, 0))
    );
    let v = Versions {
        build: Versions::default().build + 1,
        ..Versions::default()
    };
    let (_, c) = run_all(dir.path(), v, &ch);
    assert_eq!(
        (stage(&c, "load"), stage(&c, "build"), stage(&c, "compact")),
        ((0, 2), (4, 0), (4, 0))
    );
    let v = Versions {
        load: Versions::default().load + 1,
        ..Versions::default()
    };
    let (_, c) = run_all(dir.path(), v, &ch);
    assert_eq!((c.computed, c.cached), (10, 0));
}

fn flip_last_byte(p: &Path) {
    let mut b = std::fs::read(p).unwrap();
    let n = b.len() - 1;
    b[n] ^= 0x55;
    std::fs::write(p, b).unwrap();
}

#[test]
fn corrupt_artifacts_are_recomputed_not_used() {
    let dir = tempfile::tempdir().unwrap();
    let ch = chains(&["4"]);
    let (rows, _) = run_all(dir.path(), Versions::default(), &ch);
    let store = Store::open(dir.path()).unwrap();
    let build_key = Key::from_hex(&rows[0].keys["build"]).unwrap();
    let load_key = Key::from_hex(&rows[0].keys["load"]).unwrap();

    // Summary and full artifact of one build both corrupt: the build is recomputed.
    flip_last_byte(&store.path("build", &build_key, "sum"));
    flip_last_byte(&store.path("build", &build_key, "bin"));
    let (rows2, c) = run_all(dir.path(), Versions::default(), &ch);
    assert_eq!(stage(&c, "build"), (1, 1));
    assert_eq!(
        stage(&c, "load"),
        (0, 2),
        "the recomputed build read the intact scene from the cache"
    );
    assert_eq!(untimed(&rows2), untimed(&rows));
    assert!(dir.path().join("quarantine").read_dir().unwrap().count() >= 2);
    // The recomputed entry is whole again.
    assert!(store.verify().bad.is_empty());

    // Only the summary corrupt: it is restored from the intact full artifact (no recompute).
    flip_last_byte(&store.path("build", &build_key, "sum"));
    let (rows3, c) = run_all(dir.path(), Versions::default(), &ch);
    assert_eq!(c.computed, 0);
    assert_eq!(rows3[0].bvh_hash, rows[0].bvh_hash);
    assert!(store.path("build", &build_key, "sum").is_file());
    assert!(store.verify().bad.is_empty());

    // A corrupt scene is recomputed when a build needs it, and verify would have caught it.
    flip_last_byte(&store.path("load", &load_key, "bin"));
    let v = Versions {
        build: Versions::default().build + 1,
        ..Versions::default()
    };
    let (rows4, c) = run_all(dir.path(), v, &ch);
    assert_eq!(stage(&c, "load"), (1, 1));
    assert_eq!(rows4[0].bvh_hash, rows[0].bvh_hash);
}

#[test]
fn verify_finds_corruption_and_next_run_repairs() {
    let dir = tempfile::tempdir().unwrap();
    let ch = chains(&["4"]);
    let (rows, _) = run_all(dir.path(), Versions::default(), &ch);
    let store = Store::open(dir.path()).unwrap();
    let k = Key::from_hex(&rows[1].keys["compact"]).unwrap();
    flip_last_byte(&store.path("compact", &k, "bin"));
    let r = store.verify();
    assert_eq!(r.bad.len(), 1, "{:?}", r.bad);
    assert!(!store.path("compact", &k, "bin").exists());
    // The summary is intact, so a warm run still computes nothing...
    let (_, c) = run_all(dir.path(), Versions::default(), &ch);
    assert_eq!(c.computed, 0);
    // ...and gc removes quarantined files.
    assert!(store.gc().removed_files >= 1);
    assert!(!dir.path().join("quarantine").exists());
}

#[test]
fn manifest_records_provenance() {
    let dir = tempfile::tempdir().unwrap();
    let (rows, _) = run_all(dir.path(), Versions::default(), &chains(&["8"]));
    let store = Store::open(dir.path()).unwrap();
    let bk = Key::from_hex(&rows[1].keys["build"]).unwrap();
    let m = store.read_manifest("build", &bk).unwrap();
    assert_eq!(m.key, bk.hex());
    assert_eq!(m.stage, "build");
    assert_eq!(m.version, Versions::default().build);
    assert_eq!(m.params["bins"], "8");
    assert_eq!(m.params["leaf"], "2");
    assert_eq!(m.params["c_t"], "3");
    assert_eq!(m.params["builder"], "test-median");
    assert_eq!(m.params["repeat"], "3");
    assert_eq!(m.inputs, vec![format!("load:{}", rows[1].keys["load"])]);
    assert!(m.versions.contains_key("bvhlab"));
    assert!(m.machine.cpus >= 1 && !m.machine.os.is_empty());
    assert!(m.time_unix > 1_600_000_000);
    for (ext, h) in &m.files {
        let bytes = std::fs::read(store.path("build", &bk, ext)).unwrap();
        assert_eq!(&blake3::hash(&bytes).to_hex().to_string(), h);
    }
    assert_eq!(m.files.len(), 2);
    let ck = Key::from_hex(&rows[1].keys["compact"]).unwrap();
    let mc = store.read_manifest("compact", &ck).unwrap();
    assert_eq!(mc.inputs, vec![format!("build:{}", bk.hex())]);
    assert_eq!(store.entries().len(), 2 + 2 + 2);
}

#[test]
fn bad_input_is_an_input_error_and_leaves_cache_intact() {
    let dir = tempfile::tempdir().unwrap();
    let ch = chains(&["4"]);
    run_all(dir.path(), Versions::default(), &ch);
    let before = Store::open(dir.path()).unwrap().entries().len();
    let mut r = test_runner(dir.path(), Versions::default());
    let e = r
        .run_chain(&ChainSpec::new("gen:bogus", "test-median"), "t")
        .unwrap_err();
    assert_eq!(e.exit_code(), 2);
    let e = r
        .run_chain(&ChainSpec::new("gen:grid:n=5", "nope"), "t")
        .unwrap_err();
    assert!(e.message().contains("test-median"), "{e}");
    let mut c = ChainSpec::new("gen:grid:n=5", "test-median");
    c.params.insert("bins".into(), "1000".into());
    assert_eq!(r.run_chain(&c, "t").unwrap_err().exit_code(), 2);
    let e = r
        .run_chain(&ChainSpec::new("gen:grid:n=0", "test-median"), "t")
        .unwrap_err();
    assert_eq!(e.exit_code(), 2);
    let e = r
        .run_chain(&ChainSpec::new("/no/such/file.obj", "test-median"), "t")
        .unwrap_err();
    assert!(
        e.message().contains("/no/such/file.obj") && e.exit_code() == 2,
        "{e}"
    );
    assert_eq!(Store::open(dir.path()).unwrap().entries().len(), before);
    let (_, c) = run_all(dir.path(), Versions::default(), &ch);
    assert_eq!(c.computed, 0);
}

#[test]
fn nondeterministic_builder_fails_loudly() {
    use std::sync::atomic::{AtomicU32, Ordering};
    static CALLS: AtomicU32 = AtomicU32::new(0);
    let dir = tempfile::tempdir().unwrap();
    let mut r = test_runner(dir.path(), Versions::default());
    r.registry.builders[0].run = |b, c, _, res| {
        let mut bvh = test_build(b, c, res);
        if CALLS.fetch_add(1, Ordering::SeqCst) % 2 == 1 {
            bvh.prim_indices.swap(0, 1);
        }
        bvh
    };
    let mut c = ChainSpec::new("gen:grid:n=20", "test-median");
    c.repeat = 3;
    let e = r.run_chain(&c, "t").unwrap_err();
    assert!(e.message().contains("not deterministic"), "{e}");
    assert_eq!(e.exit_code(), 1);
}

// ---- encode and focus stages -------------------------------------------------------------------

fn code_chain(
    build: &str,
    encode: Option<&str>,
    params: &[(&str, &str)],
    compact: &str,
) -> ChainSpec {
    let mut c = ChainSpec::new("gen:grid:n=40", build);
    c.encode = encode.map(str::to_string);
    c.params = params
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    c.compact = compact.into();
    c.repeat = 3;
    c
}

#[test]
fn encode_stage_cold_warm_and_row_fields() {
    let dir = tempfile::tempdir().unwrap();
    let ch = vec![
        code_chain("test-codes", None, &[], "none"),
        code_chain("test-codes", Some("morton"), &[], "collapse"),
    ];
    let (rows, c) = run_all(dir.path(), Versions::default(), &ch);
    // `encode = None` means morton: both chains share load, encode and build.
    assert_eq!(
        (
            stage(&c, "load"),
            stage(&c, "encode"),
            stage(&c, "build"),
            stage(&c, "compact")
        ),
        ((1, 0), (1, 0), (1, 0), (1, 0))
    );
    let r = &rows[0];
    assert_eq!(r.encoder.as_deref(), Some("morton"));
    assert_eq!(
        r.encode_params.as_deref(),
        Some("bits=auto:lbvh,bounds=scene,grid_bits=0")
    );
    assert_eq!(r.code_bits, Some(10));
    assert_eq!(
        r.duplicate_code_fraction,
        Some(0.0),
        "x = 0..39 are distinct codes"
    );
    let enc = r.encode_seconds.unwrap();
    assert!(enc > 0.0);
    assert_eq!(r.total_build_seconds, enc + r.build_seconds);
    assert_eq!(r.method, "test-codes \u{b7} morton");
    assert_eq!(rows[1].method, "test-codes \u{b7} morton +collapse");
    assert!(r.keys.contains_key("encode"));
    // The build applied the (test) compaction of bottom-up builders: code order reversed.
    let store = Store::open(dir.path()).unwrap();
    let m = store
        .read_manifest("build", &Key::from_hex(&r.keys["build"]).unwrap())
        .unwrap();
    assert_eq!(
        m.inputs,
        vec![
            format!("load:{}", r.keys["load"]),
            format!("encode:{}", r.keys["encode"])
        ]
    );
    let em = store
        .read_manifest("encode", &Key::from_hex(&r.keys["encode"]).unwrap())
        .unwrap();
    assert_eq!(em.params["encoder"], "morton");
    assert_eq!(em.params["bits"], "auto:lbvh");
    assert_eq!(em.inputs, vec![format!("load:{}", r.keys["load"])]);

    let (warm_rows, w) = run_all(dir.path(), Versions::default(), &ch);
    assert_eq!((w.computed, w.cached), (0, 4));
    assert_eq!(warm_rows, rows);
    assert!(store.verify().bad.is_empty());
}

#[test]
fn encoder_parameter_change_recomputes_encode_and_downstream_only() {
    let dir = tempfile::tempdir().unwrap();
    run_all(
        dir.path(),
        Versions::default(),
        &[code_chain("test-codes", None, &[], "collapse")],
    );
    let (rows, c) = run_all(
        dir.path(),
        Versions::default(),
        &[code_chain("test-codes", None, &[("bits", "4")], "collapse")],
    );
    assert_eq!(
        (
            stage(&c, "load"),
            stage(&c, "encode"),
            stage(&c, "build"),
            stage(&c, "compact")
        ),
        ((0, 1), (1, 0), (1, 0), (1, 0))
    );
    assert_eq!(rows[0].code_bits, Some(4));
    assert!(
        rows[0].duplicate_code_fraction.unwrap() > 0.5,
        "x >= 15 all share the top code"
    );
    assert_eq!(rows[0].method, "test-codes \u{b7} morton bits=4 +collapse");
    // An explicit default spelling shares the keys.
    let (_, c) = run_all(
        dir.path(),
        Versions::default(),
        &[code_chain(
            "test-codes",
            Some("morton"),
            &[("bits", "auto"), ("grid_bits", "0")],
            "collapse",
        )],
    );
    assert_eq!(c.computed, 0);
    // A builder parameter (cost) changes build and compact, not encode.
    let (_, c) = run_all(
        dir.path(),
        Versions::default(),
        &[code_chain(
            "test-codes",
            None,
            &[("c_t", "1.5")],
            "collapse",
        )],
    );
    assert_eq!(
        (
            stage(&c, "encode"),
            stage(&c, "build"),
            stage(&c, "compact")
        ),
        ((0, 1), (1, 0), (1, 0))
    );
    // Another encoder: new encode node.
    let (rows, c) = run_all(
        dir.path(),
        Versions::default(),
        &[code_chain("test-codes", Some("emc64-var"), &[], "none")],
    );
    assert_eq!(
        (stage(&c, "load"), stage(&c, "encode"), stage(&c, "build")),
        ((0, 1), (1, 0), (1, 0))
    );
    assert_eq!(
        rows[0].encode_params.as_deref(),
        Some("bounds=scene,grid_bits=0")
    );
    // EMC has no bits: another builder with another `auto` shares the encode node...
    let (_, c) = run_all(
        dir.path(),
        Versions::default(),
        &[code_chain("test-codes2", Some("emc64-var"), &[], "none")],
    );
    assert_eq!((stage(&c, "encode"), stage(&c, "build")), ((0, 1), (1, 0)));
    // ...while morton bits=auto resolves per builder (auto:ploc is a new encode node).
    let (rows, c) = run_all(
        dir.path(),
        Versions::default(),
        &[code_chain("test-codes2", None, &[], "none")],
    );
    assert_eq!(stage(&c, "encode"), (1, 0));
    assert_eq!(
        rows[0].encode_params.as_deref(),
        Some("bits=auto:ploc,bounds=scene,grid_bits=0")
    );
    // An encode version bump invalidates encode and downstream, not load.
    let v = Versions {
        encode: Versions::default().encode + 1,
        ..Versions::default()
    };
    let (_, c) = run_all(
        dir.path(),
        v,
        &[code_chain("test-codes", None, &[], "collapse")],
    );
    assert_eq!(
        (
            stage(&c, "load"),
            stage(&c, "encode"),
            stage(&c, "build"),
            stage(&c, "compact")
        ),
        ((0, 1), (1, 0), (1, 0), (1, 0))
    );
}

#[test]
fn encode_errors_are_input_errors() {
    let dir = tempfile::tempdir().unwrap();
    let mut r = test_runner(dir.path(), Versions::default());
    let e = r
        .run_chain(&code_chain("test-median", Some("morton"), &[], "none"), "t")
        .unwrap_err();
    assert!(
        e.exit_code() == 2 && e.message().contains("takes no codes"),
        "{e}"
    );
    let e = r
        .run_chain(&code_chain("test-codes", Some("zorder"), &[], "none"), "t")
        .unwrap_err();
    assert!(
        e.exit_code() == 2 && e.message().contains("emc64-var"),
        "{e}"
    );
    let e = r
        .run_chain(
            &code_chain("test-codes", Some("emc64-sort"), &[("bits", "8")], "none"),
            "t",
        )
        .unwrap_err();
    assert!(e.exit_code() == 2 && e.message().contains("bits"), "{e}");
    assert_eq!(r.counts.computed, 0);
}

#[test]
fn focus_stage_is_cached_and_keyed_by_box() {
    let dir = tempfile::tempdir().unwrap();
    let focus = |lo: f32, hi: f32| {
        Some(Aabb::new(
            Vec3::new(lo, -1.0, -1.0),
            Vec3::new(hi, 2.0, 2.0),
        ))
    };
    let mut a = ChainSpec::new("gen:grid:n=30", "test-median");
    a.repeat = 1;
    let plain = run_all(dir.path(), Versions::default(), &[a.clone()]).0;
    assert_eq!(
        (plain[0].focus_triangles, plain[0].focus_sah_cost),
        (None, None)
    );
    assert!(!plain[0].keys.contains_key("focus"));
    a.focus = focus(10.0, 12.0);
    let (rows, c) = run_all(dir.path(), Versions::default(), &[a.clone()]);
    assert_eq!((stage(&c, "build"), stage(&c, "focus")), ((0, 1), (1, 0)));
    // Centroids x = 10.25, 11.25 are inside (x + 0.25 for the triangles of the test loader).
    assert_eq!(rows[0].focus_triangles, Some(2));
    let cost = rows[0].focus_sah_cost.unwrap();
    assert!(cost.is_finite() && cost > 0.0, "{cost}");
    let (warm, c) = run_all(dir.path(), Versions::default(), &[a.clone()]);
    assert_eq!(c.computed, 0);
    assert_eq!(warm, rows);
    // A focus box holding no centroid: counted, no cost.
    a.focus = focus(100.0, 120.0);
    let (rows, c) = run_all(dir.path(), Versions::default(), &[a.clone()]);
    assert_eq!(stage(&c, "focus"), (1, 0));
    assert_eq!(
        (rows[0].focus_triangles, rows[0].focus_sah_cost),
        (Some(0), None)
    );
    // With compaction the focus is measured on the compacted BVH (another key).
    a.focus = focus(10.0, 12.0);
    a.compact = "collapse".into();
    let (rows2, c) = run_all(dir.path(), Versions::default(), &[a]);
    assert_eq!(stage(&c, "focus"), (1, 0));
    assert_ne!(rows2[0].keys["focus"], rows[0].keys["focus"]);
}

/// The optimize stage sits between build and compact: cached like the others, its trace read back
/// from the cache, and an optimizer parameter re-runs only optimize and what follows.
#[test]
fn optimize_stage_is_cached_and_keyed() {
    let dir = tempfile::tempdir().unwrap();
    let mk = |passes: &str, compact: &str| {
        let mut c = ChainSpec::new("gen:grid:n=40", "test-median");
        c.optimize = Some("test-opt".into());
        c.params.insert("passes".into(), passes.into());
        c.compact = compact.into();
        c.repeat = 2;
        c
    };
    let ch = [mk("2", "none"), mk("2", "collapse")];
    let (cold_rows, cold) = run_all(dir.path(), Versions::default(), &ch);
    assert_eq!(
        (
            stage(&cold, "build"),
            stage(&cold, "optimize"),
            stage(&cold, "compact")
        ),
        ((1, 0), (1, 0), (1, 0))
    );
    let r = &cold_rows[1];
    assert_eq!(r.optimizer.as_deref(), Some("test-opt"));
    assert_eq!(r.optimize_params.as_deref(), Some("passes=2"));
    assert_eq!(r.optimize_passes, Some(2));
    assert_eq!(r.optimize_stop.as_deref(), Some("converged"));
    assert_eq!(r.optimize_trace.as_ref().map(|t| t.len()), Some(3));
    assert_eq!(r.method, "test-median bins=16 +test-opt 2 +collapse");
    assert!(r.keys.contains_key("optimize"));
    assert_ne!(
        cold_rows[0].bvh_hash, cold_rows[1].bvh_hash,
        "compaction reads the optimized tree"
    );
    assert_eq!(
        r.total_build_seconds,
        r.build_seconds + r.optimize_seconds.unwrap()
    );
    let (warm_rows, warm) = run_all(dir.path(), Versions::default(), &ch);
    assert_eq!(warm.computed, 0);
    assert_eq!(
        warm_rows, cold_rows,
        "trace and rows come back from the cache"
    );
    // A new optimizer parameter: optimize and compact recompute, build is reused.
    let (_, c) = run_all(dir.path(), Versions::default(), &[mk("3", "collapse")]);
    assert_eq!(
        (
            stage(&c, "build"),
            stage(&c, "optimize"),
            stage(&c, "compact")
        ),
        ((0, 1), (1, 0), (1, 0))
    );
    // A lost trace file recomputes the optimize stage, with a correct row.
    for f in std::fs::read_dir(dir.path().join("optimize"))
        .unwrap()
        .flatten()
    {
        if f.path().extension().is_some_and(|e| e == "opt") {
            std::fs::remove_file(f.path()).unwrap();
        }
    }
    let (rows, c) = run_all(dir.path(), Versions::default(), &ch[..1]);
    assert_eq!(stage(&c, "optimize"), (1, 0));
    assert_eq!(untimed(&rows), untimed(&cold_rows[..1]));
    // Unknown optimizer parameters and optimizers are input errors naming the valid ones.
    let mut bad = mk("2", "none");
    bad.params.insert("pt".into(), "3".into());
    let mut r = test_runner(dir.path(), Versions::default());
    let e = r.run_chain(&bad, "t").unwrap_err();
    assert!(e.message().contains("optimizer parameters: passes"), "{e}");
    let mut bad = mk("2", "none");
    bad.optimize = Some("annealing".into());
    let e = r.run_chain(&bad, "t").unwrap_err();
    assert!(e.message().contains("valid optimizers: test-opt"), "{e}");
}

// ---- layout stage -------------------------------------------------------------------------------

fn layout_chain(builder_bins: &str, layout: &str, rays: bool) -> ChainSpec {
    let mut c = ChainSpec::new("gen:grid:n=60", "test-median");
    c.params.insert("bins".into(), builder_bins.into());
    c.layout = Some(layout.into());
    c.rays = rays.then_some(bvhlab_pipeline::RaySpec::Random { count: 200 });
    c.repeat = 3;
    c
}

#[test]
fn layout_keys_follow_name_params_and_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let ch = vec![
        layout_chain("4", "bvh2", false),
        layout_chain("4", "qbvh_chunks", false),
        layout_chain("4", "qbvh_chunks:chunk_bytes=64", false), // the default, spelled out
        layout_chain("4", "qbvh_chunks:chunk_bytes=128", false),
        layout_chain("4", "qbvh_chunks:frame=parent", false),
        layout_chain("8", "qbvh_chunks", false), // another BVH
        layout_chain("4", "octree", false),
        layout_chain("8", "octree", false), // octrees ignore the BVH: same node
        layout_chain("4", "octree_1bit:chunk_bytes=32", false),
    ];
    let (rows, c) = run_all(dir.path(), Versions::default(), &ch);
    let k: Vec<&str> = rows.iter().map(|r| r.keys["layout"].as_str()).collect();
    assert_eq!(k[1], k[2], "explicit default shares the key");
    assert_eq!(k[6], k[7], "octree key independent of the builder");
    let mut distinct = k.clone();
    distinct.sort();
    distinct.dedup();
    assert_eq!(distinct.len(), 7);
    assert_eq!(stage(&c, "layout"), (7, 0));
    assert_eq!(stage(&c, "build"), (2, 0));
    // The octree node's manifest lists the scene as its only input.
    let store = Store::open(dir.path()).unwrap();
    let m = store
        .read_manifest("layout", &Key::from_hex(k[6]).unwrap())
        .unwrap();
    assert_eq!(m.inputs, vec![format!("load:{}", rows[6].keys["load"])]);
    assert_eq!(m.params["layout"], "octree");
    let m = store
        .read_manifest("layout", &Key::from_hex(k[1]).unwrap())
        .unwrap();
    assert!(m
        .inputs
        .contains(&format!("build:{}", rows[1].keys["build"])));
    // Row fields.
    let r = &rows[0];
    assert_eq!(r.layout.as_deref(), Some("bvh2"));
    assert_eq!(r.layout_params.as_deref(), Some(""));
    assert_eq!(r.topology_bytes, Some(32 * (r.inner_nodes + r.leaves)));
    assert_eq!(
        r.total_bytes,
        Some(32 * (r.inner_nodes + r.leaves) + 4 * 60)
    );
    assert_eq!(r.layout_nodes, Some(r.inner_nodes + r.leaves));
    assert_eq!(r.topology_bits_per_node, Some(256.0));
    assert_eq!(r.prim_refs, Some(60));
    assert_eq!((r.chunks, r.chunk_fill), (Some(0), Some(0.0)));
    assert!(r.layout_seconds.is_some() && r.peak_build_bytes.is_some());
    assert!(r.valid);
    assert_eq!(r.slowdown, None, "no rays, no trace");
    assert!(r.method.ends_with(" @bvh2"), "{}", r.method);
    assert_eq!(
        rows[3].layout_params.as_deref(),
        Some("bits=8,chunk_bytes=128,frame=chunk")
    );
    assert!(
        rows[3]
            .method
            .ends_with(" @qbvh_chunks bits=8,chunk_bytes=128,frame=chunk"),
        "{}",
        rows[3].method
    );
    // Warm: nothing computed, rows identical.
    let (warm, c) = run_all(dir.path(), Versions::default(), &ch);
    assert_eq!(c.computed, 0);
    assert_eq!(warm, rows);
}

#[test]
fn layout_with_rays_warm_lost_bin_and_version_bump() {
    let dir = tempfile::tempdir().unwrap();
    let ch = vec![
        layout_chain("4", "bvh2", true),
        layout_chain("4", "qbvh_chunks:bits=6", true),
    ];
    let (rows, c) = run_all(dir.path(), Versions::default(), &ch);
    assert_eq!(
        (stage(&c, "layout"), stage(&c, "measure")),
        ((2, 0), (2, 0))
    );
    let r = &rows[0];
    assert!(r.slowdown.unwrap() > 0.0 && r.bvh2_trace_seconds.unwrap() > 0.0);
    assert_eq!(r.extra_box_hits_per_ray, Some(0.0));
    assert_eq!(r.extra_tests_per_ray, Some(0.0));
    assert_ne!(rows[0].keys["measure"], rows[1].keys["measure"]);
    // The same chain without a layout has another measure node (and no layout fields).
    let mut plain = layout_chain("4", "bvh2", true);
    plain.layout = None;
    let (p, _) = run_all(dir.path(), Versions::default(), &[plain]);
    assert_ne!(p[0].keys["measure"], rows[0].keys["measure"]);
    assert!(p[0].layout.is_none() && p[0].slowdown.is_none() && !p[0].keys.contains_key("layout"));
    assert_eq!(p[0].traversal_steps_per_ray, r.traversal_steps_per_ray);

    // Warm: only summaries are read.
    let (warm, c) = run_all(dir.path(), Versions::default(), &ch);
    assert_eq!(c.computed, 0);
    assert_eq!(warm, rows);

    // The layout's full artifact lost and the measure summary gone: measure needs the layout,
    // so it is rebuilt (the summary was still readable: counted once, as computed).
    let store = Store::open(dir.path()).unwrap();
    let lk = Key::from_hex(&rows[0].keys["layout"]).unwrap();
    let mk = Key::from_hex(&rows[0].keys["measure"]).unwrap();
    std::fs::remove_file(store.path("layout", &lk, "bin")).unwrap();
    std::fs::remove_file(store.path("measure", &mk, "json")).unwrap();
    let (again, c) = run_all(dir.path(), Versions::default(), &ch);
    assert_eq!(
        (
            stage(&c, "layout"),
            stage(&c, "measure"),
            stage(&c, "build")
        ),
        ((1, 1), (1, 1), (0, 1))
    );
    assert!(store.path("layout", &lk, "bin").is_file());
    assert_eq!(again[0].layout_params, rows[0].layout_params);
    assert_eq!(again[0].hits, rows[0].hits);

    // Bumping the layout version recomputes layout and measure only.
    let v = Versions {
        layout: Versions::default().layout + 1,
        ..Versions::default()
    };
    let (_, c) = run_all(dir.path(), v, &ch);
    assert_eq!(
        (
            stage(&c, "load"),
            stage(&c, "build"),
            stage(&c, "layout"),
            stage(&c, "measure")
        ),
        ((0, 1), (0, 1), (2, 0), (2, 0))
    );
}

#[test]
fn layout_input_errors() {
    let dir = tempfile::tempdir().unwrap();
    let mut r = test_runner(dir.path(), Versions::default());
    for bad in [
        "zip",
        "qbvh_chunks:chunk_bytes",
        "bvh2:bits=8",
        "auto:max_slowdown=0",
    ] {
        let e = r
            .run_chain(&layout_chain("4", bad, false), "t")
            .unwrap_err();
        assert_eq!(e.exit_code(), 2, "{bad}: {e}");
    }
    assert_eq!(r.counts.computed, 0, "nothing runs for a bad spec");
}

/// `run_all` with the runner's registry changed by `bump` first.
fn run_bumped(
    root: &Path,
    bump: impl Fn(&mut Registry),
    chains: &[ChainSpec],
) -> (Vec<ResultRow>, Counts) {
    let mut r = test_runner(root, Versions::default());
    bump(&mut r.registry);
    let rows = chains
        .iter()
        .map(|c| r.run_chain(c, "t").unwrap())
        .collect();
    (rows, r.counts.clone())
}

/// Per-method versions (issue 17): a builder, encoder or optimizer carries its own version, part
/// of its stage's key; bumping one recomputes that method's nodes and what is downstream of them,
/// nothing else.
#[test]
fn method_version_bump_recomputes_only_that_method() {
    let dir = tempfile::tempdir().unwrap();
    let mut opt = code_chain("test-median", None, &[], "none");
    opt.optimize = Some("test-opt".into());
    let ch = vec![
        code_chain("test-median", None, &[], "collapse"),
        code_chain("test-codes", Some("morton"), &[], "collapse"),
        code_chain("test-codes2", Some("emc64-var"), &[], "collapse"),
        opt,
    ];
    let (rows, c) = run_bumped(dir.path(), |_| {}, &ch);
    let counts =
        |c: &Counts| ["load", "encode", "build", "optimize", "compact"].map(|s| stage(c, s));
    // 1 load, 2 encodes, 3 builds (the optimizer's shares test-median's), 1 optimize, 3 compacts.
    assert_eq!(counts(&c), [(1, 0), (2, 0), (3, 0), (1, 0), (3, 0)]);
    // Version 1 adds nothing to a key (keys written before per-method versions stay valid).
    let store = Store::open(dir.path()).unwrap();
    let manifest = |row: &ResultRow, s: &str| {
        store
            .read_manifest(s, &Key::from_hex(&row.keys[s]).unwrap())
            .unwrap()
    };
    assert!(!manifest(&rows[1], "build")
        .params
        .contains_key("method_version"));

    let builder = |name: &'static str, v: u32| {
        move |reg: &mut Registry| {
            reg.builders
                .iter_mut()
                .find(|b| b.name == name)
                .unwrap()
                .version = v
        }
    };
    let (bumped, c) = run_bumped(dir.path(), builder("test-codes", 2), &ch);
    assert_eq!(counts(&c), [(0, 1), (0, 2), (1, 2), (0, 1), (1, 2)]);
    assert_eq!(manifest(&bumped[1], "build").params["method_version"], "2");
    for (i, (a, b)) in rows.iter().zip(&bumped).enumerate() {
        for (s, k) in &a.keys {
            let changed = i == 1 && (s == "build" || s == "compact");
            assert_eq!(k != &b.keys[s], changed, "chain {i} stage {s}");
        }
    }
    let results = |rows: &[ResultRow]| -> Vec<ResultRow> {
        rows.iter()
            .map(|r| ResultRow {
                keys: Default::default(),
                ..r.untimed()
            })
            .collect()
    };
    assert_eq!(
        results(&bumped),
        results(&rows),
        "the same results under new keys"
    );
    // Bumped again (a second change of the same builder): computed again; back to 1: cached.
    let (_, c) = run_bumped(dir.path(), builder("test-codes", 3), &ch);
    assert_eq!(stage(&c, "build"), (1, 2));
    let (_, c) = run_bumped(dir.path(), builder("test-codes", 1), &ch);
    assert_eq!(c.computed, 0);

    // An encoder: its encode nodes and what reads them; the other encoder's chain is untouched.
    let (_, c) = run_bumped(
        dir.path(),
        |reg| {
            reg.encoders
                .iter_mut()
                .find(|e| e.name == "morton")
                .unwrap()
                .version = 2
        },
        &ch,
    );
    assert_eq!(counts(&c), [(0, 1), (1, 1), (1, 2), (0, 1), (1, 2)]);
    // An optimizer: its optimize node only (the chain has no compaction after it).
    let (_, c) = run_bumped(dir.path(), |reg| reg.optimizers[0].version = 2, &ch);
    assert_eq!(counts(&c), [(0, 1), (0, 2), (0, 3), (1, 0), (0, 3)]);
}

/// With the real registry: bumping one builder's version changes that builder's build keys (and
/// those downstream of them) and no other builder's; load and encode keys stay the same.
#[test]
fn builder_version_changes_only_its_build_keys() {
    let dir = tempfile::tempdir().unwrap();
    let mut r = Runner::new(Store::open(dir.path()).unwrap());
    let mut ch = Vec::new();
    for scene in ["gen:sphere:n=100", "gen:terrain"] {
        for (b, e) in [
            ("binned-sah", None),
            ("sweep-sah", None),
            ("spatial-median", None),
            ("lbvh", Some("morton")),
            ("ploc", Some("emc64-var")),
            ("aac", Some("emc64-var")),
        ] {
            let mut c = ChainSpec::new(scene, b);
            c.encode = e.map(str::to_string);
            c.compact = "collapse".into();
            c.layout = Some("qbvh_chunks".into());
            c.rays = Some(bvhlab_pipeline::RaySpec::Random { count: 100 });
            ch.push(c.clone());
            c.optimize = Some("ibo".into());
            c.layout = None;
            ch.push(c);
        }
    }
    let nodes = |r: &mut Runner| -> Vec<Vec<(&'static str, Key)>> {
        ch.iter()
            .map(|c| {
                r.chain_nodes(c)
                    .unwrap()
                    .into_iter()
                    .map(|n| (n.stage, n.key))
                    .collect()
            })
            .collect()
    };
    let before = nodes(&mut r);
    for bumped in ["sweep-sah", "ploc"] {
        let mut r = Runner::new(Store::open(dir.path()).unwrap());
        r.registry
            .builders
            .iter_mut()
            .find(|b| b.name == bumped)
            .unwrap()
            .version += 1;
        let after = nodes(&mut r);
        for ((c, a), b) in ch.iter().zip(&before).zip(&after) {
            assert_eq!(a.len(), b.len());
            for ((s, ka), (_, kb)) in a.iter().zip(b) {
                // The build and everything after it in the bumped builder's chains; nothing else.
                let changed = c.build == bumped && !matches!(*s, "load" | "encode");
                assert_eq!(ka != kb, changed, "{bumped}: {} {} {s}", c.scene, c.build);
            }
        }
    }
}

/// Layouts carry their own versions too (`Method::version` of their METHOD): bumping one changes the layout
/// nodes of that layout and of `auto` (which may choose it), and what reads them (measure), only.
#[test]
fn layout_version_changes_only_its_layout_keys() {
    let dir = tempfile::tempdir().unwrap();
    let layouts = [
        "bvh2",
        "qbvh_chunks",
        "octree",
        "octree_1bit",
        "auto:max_slowdown=1.5,rays=500",
    ];
    let ch: Vec<ChainSpec> = layouts
        .iter()
        .map(|l| {
            let mut c = ChainSpec::new("gen:sphere:n=100", "binned-sah");
            c.layout = Some(l.to_string());
            c.rays = Some(bvhlab_pipeline::RaySpec::Random { count: 100 });
            c
        })
        .collect();
    // A layout's version is its METHOD's (`Method::version`), read from the runner's registry.
    let nodes = |bump: Option<&str>| -> Vec<Vec<(&'static str, Key)>> {
        let mut r = Runner::new(Store::open(dir.path()).unwrap());
        if let Some(name) = bump {
            r.registry.layouts.iter_mut().find(|l| l.name == name).unwrap().version = 2;
        }
        ch.iter()
            .map(|c| {
                let n = r.chain_nodes(c).unwrap();
                n.into_iter().map(|n| (n.stage, n.key)).collect()
            })
            .collect()
    };
    let before = nodes(None);
    // Version 1 adds nothing to the keys: the same keys as before layouts carried versions (for the
    // layouts of this test and of `auto`'s candidates; bvh4, bvh8 and cwbvh have their own).
    let r = Runner::new(Store::open(dir.path()).unwrap());
    assert!(
        r.registry
            .layouts
            .iter()
            .filter(|l| matches!(l.name, "bvh2" | "qbvh_chunks" | "octree" | "octree_1bit"))
            .all(|l| l.version == 1),
        "bump the expected keys with a layout's version"
    );
    let after = nodes(Some("octree_1bit"));
    for ((l, a), b) in layouts.iter().zip(&before).zip(&after) {
        for ((s, ka), (_, kb)) in a.iter().zip(b) {
            let changed = (l.starts_with("octree_1bit") || l.starts_with("auto"))
                && matches!(*s, "layout" | "measure");
            assert_eq!(ka != kb, changed, "{l} {s}");
        }
    }
}
