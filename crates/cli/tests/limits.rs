//! Issue 15: inputs that used to run away or fail badly. A grid is counted from its shape and
//! refused above `--max-configs` before anything is expanded.
use std::path::Path;
use std::time::Instant;

mod common;
use common::{command, ok};

/// `axes` parameters with 10 values each over 10 scenes: 10^(axes + 1) configurations.
fn grid(axes: usize) -> String {
    let scenes: Vec<String> = (1..=10)
        .map(|i| format!("\"gen:sphere:n={}\"", 100 + i))
        .collect();
    let mut s = format!(
        "name = \"big\"\nscenes = [{}]\n[[chain]]\nbuild = \"binned-sah\"\n",
        scenes.join(", ")
    );
    for k in ["bins", "leaf", "c_t", "c_i", "p5", "p6", "p7", "p8"]
        .iter()
        .take(axes)
    {
        s.push_str(&format!("{k} = [2, 3, 4, 5, 6, 7, 8, 9, 10, 11]\n"));
    }
    s
}

fn refused(dir: &Path, args: &[&str], count: &str, limit: &str) -> f64 {
    let t0 = Instant::now();
    let o = command(args, dir).output().unwrap();
    let secs = t0.elapsed().as_secs_f64();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
    assert!(
        err.starts_with("error: ") && !err.contains("panicked"),
        "{err}"
    );
    for needle in [
        format!("{count} configurations (scenes 10 x chain 1: "),
        format!("exceed --max-configs {limit}"),
        "raise it with --max-configs N".to_string(),
        "bins 10 x ".to_string(),
    ] {
        assert!(err.contains(&needle), "`{needle}` not in {err}");
    }
    assert!(o.stdout.is_empty(), "nothing printed on a refusal");
    secs
}

#[test]
fn huge_grids_are_refused_at_once_with_the_count_and_axes() {
    let dir = tempfile::tempdir().unwrap();
    // 10^9: 8 axes of 10 values over 10 scenes (parameters need not exist: counting comes first).
    std::fs::write(dir.path().join("g9.toml"), grid(8)).unwrap();
    std::fs::write(dir.path().join("g6.toml"), grid(5)).unwrap();
    for sub in [
        vec!["sweep", "g9.toml", "--cache", "c"],
        vec!["sweep", "g9.toml", "--cache", "c", "--plan"],
        vec!["sweep", "g9.toml", "--cache", "c", "--status"],
        vec![
            "sweep",
            "g9.toml",
            "--cache",
            "c",
            "--report-only",
            "--out",
            "rep",
        ],
        vec!["sweep", "g9.toml", "--cache", "c", "--shard", "1/2"],
        vec!["slurm", "g9.toml", "--tasks", "2", "--cache", "c"],
    ] {
        let secs = refused(dir.path(), &sub, "1000000000", "10000");
        eprintln!("{sub:?}: refused in {secs:.3} s");
        assert!(secs < 5.0, "{sub:?}: {secs} s");
    }
    // 10^6 is refused too unless raised (not raised here: it would plan a million chains).
    refused(
        dir.path(),
        &["sweep", "g6.toml", "--cache", "c", "--plan"],
        "1000000",
        "10000",
    );
    refused(
        dir.path(),
        &[
            "sweep",
            "g6.toml",
            "--cache",
            "c",
            "--plan",
            "--max-configs",
            "999999",
        ],
        "1000000",
        "999999",
    );
    assert!(
        !dir.path().join("c").exists(),
        "a refused experiment touches no cache"
    );
}

#[test]
fn raising_the_limit_runs_a_grid_over_it() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("small.toml"),
        "name = \"small\"\nscenes = [\"gen:sphere:n=200\", \"gen:sphere:n=300\"]\nrepeat = 1\n\
         [[chain]]\nbuild = \"binned-sah\"\nbins = [4, 8, 16]\n",
    )
    .unwrap();
    let o = command(
        &[
            "sweep",
            "small.toml",
            "--cache",
            "c",
            "--out",
            "rep",
            "--max-configs",
            "5",
        ],
        dir.path(),
    )
    .output()
    .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("small.toml: 6 configurations (scenes 2 x chain 1: bins 3 x rays 1) exceed --max-configs 5"), "{err}");
    let plan = ok(
        command(
            &[
                "sweep",
                "small.toml",
                "--cache",
                "c",
                "--plan",
                "--max-configs",
                "6",
            ],
            dir.path(),
        )
        .output()
        .unwrap(),
        "plan at the limit",
    );
    assert_eq!(plan["chains"], 6);
    let run = ok(
        command(
            &[
                "sweep",
                "small.toml",
                "--cache",
                "c",
                "--out",
                "rep",
                "--max-configs",
                "6",
            ],
            dir.path(),
        )
        .output()
        .unwrap(),
        "sweep at the limit",
    );
    assert_eq!(run["rows"], 6);
}
