//! End-to-end tests of the `bvhlab` binary.
use std::path::Path;
use std::process::{Command, Output};

fn bvhlab(args: &[&str], cwd: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_bvhlab"))
        .args(args)
        .current_dir(cwd)
        .env_remove("BVHLAB_CACHE")
        .output()
        .unwrap()
}

fn stdout_json(o: &Output) -> serde_json::Value {
    let s = String::from_utf8_lossy(&o.stdout);
    let last = s
        .lines()
        .last()
        .unwrap_or_else(|| panic!("no stdout; stderr: {}", String::from_utf8_lossy(&o.stderr)));
    serde_json::from_str(last).unwrap_or_else(|e| panic!("{e}: {last}"))
}

const REQUIRED: [&str; 13] = [
    "triangles",
    "dropped_triangles",
    "sah_cost",
    "build_seconds",
    "valid",
    "inner_nodes",
    "leaves",
    "refs_per_leaf",
    "inner_sa_ratio",
    "leaf_sa_ratio",
    "bytes",
    "bvh_hash",
    "computed",
];

#[test]
fn eval_json_has_required_keys() {
    let dir = tempfile::tempdir().unwrap();
    let o = bvhlab(
        &[
            "eval",
            "--scene",
            "gen:sphere",
            "--build",
            "binned-sah",
            "--json",
            "--no-cache",
        ],
        dir.path(),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v = stdout_json(&o);
    for k in REQUIRED {
        assert!(v.get(k).is_some(), "missing {k}: {v}");
    }
    assert!(v["triangles"].as_u64().unwrap() > 1000);
    assert_eq!(v["valid"], true);
    assert_eq!(v["bvh_hash"].as_str().unwrap().len(), 64);
    assert!(v["sah_cost"].as_f64().unwrap() > 0.0);
    assert!(
        !dir.path().join("cache").exists(),
        "--no-cache writes no cache"
    );
}

#[test]
fn eval_with_rays_and_cache() {
    let dir = tempfile::tempdir().unwrap();
    let args = [
        "eval",
        "--scene",
        "gen:sphere:n=2000",
        "--build",
        "sweep-sah",
        "--compact",
        "collapse",
        "--set",
        "leaf=1",
        "--rays",
        "primary:64x48",
        "--repeat",
        "2",
        "--cache",
        "c",
        "--json",
    ];
    let o = bvhlab(&args, dir.path());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v = stdout_json(&o);
    for k in [
        "rays",
        "hits",
        "traversal_steps_per_ray",
        "intersections_per_ray",
        "trace_seconds",
        "mrays_per_s",
    ] {
        assert!(v[k].is_number(), "{k}: {v}");
    }
    assert_eq!(v["rays"], 64 * 48);
    assert!(v["hits"].as_u64().unwrap() > 0);
    assert_eq!(v["computed"], 4);
    let heat = v["heatmap"].as_str().unwrap();
    assert!(
        dir.path().join(heat).is_file() || Path::new(heat).is_file(),
        "{heat}"
    );
    // Warm: identical result, nothing computed.
    let w = stdout_json(&bvhlab(&args, dir.path()));
    assert_eq!(w["computed"], 0);
    assert_eq!(w["cached"], 4);
    assert_eq!(w["bvh_hash"], v["bvh_hash"]);
    assert_eq!(w["trace_seconds"], v["trace_seconds"]);
    let o = bvhlab(&["cache", "verify", "--cache", "c"], dir.path());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stdout));
    let o = bvhlab(&["cache", "ls", "--cache", "c"], dir.path());
    assert!(String::from_utf8_lossy(&o.stdout).contains("measure"));
}

