//! Slurm for real: `bvhlab slurm --submit` on a running Slurm (one node is enough; CI starts a
//! localhost cluster with scripts/setup-slurm.sh). Ignored by default: `.ci/run` runs them with
//! `cargo test -p bvhlab --test slurm -- --ignored --test-threads=1` after the setup script.
//! `BVHLAB_BIN` picks the binary the jobs run (default: this test build's `bvhlab`).
//!
//! 1. A 4-task array of a >= 100-stage experiment into a fresh cache: every task finishes, the
//!    tasks' `computed` add up to a single local cold sweep's (no stage computed twice), the
//!    report job's results equal the local run's (timing columns aside), and a following local
//!    sweep computes nothing.
//! 2. One task is cancelled mid-run (scancel): the first report is incomplete; resubmitting the
//!    same command completes it with nothing lost, and `cache verify` is clean.
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

mod common;
use common::untimed_rows;

/// experiments/cluster-small.toml: 4 generated scenes x (1 load + 4 encodes + 12 builds + 4
/// compactions + 16 measures) = 148 stages; about 20 s cold on one thread of the release build (the
/// hairball's rays are most of it), so a task can be cancelled while it runs.
fn experiment() -> String {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../experiments/cluster-small.toml");
    std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

fn bin() -> PathBuf {
    std::env::var_os("BVHLAB_BIN")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_BIN_EXE_bvhlab")))
}

fn bvhlab(args: &[&str], cwd: &Path) -> Output {
    Command::new(bin())
        .args(args)
        .current_dir(cwd)
        .env_remove("BVHLAB_CACHE")
        .env_remove("BVHLAB_MAX_MEMORY")
        .output()
        .unwrap()
}

fn json_line(text: &str) -> serde_json::Value {
    let last = text
        .lines()
        .rev()
        .find(|l| l.starts_with('{'))
        .unwrap_or_else(|| panic!("no JSON line in: {text}"));
    serde_json::from_str(last).unwrap_or_else(|e| panic!("{e}: {last}"))
}

fn ok_json(o: &Output, what: &str) -> serde_json::Value {
    assert!(
        o.status.success(),
        "{what}: exit {:?}\n{}\n{}",
        o.status.code(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    json_line(&String::from_utf8_lossy(&o.stdout))
}

fn run(cmd: &str, args: &[&str]) -> String {
    let o = Command::new(cmd)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("{cmd}: {e}"));
    String::from_utf8_lossy(&o.stdout).to_string()
}

/// Waits until none of `jobs` is pending or running.
fn wait_jobs(jobs: &[&str], limit: Duration) {
    let t0 = Instant::now();
    let list = jobs.join(",");
    loop {
        let q = run("squeue", &["-h", "-j", &list, "-o", "%i %T"]);
        if q.trim().is_empty() {
            return;
        }
        assert!(
            t0.elapsed() < limit,
            "jobs {list} still queued after {limit:?}:\n{q}"
        );
        std::thread::sleep(Duration::from_millis(500));
    }
}

/// `JobState` and `ExitCode` of a finished job from `scontrol show job` (kept for MinJobAge).
fn job_state(id: &str) -> (String, String) {
    let s = run("scontrol", &["show", "job", id]);
    let field = |k: &str| {
        s.split_whitespace()
            .find_map(|w| w.strip_prefix(&format!("{k}=")))
            .unwrap_or("?")
            .to_string()
    };
    (field("JobState"), field("ExitCode"))
}

fn slurm_ready() {
    let o = Command::new("sinfo").args(["-h", "-o", "%T"]).output();
    match o {
        Ok(o) if o.status.success() && !String::from_utf8_lossy(&o.stdout).trim().is_empty() => {}
        _ => panic!("no running Slurm: run scripts/setup-slurm.sh first"),
    }
}

struct Submission {
    array: String,
    report: String,
    logs: PathBuf,
}

fn submit(cwd: &Path, cache: &str, out: &str) -> Submission {
    let v = ok_json(
        &bvhlab(
            &[
                "slurm", "t.toml", "--tasks", "4", "--cache", cache, "--out", out, "--submit",
            ],
            cwd,
        ),
        "bvhlab slurm --submit",
    );
    Submission {
        array: v["array_job"].as_str().expect("array job id").to_string(),
        report: v["report_job"].as_str().expect("report job id").to_string(),
        logs: PathBuf::from(v["logs"].as_str().unwrap()),
    }
}

/// The last JSON line of each finished task's log (tasks cut off before the end print none).
fn task_results(s: &Submission) -> Vec<(u32, serde_json::Value)> {
    let mut v = Vec::new();
    for i in 1..=4 {
        let p = s.logs.join(format!("task-{}_{i}.out", s.array));
        let text = std::fs::read_to_string(&p).unwrap_or_default();
        if text.lines().any(|l| l.starts_with('{')) {
            v.push((i, json_line(&text)));
        }
    }
    v
}

fn local_reference(cwd: &Path) -> (u64, Vec<Vec<(String, String)>>, f64) {
    let t0 = Instant::now();
    let v = ok_json(
        &bvhlab(
            &[
                "sweep",
                "t.toml",
                "--cache",
                "local",
                "--out",
                "local-rep",
                "--threads",
                "1",
            ],
            cwd,
        ),
        "local cold sweep",
    );
    let secs = t0.elapsed().as_secs_f64();
    (
        v["computed"].as_u64().unwrap(),
        untimed_rows(&cwd.join("local-rep")),
        secs,
    )
}

#[test]
#[ignore = "needs a running Slurm: scripts/setup-slurm.sh"]
fn array_of_shards_computes_each_stage_once_and_matches_a_local_sweep() {
    slurm_ready();
    let dir = tempfile::tempdir().unwrap();
    let cwd = dir.path();
    std::fs::write(cwd.join("t.toml"), experiment()).unwrap();
    let (local_computed, reference, local_secs) = local_reference(cwd);
    assert!(
        local_computed >= 100,
        "the experiment has {local_computed} stages"
    );

    let t0 = Instant::now();
    let s = submit(cwd, "shared", "slurm-rep");
    wait_jobs(&[&s.array, &s.report], Duration::from_secs(1200));
    let array_secs = t0.elapsed().as_secs_f64();

    let tasks = task_results(&s);
    assert_eq!(tasks.len(), 4, "every task finished: {tasks:?}");
    let computed: u64 = tasks
        .iter()
        .map(|(_, v)| v["computed"].as_u64().unwrap())
        .sum();
    for (i, v) in &tasks {
        eprintln!("task {i}: {v}");
    }
    assert_eq!(
        computed, local_computed,
        "the tasks' computed add up to one cold sweep's: no stage computed twice"
    );
    let (state, exit) = job_state(&s.report);
    assert_eq!(
        (state.as_str(), exit.as_str()),
        ("COMPLETED", "0:0"),
        "report job"
    );
    assert_eq!(
        untimed_rows(&cwd.join("slurm-rep")),
        reference,
        "the report job's results equal the local run's"
    );

    let again = ok_json(
        &bvhlab(
            &["sweep", "t.toml", "--cache", "shared", "--out", "again"],
            cwd,
        ),
        "warm local sweep",
    );
    assert_eq!(
        again["computed"].as_u64(),
        Some(0),
        "a local sweep after the array computes nothing: {again}"
    );
    let verify = bvhlab(&["cache", "verify", "--cache", "shared"], cwd);
    assert!(
        verify.status.success(),
        "{}",
        String::from_utf8_lossy(&verify.stdout)
    );
    eprintln!(
        "{local_computed} stages; local cold sweep (1 thread) {local_secs:.1} s; 4-task array incl. report job {array_secs:.1} s \
         (wall, submission to the end of the report job)"
    );
}

#[test]
#[ignore = "needs a running Slurm: scripts/setup-slurm.sh"]
fn cancelled_task_then_resubmit_completes_the_report() {
    slurm_ready();
    let dir = tempfile::tempdir().unwrap();
    let cwd = dir.path();
    std::fs::write(cwd.join("t.toml"), experiment()).unwrap();
    let (_, reference, _) = local_reference(cwd);

    let s = submit(cwd, "shared", "slurm-rep");
    // Cancel task 2 once it has run for a moment (it has computed part of its shard).
    let task = format!("{}_2", s.array);
    let t0 = Instant::now();
    loop {
        let st = run("squeue", &["-h", "-j", &task, "-o", "%T"]);
        if st.trim() == "RUNNING" {
            break;
        }
        assert!(
            st.trim() == "PENDING" && t0.elapsed() < Duration::from_secs(300),
            "task 2: `{}`",
            st.trim()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    std::thread::sleep(Duration::from_millis(1500));
    let o = Command::new("scancel").arg(&task).output().unwrap();
    assert!(
        o.status.success(),
        "scancel: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    wait_jobs(&[&s.array, &s.report], Duration::from_secs(1200));
    let finished: Vec<u32> = task_results(&s).iter().map(|(i, _)| *i).collect();
    assert!(
        !finished.contains(&2),
        "task 2 was cancelled before it finished: {finished:?}"
    );
    let status = ok_json(
        &bvhlab(
            &[
                "sweep", "t.toml", "--cache", "shared", "--status", "--shards", "4",
            ],
            cwd,
        ),
        "status after the cancel",
    );
    assert!(
        status["missing"].as_u64().unwrap() > 0,
        "the cancel left chains missing: {status}"
    );
    let (state, _) = job_state(&s.report);
    assert_ne!(
        state, "COMPLETED",
        "the first report job reports the missing chains (exit 3)"
    );

    // The user resubmits the same command: only what is missing is computed.
    let s2 = submit(cwd, "shared", "slurm-rep");
    wait_jobs(&[&s2.array, &s2.report], Duration::from_secs(1200));
    let tasks = task_results(&s2);
    assert_eq!(tasks.len(), 4, "every resubmitted task finished: {tasks:?}");
    let (state, exit) = job_state(&s2.report);
    assert_eq!(
        (state.as_str(), exit.as_str()),
        ("COMPLETED", "0:0"),
        "second report job"
    );
    assert_eq!(
        untimed_rows(&cwd.join("slurm-rep")),
        reference,
        "nothing lost"
    );
    let status = ok_json(
        &bvhlab(
            &[
                "sweep", "t.toml", "--cache", "shared", "--status", "--shards", "4",
            ],
            cwd,
        ),
        "status after the resubmission",
    );
    assert_eq!(status["missing"].as_u64(), Some(0), "{status}");
    let verify = bvhlab(&["cache", "verify", "--cache", "shared"], cwd);
    assert!(
        verify.status.success(),
        "cache verify: {}",
        String::from_utf8_lossy(&verify.stdout)
    );
    let again = ok_json(
        &bvhlab(
            &["sweep", "t.toml", "--cache", "shared", "--out", "again"],
            cwd,
        ),
        "warm local sweep",
    );
    assert_eq!(again["computed"].as_u64(), Some(0), "{again}");
}
