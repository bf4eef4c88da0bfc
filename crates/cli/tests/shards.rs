//! `sweep --plan`, `--shard I/N`, `--status` and `--report-only` through the real binary (issue 12):
//! shards run one after another or at once on one cache compute each stage once in total (their
//! `computed` add up to a single cold sweep's), give the same results, and the partition does not
//! depend on the cache state or the thread count.
use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Output, Stdio};

mod common;
use common::{command, json_line, ok, untimed_rows};

const EXPERIMENT: &str = r#"
name = "sharded"
scenes = ["gen:sphere:n=3000", "gen:city:blocks=8", "gen:hairball:n=200"]
repeat = 1
[[chain]]
build = "binned-sah"
bins = [4, 16]
compact = ["none", "collapse"]
[[chain]]
build = ["lbvh", "ploc"]
encode = ["morton", "emc64-var"]
[[chain]]
build = "sweep-sah"
leaf = 1
optimize = "ibo"
max_passes = 2
compact = "collapse"
[rays]
sets = ["random:500"]
"#;

fn bvhlab(args: &[&str], cwd: &Path) -> Output {
    command(args, cwd).output().unwrap()
}

fn setup() -> (tempfile::TempDir, u64, Vec<Vec<(String, String)>>) {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("t.toml"), EXPERIMENT).unwrap();
    let v = ok(
        bvhlab(
            &[
                "sweep",
                "t.toml",
                "--cache",
                "single",
                "--out",
                "single-rep",
                "--threads",
                "1",
            ],
            dir.path(),
        ),
        "cold sweep",
    );
    let computed = v["computed"].as_u64().unwrap();
    let rows = untimed_rows(&dir.path().join("single-rep"));
    (dir, computed, rows)
}

fn owners(cwd: &Path, cache: &str, shards: &str, threads: &str) -> BTreeMap<String, u64> {
    let o = bvhlab(
        &[
            "sweep",
            "t.toml",
            "--cache",
            cache,
            "--plan",
            "--shards",
            shards,
            "--json",
            "--threads",
            threads,
        ],
        cwd,
    );
    let v: serde_json::Value = serde_json::from_slice(&o.stdout)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&o.stderr)));
    v["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| {
            (
                format!(
                    "{}:{}",
                    n["stage"].as_str().unwrap(),
                    n["key"].as_str().unwrap()
                ),
                n["shard"].as_u64().unwrap(),
            )
        })
        .collect()
}