#[test]
fn same_bvh_at_any_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    for build in ["spatial-median", "sweep-sah", "binned-sah"] {
        let hash = |t: &str| {
            let o = bvhlab(
                &[
                    "eval",
                    "--scene",
                    "gen:hairball:n=20000",
                    "--build",
                    build,
                    "--threads",
                    t,
                    "--repeat",
                    "1",
                    "--no-cache",
                    "--json",
                ],
                dir.path(),
            );
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
            stdout_json(&o)["bvh_hash"].as_str().unwrap().to_string()
        };
        assert_eq!(hash("1"), hash("2"), "{build}");
    }
}

fn assert_input_error(o: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "stderr: {err}");
    assert!(err.starts_with("error: "), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    for n in needles {
        assert!(err.contains(n), "`{n}` not in: {err}");
    }
}

#[test]
fn bad_input_exits_2_with_a_clear_message() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("bad.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nv 1 2 banana\n",
    )
    .unwrap();
    let o = bvhlab(
        &[
            "eval",
            "--scene",
            "bad.obj",
            "--build",
            "sweep-sah",
            "--json",
        ],
        dir.path(),
    );
    assert_input_error(&o, &["bad.obj:5"]);
    let o = bvhlab(
        &[
            "eval",
            "--scene",
            "missing.obj",
            "--build",
            "sweep-sah",
            "--json",
        ],
        dir.path(),
    );
    assert_input_error(&o, &["missing.obj"]);
    let o = bvhlab(
        &[
            "eval",
            "--scene",
            "gen:sphere",
            "--build",
            "magic",
            "--no-cache",
        ],
        dir.path(),
    );
    assert_input_error(&o, &["magic", "binned-sah", "sweep-sah", "spatial-median"]);
    let o = bvhlab(
        &[
            "eval",
            "--scene",
            "gen:sphere",
            "--build",
            "binned-sah",
            "--set",
            "bins=1",
            "--no-cache",
        ],
        dir.path(),
    );
    assert_input_error(&o, &["bins"]);
    let o = bvhlab(
        &[
            "eval",
            "--scene",
            "gen:sphere",
            "--build",
            "sweep-sah",
            "--set",
            "bins=8",
            "--no-cache",
        ],
        dir.path(),
    );
    assert_input_error(&o, &["bins", "leaf"]);
    let o = bvhlab(
        &[
            "eval",
            "--scene",
            "gen:nope",
            "--build",
            "sweep-sah",
            "--no-cache",
        ],
        dir.path(),
    );
    assert_input_error(&o, &["nope"]);
    let o = bvhlab(
        &[
            "eval",
            "--scene",
            "gen:sphere",
            "--build",
            "sweep-sah",
            "--rays",
            "laser",
            "--no-cache",
        ],
        dir.path(),
    );
    assert_input_error(&o, &["laser"]);
    std::fs::write(
        dir.path().join("x.toml"),
        "name = \"x\"\nscenes = [\"gen:sphere\"]\n[[chain]]\nbuild = 3\nbins = [4,\n",
    )
    .unwrap();
    let o = bvhlab(&["sweep", "x.toml", "--cache", "c"], dir.path());
    assert_input_error(&o, &["x.toml:"]);
    // The failed runs left the cache untouched (only the OBJ attempt could have created it).
    assert!(!dir.path().join("c").join("load").exists());
}

#[test]
fn sweep_cold_then_warm() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("tiny.toml"),
        r#"name = "tiny"
scenes = ["gen:sphere:n=2000", "gen:city:blocks=5"]
repeat = 2
[[chain]]
build = "binned-sah"
bins = [4, 8]
[[chain]]
build = "sweep-sah"
compact = "collapse"
[rays]
sets = ["primary:32x32", "random:1000"]
"#,
    )
    .unwrap();
    let args = ["sweep", "tiny.toml", "--cache", "c", "--out", "rep"];
    let o = bvhlab(&args, dir.path());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let cold = stdout_json(&o);
    // Per scene: 1 load + 3 builds + 1 compact + 3 finals x 2 ray sets.
    assert_eq!(cold["computed"], 2 * (1 + 3 + 1 + 6));
    assert_eq!(cold["cached"], 0);
    assert_eq!(cold["rows"], 2 * 3 * 2);
    assert!(
        Path::new(cold["report"].as_str().unwrap()).is_absolute()
            || dir.path().join(cold["report"].as_str().unwrap()).exists()
    );
    let warm = stdout_json(&bvhlab(&args, dir.path()));
    assert_eq!(warm["computed"], 0);
    assert_eq!(warm["cached"], cold["computed"]);
}

