//! Two `bvhlab sweep` processes on one cache directory at once: both complete, their results equal a
//! single sweep's (except timings), each stage is computed once in total (the two `computed` counts
//! add up to a single cold sweep's), and no partial file is ever visible under a real name (a
//! watcher checks every file it finds while they run).
use bvhlab_pipeline::{codec, store::Manifest};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

mod common;
use common::parse_csv;

const EXPERIMENT: &str = r#"
name = "together"
scenes = ["gen:sphere:n=4000", "gen:city:blocks=12", "gen:hairball:n=300"]
repeat = 2
[[chain]]
build = "binned-sah"
bins = [4, 8, 16]
compact = ["none", "collapse"]
[[chain]]
build = "sweep-sah"
[[chain]]
build = ["lbvh", "aac", "ploc"]
encode = ["morton", "emc64-var"]
[[chain]]
build = "sweep-sah"
leaf = 1
optimize = "ibo"
compact = "collapse"
[rays]
sets = ["primary:24x24", "random:1000"]
"#;

fn command(args: &[&str], cwd: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_bvhlab"));
    c.args(args)
        .current_dir(cwd)
        .env_remove("BVHLAB_CACHE")
        .env_remove("BVHLAB_MAX_MEMORY");
    c
}

fn json_line(o: &Output) -> serde_json::Value {
    let s = String::from_utf8_lossy(&o.stdout);
    let last = s
        .lines()
        .last()
        .unwrap_or_else(|| panic!("no stdout; stderr: {}", String::from_utf8_lossy(&o.stderr)));
    serde_json::from_str(last).unwrap_or_else(|e| panic!("{e}: {last}"))
}

fn untimed_rows(report: &Path) -> Vec<Vec<String>> {
    let rows = parse_csv(&std::fs::read_to_string(report.join("results.csv")).unwrap());
    let header = rows[0].clone();
    let keep: Vec<usize> = (0..header.len())
        .filter(|&i| {
            let h = &header[i];
            !(h.contains("seconds")
                || h.contains("heap") // a measurement: parallel builds allocate in any order
                || h.contains("mrays")
                || h.starts_with("slowdown")
                || h.starts_with("auto_search_slowdown")
                || h == "optimize_trace"
                || h == "heatmap")
        })
        .collect();
    rows[1..]
        .iter()
        .map(|r| {
            keep.iter()
                .map(|&i| r.get(i).cloned().unwrap_or_default())
                .collect()
        })
        .collect()
}

/// Every file under a real name in the stage directories is complete: manifests parse, artifacts
/// pass their codec checksum. Returns how many files were checked.
fn check_visible_files(root: &Path) -> u64 {
    let mut n = 0;
    let Ok(dirs) = std::fs::read_dir(root) else {
        return 0;
    };
    for d in dirs.flatten() {
        let name = d.file_name().to_string_lossy().to_string();
        if name == "locks" || name == "quarantine" || !d.path().is_dir() {
            continue;
        }
        let Ok(files) = std::fs::read_dir(d.path()) else {
            continue;
        };
        for f in files.flatten() {
            let fname = f.file_name().to_string_lossy().to_string();
            if fname.starts_with(".tmp-") {
                continue;
            }
            let p: PathBuf = f.path();
            // Renamed into place whole: a read sees the old or the new file, never a partial one.
            let Ok(bytes) = std::fs::read(&p) else {
                continue;
            };
            if fname.ends_with(".json") {
                serde_json::from_slice::<Manifest>(&bytes)
                    .unwrap_or_else(|e| panic!("partial manifest {}: {e}", p.display()));
            } else if fname.ends_with(".bin") || fname.ends_with(".sum") || fname.ends_with(".opt")
            {
                codec::verify(&bytes)
                    .unwrap_or_else(|e| panic!("partial artifact {}: {e}", p.display()));
            }
            n += 1;
        }
    }
    n
}

#[test]
fn two_concurrent_sweeps_compute_each_stage_once() {
    let dir = tempfile::tempdir().unwrap();
    let cwd = dir.path().to_path_buf();
    std::fs::write(cwd.join("t.toml"), EXPERIMENT).unwrap();

    let single = command(
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
        &cwd,
    )
    .output()
    .unwrap();
    assert!(
        single.status.success(),
        "{}",
        String::from_utf8_lossy(&single.stderr)
    );
    let single_computed = json_line(&single)["computed"].as_u64().unwrap();
    let reference = untimed_rows(&cwd.join("single-rep"));

    let done = Arc::new(AtomicBool::new(false));
    let watcher = {
        let (done, root) = (done.clone(), cwd.join("shared"));
        std::thread::spawn(move || {
            let (mut scans, mut files) = (0u64, 0u64);
            while !done.load(Ordering::Relaxed) {
                files += check_visible_files(&root);
                scans += 1;
            }
            (scans, files)
        })
    };
    let children: Vec<_> = ["a", "b"]
        .iter()
        .map(|out| {
            command(
                &[
                    "sweep",
                    "t.toml",
                    "--cache",
                    "shared",
                    "--out",
                    out,
                    "--threads",
                    "1",
                ],
                &cwd,
            )
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
        })
        .collect();
    let outputs: Vec<Output> = children
        .into_iter()
        .map(|c| c.wait_with_output().unwrap())
        .collect();
    done.store(true, Ordering::Relaxed);
    let (scans, files) = watcher.join().unwrap();
    assert!(
        scans > 0 && files > 0,
        "the watcher saw the cache ({scans} scans, {files} files)"
    );

    let mut computed = 0;
    for (o, out) in outputs.iter().zip(["a", "b"]) {
        assert!(
            o.status.success(),
            "{out}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let v = json_line(o);
        computed += v["computed"].as_u64().unwrap();
        assert_eq!(
            v["computed"].as_u64().unwrap() + v["cached"].as_u64().unwrap(),
            single_computed,
            "{out}: every node counted once: {v}"
        );
        assert_eq!(
            untimed_rows(&cwd.join(out)),
            reference,
            "{out}: same rows as one sweep"
        );
    }
    assert_eq!(
        computed, single_computed,
        "each stage computed once in total"
    );
    let o = command(&["cache", "verify", "--cache", "shared"], &cwd)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stdout));
}