#[test]
fn shards_one_after_another_compute_each_stage_once() {
    let (dir, single_computed, reference) = setup();
    let cwd = dir.path();
    // The plan lists exactly the stages a cold sweep computes, all missing in a fresh cache.
    let plan = ok(
        bvhlab(
            &[
                "sweep", "t.toml", "--cache", "fresh", "--plan", "--shards", "3",
            ],
            cwd,
        ),
        "plan",
    );
    assert_eq!(plan["nodes"].as_u64(), Some(single_computed), "{plan}");
    assert_eq!(plan["missing"].as_u64(), Some(single_computed));
    assert_eq!(plan["shard_seconds"].as_array().map(|a| a.len()), Some(3));
    let before = owners(cwd, "fresh", "3", "1");
    let status = ok(
        bvhlab(
            &[
                "sweep", "t.toml", "--cache", "fresh", "--status", "--shards", "3",
            ],
            cwd,
        ),
        "status",
    );
    assert_eq!(status["done"].as_u64(), Some(0), "{status}");

    // A report of an empty cache is incomplete: exit 3, every chain listed.
    let o = bvhlab(
        &[
            "sweep",
            "t.toml",
            "--cache",
            "fresh",
            "--report-only",
            "--out",
            "early",
        ],
        cwd,
    );
    assert_eq!(
        o.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(
        json_line(&o)["missing_chains"].as_array().map(|a| a.len()),
        status["chains"].as_u64().map(|n| n as usize)
    );

    let mut computed = 0;
    let mut owned = 0;
    for i in 1..=3 {
        let v = ok(
            bvhlab(
                &[
                    "sweep",
                    "t.toml",
                    "--cache",
                    "fresh",
                    "--shard",
                    &format!("{i}/3"),
                    "--threads",
                    "1",
                ],
                cwd,
            ),
            "shard",
        );
        assert_eq!(v["shard"].as_u64(), Some(i));
        computed += v["computed"].as_u64().unwrap();
        owned += v["owned"].as_u64().unwrap();
        if i == 1 {
            let s = ok(
                bvhlab(
                    &[
                        "sweep", "t.toml", "--cache", "fresh", "--status", "--shards", "3",
                    ],
                    cwd,
                ),
                "status",
            );
            assert!(s["nodes_missing"].as_u64().unwrap() > 0, "{s}");
            assert_eq!(
                s["missing_per_shard"]["1"],
                serde_json::Value::Null,
                "shard 1 left nothing of its own: {s}"
            );
        }
    }
    assert_eq!(
        owned, single_computed,
        "every node owned by exactly one shard"
    );
    assert_eq!(
        computed, single_computed,
        "the shards computed each stage once in total"
    );
    // The partition did not change with the cache's state or the thread count.
    assert_eq!(owners(cwd, "fresh", "3", "2"), before);

    let status = ok(
        bvhlab(&["sweep", "t.toml", "--cache", "fresh", "--status"], cwd),
        "status",
    );
    assert_eq!(status["missing"].as_u64(), Some(0), "{status}");
    let v = ok(
        bvhlab(
            &[
                "sweep",
                "t.toml",
                "--cache",
                "fresh",
                "--report-only",
                "--out",
                "rep",
                "--threads",
                "1",
            ],
            cwd,
        ),
        "report-only",
    );
    assert_eq!(v["computed"].as_u64(), Some(0));
    assert_eq!(
        untimed_rows(&cwd.join("rep")),
        reference,
        "same results as one sweep"
    );
    let v = ok(
        bvhlab(
            &["sweep", "t.toml", "--cache", "fresh", "--out", "warm"],
            cwd,
        ),
        "warm sweep",
    );
    assert_eq!(v["computed"].as_u64(), Some(0));
}

#[test]
fn concurrent_shard_processes_compute_each_stage_once() {
    let (dir, single_computed, reference) = setup();
    let cwd = dir.path();
    let children: Vec<_> = (1..=4)
        .map(|i| {
            command(
                &[
                    "sweep",
                    "t.toml",
                    "--cache",
                    "shared",
                    "--shard",
                    &format!("{i}/4"),
                    "--threads",
                    "1",
                ],
                cwd,
            )
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
        })
        .collect();
    let mut computed = 0;
    for c in children {
        let v = ok(c.wait_with_output().unwrap(), "shard process");
        computed += v["computed"].as_u64().unwrap();
    }
    assert_eq!(
        computed, single_computed,
        "each stage computed once across 4 concurrent shards"
    );
    let v = ok(
        bvhlab(
            &[
                "sweep",
                "t.toml",
                "--cache",
                "shared",
                "--report-only",
                "--out",
                "rep",
                "--threads",
                "1",
            ],
            cwd,
        ),
        "report",
    );
    assert_eq!(v["missing_chains"].as_array().map(|a| a.len()), Some(0));
    assert_eq!(untimed_rows(&cwd.join("rep")), reference);
    let o = bvhlab(&["cache", "verify", "--cache", "shared"], cwd);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stdout));
}

#[test]
fn bad_shard_arguments_are_input_errors() {
    let dir = tempfile::tempdir().unwrap();
    let cwd = dir.path();
    std::fs::write(cwd.join("t.toml"), EXPERIMENT).unwrap();
    for bad in ["0/4", "5/4", "1/0", "x/4", "3"] {
        let o = bvhlab(&["sweep", "t.toml", "--cache", "c", "--shard", bad], cwd);
        assert_eq!(
            o.status.code(),
            Some(2),
            "--shard {bad}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(
            String::from_utf8_lossy(&o.stderr).contains("--shard"),
            "the message names the flag"
        );
    }
    let o = bvhlab(
        &["sweep", "t.toml", "--cache", "c", "--plan", "--shards", "0"],
        cwd,
    );
    assert_eq!(o.status.code(), Some(2));
    // Nothing was computed by the failed calls.
    assert!(!cwd.join("c").join("load").exists());
}