#[test]
fn eval_focus_and_encode_errors() {
    let dir = tempfile::tempdir().unwrap();
    // gen:sphere is the unit sphere: a box around its upper cap holds some of its triangles.
    let o = bvhlab(
        &[
            "eval",
            "--scene",
            "gen:sphere:n=2000",
            "--build",
            "binned-sah",
            "--focus",
            "-1,0.5,-1,1,1,1",
            "--repeat",
            "1",
            "--no-cache",
            "--json",
        ],
        dir.path(),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v = stdout_json(&o);
    let n = v["focus_triangles"].as_u64().unwrap();
    assert!(n > 0 && n < v["triangles"].as_u64().unwrap(), "{v}");
    assert!(v["focus_sah_cost"].as_f64().unwrap() > 0.0, "{v}");
    assert!(
        v["encoder"].is_null() && v["code_bits"].is_null(),
        "top-down builders have no encoder: {v}"
    );
    for k in [
        "encode_params",
        "encode_seconds",
        "duplicate_code_fraction",
        "total_build_seconds",
        "threads",
    ] {
        assert!(v.get(k).is_some(), "missing {k}: {v}");
    }

    let o = bvhlab(
        &[
            "eval",
            "--scene",
            "gen:sphere",
            "--build",
            "sweep-sah",
            "--encode",
            "morton",
            "--no-cache",
        ],
        dir.path(),
    );
    assert_input_error(&o, &["sweep-sah", "takes no codes", "lbvh"]);
    let o = bvhlab(
        &[
            "eval",
            "--scene",
            "gen:sphere",
            "--build",
            "lbvh",
            "--encode",
            "hilbert",
            "--no-cache",
        ],
        dir.path(),
    );
    assert_input_error(&o, &["hilbert", "morton", "emc64-sort", "emc64-var"]);
    let o = bvhlab(
        &[
            "eval",
            "--scene",
            "gen:sphere",
            "--build",
            "ploc",
            "--encode",
            "emc64-var",
            "--set",
            "bits=10",
            "--no-cache",
        ],
        dir.path(),
    );
    assert_input_error(&o, &["bits", "bounds, grid_bits"]);
    let o = bvhlab(
        &[
            "eval",
            "--scene",
            "gen:sphere",
            "--build",
            "binned-sah",
            "--focus",
            "1,1,1,0,0,0",
            "--no-cache",
        ],
        dir.path(),
    );
    assert_input_error(&o, &["focus"]);
    let o = bvhlab(
        &[
            "eval",
            "--scene",
            "gen:sphere",
            "--build",
            "binned-sah",
            "--focus",
            "1,2,3",
            "--no-cache",
        ],
        dir.path(),
    );
    assert_input_error(&o, &["six numbers"]);
}

#[test]
fn methods_lists_builders_and_encoders() {
    let dir = tempfile::tempdir().unwrap();
    let o = bvhlab(&["methods"], dir.path());
    assert!(o.status.success());
    let s = String::from_utf8_lossy(&o.stdout);
    for n in [
        "binned-sah",
        "lbvh",
        "aac",
        "ploc",
        "radius=[10]",
        "morton",
        "emc64-var",
        "bits=[auto]",
        "grid_bits",
        "bonsai",
        "incremental",
        "ibo",
        "measure=[comb]",
        "schedule=[bittner]",
        "frame=[centroids]",
        "kensler-sa",
        "layouts",
        "qbvh_chunks",
        "octree_1bit",
        "chunk_bytes=[64]",
        "frame=[chunk]",
        "fill=[bfs]",
        "max_slowdown=[1.25]",
    ] {
        assert!(s.contains(n), "`{n}` missing in:\n{s}");
    }
}

/// Needs the bottom-up builders (lbvh, aac, ploc) from bvhlab-builders.
#[test]
fn eval_bottom_up_with_encoder_prints_encode_fields() {
    let dir = tempfile::tempdir().unwrap();
    let args = [
        "eval",
        "--scene",
        "gen:sphere:n=2000",
        "--build",
        "ploc",
        "--encode",
        "emc64-var",
        "--set",
        "bounds=concise",
        "--set",
        "radius=25",
        "--repeat",
        "2",
        "--cache",
        "c",
        "--json",
    ];
    let o = bvhlab(&args, dir.path());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v = stdout_json(&o);
    assert_eq!(v["encoder"], "emc64-var");
    assert_eq!(v["encode_params"], "bounds=concise,grid_bits=0");
    assert_eq!(v["build_params"], "radius=25");
    assert_eq!(
        v["method"],
        "ploc radius=25 \u{b7} emc64-var bounds=concise"
    );
    let bits = v["code_bits"].as_u64().unwrap();
    assert!((32..=64).contains(&bits), "EMC-64 codes: {v}");
    assert_eq!(v["valid"], true);
    assert_eq!(v["computed"], 3, "load, encode, build");
    let total = v["total_build_seconds"].as_f64().unwrap();
    let parts = v["encode_seconds"].as_f64().unwrap() + v["build_seconds"].as_f64().unwrap();
    assert!((total - parts).abs() < 1e-12, "{v}");
    let w = stdout_json(&bvhlab(&args, dir.path()));
    assert_eq!(
        (w["computed"].as_u64(), w["cached"].as_u64()),
        (Some(0), Some(3))
    );
    assert_eq!(w["bvh_hash"], v["bvh_hash"]);
}

/// The optimize stage from the command line: ibo on a single-primitive-leaf sweep-SAH tree, then the
/// compaction; the row carries the optimizer's fields and trace, a re-run is fully cached, and
/// optimizer mistakes are input errors.
#[test]
fn eval_optimize_ibo_then_collapse() {
    let dir = tempfile::tempdir().unwrap();
    let args = [
        "eval",
        "--scene",
        "gen:city:blocks=4",
        "--build",
        "spatial-median",
        "--set",
        "leaf=1",
        "--optimize",
        "ibo",
        "--set",
        "measure=area",
        "--compact",
        "collapse",
        "--repeat",
        "2",
        "--cache",
        "c",
        "--json",
    ];
    let o = bvhlab(&args, dir.path());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v = stdout_json(&o);
    assert_eq!(v["optimizer"], "ibo");
    assert_eq!(v["method"], "spatial-median leaf=1 +ibo area +collapse");
    assert_eq!(v["valid"], true);
    assert_eq!(v["computed"], 4, "load, build, optimize, compact");
    let (built, optimized, fin) = (
        v["build_sah_cost"].as_f64().unwrap(),
        v["optimized_sah_cost"].as_f64().unwrap(),
        v["sah_cost"].as_f64().unwrap(),
    );
    assert!(
        optimized < built,
        "ibo improves a spatial-median tree: {built} -> {optimized}"
    );
    assert!(
        fin <= optimized,
        "compaction never raises the cost: {optimized} -> {fin}"
    );
    let trace = v["optimize_trace"].as_array().unwrap();
    assert_eq!(
        trace.len() as u64,
        v["optimize_passes"].as_u64().unwrap() + 1
    );
    // Pass 0 is the input tree (the optimizer sums areas in its own order: equal up to rounding).
    assert!(
        (trace[0]["sah_cost"].as_f64().unwrap() - built).abs() <= 1e-9 * built,
        "{v}"
    );
    let w = stdout_json(&bvhlab(&args, dir.path()));
    assert_eq!(
        (w["computed"].as_u64(), w["cached"].as_u64()),
        (Some(0), Some(4))
    );
    assert_eq!(w["optimize_trace"], v["optimize_trace"]);

    let bad = |extra: &[&str]| {
        let mut a = vec![
            "eval",
            "--scene",
            "gen:sphere",
            "--build",
            "sweep-sah",
            "--no-cache",
        ];
        a.extend_from_slice(extra);
        bvhlab(&a, dir.path())
    };
    assert_input_error(
        &bad(&["--optimize", "anneal"]),
        &["anneal", "ibo", "kensler-hc", "kensler-sa"],
    );
    assert_input_error(
        &bad(&["--optimize", "ibo", "--set", "measure=best"]),
        &["measure", "comb"],
    );
    assert_input_error(
        &bad(&["--optimize", "ibo", "--set", "pr=20"]),
        &["pr=20", "pt=10"],
    );
    assert_input_error(&bad(&["--set", "pt=3"]), &["pt", "optimizer parameter"]);
}

#[test]
fn eval_layout_fields_in_json_and_human_output() {
    let dir = tempfile::tempdir().unwrap();
    let base = [
        "eval",
        "--scene",
        "gen:sphere:n=2000",
        "--build",
        "binned-sah",
        "--layout",
        "bvh2",
        "--repeat",
        "2",
        "--cache",
        "c",
    ];
    let with_rays = [&base[..], &["--rays", "random:1000", "--json"]].concat();
    let o = bvhlab(&with_rays, dir.path());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v = stdout_json(&o);
    for k in [
        "topology_bytes",
        "total_bytes",
        "chunks",
        "chunk_fill",
        "extra_box_hits_per_ray",
        "extra_tests_per_ray",
        "slowdown",
        "bvh2_trace_seconds",
        "topology_bits_per_node",
        "layout_seconds",
        "peak_build_bytes",
    ] {
        assert!(v[k].is_number(), "{k}: {v}");
    }
    assert_eq!(v["layout"], "bvh2");
    let nodes = v["inner_nodes"].as_u64().unwrap() + v["leaves"].as_u64().unwrap();
    assert_eq!(v["topology_bytes"].as_u64().unwrap(), 32 * nodes);
    assert_eq!(v["extra_tests_per_ray"], 0.0);
    assert!(v["keys"]["layout"].is_string());
    // Without rays: memory fields, no accuracy or timing fields; the layout node is reused.
    let o = bvhlab(&[&base[..], &["--json"]].concat(), dir.path());
    let w = stdout_json(&o);
    assert_eq!(w["computed"], 0);
    assert_eq!(w["topology_bytes"], v["topology_bytes"]);
    assert!(w["extra_box_hits_per_ray"].is_null() && w["slowdown"].is_null());
    // Human output: a layout block.
    let o = bvhlab(&with_rays[..with_rays.len() - 1], dir.path());
    let s = String::from_utf8_lossy(&o.stdout);
    assert!(
        s.contains("\nlayout: bvh2")
            && s.contains("\n  topology_bytes: ")
            && s.contains("\n  slowdown: "),
        "{s}"
    );
    // A bad spec is an input error naming the parameter; an old layout name (issue 17) is one
    // naming the new name.
    for (spec, needle) in [
        ("qbvh_chunks:frame=sideways", "frame"),
        (
            "qbvh:frame=parent",
            "layout `qbvh` was renamed to `qbvh_chunks` (Kilian 2021 5.2)",
        ),
    ] {
        let o = bvhlab(
            &[
                "eval",
                "--scene",
                "gen:sphere:n=100",
                "--build",
                "binned-sah",
                "--layout",
                spec,
                "--no-cache",
            ],
            dir.path(),
        );
        assert_eq!(o.status.code(), Some(2), "{spec}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(needle), "{spec}: {err}");
    }
}
