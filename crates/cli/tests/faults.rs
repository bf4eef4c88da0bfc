//! Issue 15 faults through the real binary: a corrupt or repaired-away heat map is recomputed,
//! `--report-only` never replaces a report by a smaller one without `--force`, a killed report
//! writer's temporary files are removed by the next run, and a closed pipe ends quietly.
use std::path::Path;
use std::process::Stdio;

mod common;
use common::{command, ok};

const TINY: &str = r#"name = "tiny"
scenes = ["gen:sphere:n=500"]
repeat = 1
[[chain]]
build = "binned-sah"
bins = [4, 8]
[rays]
sets = ["primary:16x16"]
"#;

const PNG_MAGIC: &[u8] = b"\x89PNG\r\n\x1a\n";

fn sweep(dir: &Path, extra: &[&str]) -> std::process::Output {
    sweep_in(dir, "c", extra)
}

fn sweep_in(dir: &Path, cache: &str, extra: &[&str]) -> std::process::Output {
    let mut args = vec!["sweep", "tiny.toml", "--cache", cache, "--out", "rep"];
    args.extend_from_slice(extra);
    command(&args, dir).output().unwrap()
}

fn pngs(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "png"))
        .collect();
    v.sort();
    v
}

#[test]
fn corrupt_heat_map_is_recomputed_before_and_after_repair() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("tiny.toml"), TINY).unwrap();
    let cold = ok(sweep(d, &[]), "cold");
    assert_eq!(cold["rows"], 2);
    let cached = pngs(&d.join("c/measure"));
    assert_eq!(cached.len(), 2);
    let good = std::fs::read(&cached[0]).unwrap();
    assert!(good.starts_with(PNG_MAGIC));

    // 1. Corrupted in place: detected with a warning, recomputed, the report gets a good one.
    let mut bad = good.clone();
    let mid = bad.len() / 2;
    bad[mid] ^= 0xff;
    std::fs::write(&cached[0], &bad).unwrap();
    let o = sweep(d, &[]);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    let warm = ok(o, "sweep over a corrupt heat map");
    assert!(
        err.contains("warning: bad cache file") && err.contains(".png"),
        "{err}"
    );
    assert_eq!(warm["per_stage"]["measure"]["computed"], 1, "{warm}");
    assert_eq!(std::fs::read(&cached[0]).unwrap(), good, "recomputed bytes");
    for p in pngs(&d.join("rep/heatmaps")) {
        let b = std::fs::read(&p).unwrap();
        assert!(b.starts_with(PNG_MAGIC) && b != bad, "{}", p.display());
    }
    assert_eq!(pngs(&d.join("rep/heatmaps")).len(), 2);

    // 2. Corrupted, then repaired away: the next sweep recomputes it instead of dropping it.
    std::fs::write(&cached[1], b"not a png").unwrap();
    let o = command(&["cache", "verify", "--repair", "--cache", "c"], d)
        .output()
        .unwrap();
    assert!(!o.status.success(), "the cache was not clean");
    assert!(!cached[1].exists(), "quarantined");
    let o = sweep(d, &[]);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    let after = ok(o, "sweep after repair");
    assert_eq!(
        after["per_stage"]["measure"]["computed"], 1,
        "{after} {err}"
    );
    assert!(std::fs::read(&cached[1]).unwrap().starts_with(PNG_MAGIC));
    assert_eq!(pngs(&d.join("rep/heatmaps")).len(), 2, "{err}");
    let html = std::fs::read_to_string(d.join("rep/index.html")).unwrap();
    assert!(!html.contains("heat map of"), "no heat-map problem listed");
    let o = command(&["cache", "verify", "--cache", "c"], d)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stdout));
}

#[test]
fn report_only_never_shrinks_a_report_without_force() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("tiny.toml"), TINY).unwrap();
    ok(sweep(d, &[]), "cold");
    let before = std::fs::read(d.join("rep/results.parquet")).unwrap();
    // An empty cache: zero complete chains.
    let o = sweep_in(d, "empty", &["--report-only"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("the existing report has 2 rows and the new one would have 0")
            && err.contains("--force"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(d.join("rep/results.parquet")).unwrap(),
        before,
        "report untouched"
    );
    // A plain sweep of a smaller experiment is refused before computing anything.
    std::fs::write(
        d.join("tiny.toml"),
        TINY.replace("bins = [4, 8]", "bins = 4"),
    )
    .unwrap();
    let o = sweep_in(d, "c2", &[]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("2 rows and the new one would have 1"));
    assert!(!d.join("c2").exists(), "refused before computing");
    // --force replaces it (the report-only run still says it is incomplete: exit 3).
    let o = sweep_in(d, "empty", &["--report-only", "--force"]);
    assert_eq!(
        o.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert_ne!(
        std::fs::read(d.join("rep/results.parquet")).unwrap(),
        before
    );
    // Equal or more rows need no --force.
    ok(sweep(d, &[]), "one row over an empty report");
}

#[test]
fn killed_report_writers_temporaries_are_removed_by_the_next_run() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("tiny.toml"), TINY).unwrap();
    ok(sweep(d, &[]), "cold");
    // What a report writer killed mid-write leaves: 0-byte temporaries under a dead pid.
    let dead = 4_194_399; // above Linux's largest pid_max
    let leftovers = [
        d.join(format!("rep/.tmp-{dead}-index.html")),
        d.join(format!("rep/.tmp-{dead}-results.csv")),
        d.join(format!("rep/plots/.tmp-{dead}-pareto.png")),
        d.join(format!("rep/heatmaps/.tmp-{dead}-x.png")),
    ];
    for p in &leftovers {
        std::fs::write(p, b"").unwrap();
    }
    let o = sweep(d, &[]);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    ok(o, "warm");
    for p in &leftovers {
        assert!(!p.exists(), "{} left; {err}", p.display());
    }
    assert!(err.contains("removed 4 temporary file(s)"), "{err}");
}

#[test]
fn closed_pipe_ends_quietly() {
    use std::os::unix::process::ExitStatusExt;
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("tiny.toml"), TINY).unwrap();
    for args in [
        vec!["scenes"],
        vec!["methods"],
        vec!["sweep", "tiny.toml", "--cache", "c", "--plan"],
        vec!["cache", "ls", "--cache", "c"],
    ] {
        let mut child = command(&args, dir.path())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // `| head -0`: the reader is gone before the first write.
        drop(child.stdout.take());
        let o = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.is_empty(), "{args:?}: {err}");
        // Killed by SIGPIPE like any Unix filter (a shell shows 141), or done before it wrote.
        assert!(
            o.status.signal() == Some(13) || o.status.success(),
            "{args:?}: {:?}",
            o.status
        );
    }
}
