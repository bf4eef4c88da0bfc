//! Progress without a terminal (issue 16 item 6): with stderr piped a sweep prints plain
//! `progress:` lines (one at the start, then one every `BVHLAB_PROGRESS_SECONDS`, 10 s by default;
//! shortened to 1 ms here so a sub-second sweep prints several) and ends with a closing line in
//! words after the JSON summary.
mod common;

use std::path::Path;

const EXPERIMENT: &str = r#"
name = "progress-test"
scenes = ["gen:sphere:n=3000", "gen:terrain"]
repeat = 1

[[chain]]
build = ["binned-sah", "sweep-sah", "spatial-median"]

[rays]
sets = ["primary:64x64", "random:2000"]
"#;

fn sweep(dir: &Path, extra: &[&str], interval: Option<&str>) -> (serde_json::Value, Vec<String>) {
    let exp = dir.join("exp.toml");
    std::fs::write(&exp, EXPERIMENT).unwrap();
    let cache = dir.join("cache");
    let out = dir.join("report");
    let mut args = vec![
        "sweep",
        exp.to_str().unwrap(),
        "--cache",
        cache.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let mut c = common::command(&args, dir);
    c.env_remove("BVHLAB_PROGRESS_SECONDS");
    if let Some(s) = interval {
        c.env("BVHLAB_PROGRESS_SECONDS", s);
    }
    let o = c.output().unwrap();
    let json = common::ok(o.clone(), "sweep");
    let stderr: Vec<String> = String::from_utf8_lossy(&o.stderr)
        .lines()
        .map(str::to_string)
        .collect();
    (json, stderr)
}

/// `progress: NAME: D/T stages (P %), X elapsed, ETA Y` -> (D, T).
fn periodic(line: &str) -> Option<(u64, u64)> {
    let rest = line.strip_prefix("progress: progress-test: ")?;
    let (done, rest) = rest.split_once('/')?;
    let (total, rest) = rest.split_once(" stages (")?;
    if !(rest.contains(" %), ") && rest.contains(" elapsed, ETA ") && rest.contains(" s")) {
        return None;
    }
    Some((done.parse().ok()?, total.parse().ok()?))
}

#[test]
fn piped_sweep_prints_progress_lines_and_a_closing_line() {
    let dir = tempfile::tempdir().unwrap();
    let (json, err) = sweep(dir.path(), &[], Some("0.001"));
    let computed = json["computed"].as_u64().unwrap();
    assert!(computed > 0, "{json}");
    // Nodes: 2 loads, 6 builds, 12 measures.
    assert_eq!(computed, 20, "{json}");
    let all = err.join("\n");
    let first = err.first().map(String::as_str).unwrap_or("");
    assert!(
        first.starts_with("progress: progress-test: 20 stages, 20 to compute (estimated ")
            && first.ends_with(", 0 cached"),
        "first stderr line: {first}\n{all}"
    );
    let ticks: Vec<(u64, u64)> = err.iter().filter_map(|l| periodic(l)).collect();
    assert!(!ticks.is_empty(), "no periodic progress line:\n{all}");
    assert!(ticks.iter().all(|&(d, t)| t == 20 && d <= t), "{all}");
    assert!(
        ticks.windows(2).all(|w| w[0].0 <= w[1].0),
        "stages done must not go down:\n{all}"
    );
    let last = err.last().unwrap();
    let report = dir.path().join("report").join("index.html");
    assert!(
        last.starts_with("progress-test: 20 stages, 20 computed, 0 from cache, ")
            && last.ends_with(&format!(" s; report {}", report.display())),
        "closing line: {last}\n{all}"
    );

    // Warm, default interval (10 s): the start line and the closing line, no periodic line.
    let (json, err) = sweep(dir.path(), &[], None);
    assert_eq!(json["computed"].as_u64(), Some(0), "{json}");
    let all = err.join("\n");
    assert_eq!(
        err.iter().filter(|l| periodic(l).is_some()).count(),
        0,
        "{all}"
    );
    assert!(
        err[0].starts_with("progress: progress-test: 20 stages, 0 to compute ")
            && err[0].ends_with("20 cached"),
        "{all}"
    );
    assert!(
        err.last()
            .unwrap()
            .starts_with("progress-test: 20 stages, 0 computed, 20 from cache, "),
        "{all}"
    );

    // --report-only ends with its own closing line.
    let (json, err) = sweep(dir.path(), &["--report-only"], None);
    assert_eq!(json["rows"].as_u64(), Some(12), "{json}");
    let last = err.last().unwrap();
    assert!(
        last.starts_with(
            "progress-test (report only, 12 of 12 chains): 20 stages, 0 computed, 20 from cache, "
        ) && last.contains("; report "),
        "{last}"
    );
}

#[test]
fn piped_shard_prints_progress_lines_and_a_closing_line() {
    let dir = tempfile::tempdir().unwrap();
    let (json, err) = sweep(dir.path(), &["--shard", "1/2"], Some("0.001"));
    let owned = json["owned"].as_u64().unwrap();
    let all = err.join("\n");
    assert!(
        err[0].starts_with(&format!(
            "progress: progress-test shard 1/2: {owned} stages, {owned} to compute (estimated "
        )),
        "{all}"
    );
    assert!(
        err.iter()
            .any(|l| l.starts_with("progress: progress-test shard 1/2: ")
                && l.contains(" elapsed, ETA ")),
        "{all}"
    );
    let last = err.last().unwrap();
    assert!(
        last.starts_with("progress-test shard 1/2: ") && last.contains(" computed, "),
        "{all}"
    );
}
