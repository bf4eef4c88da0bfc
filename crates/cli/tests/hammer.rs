//! Many processes on one cache (issue 12: the cache must hold for a cluster's tasks): 8 concurrent
//! sweeps compute each stage exactly once in total; shard processes SIGKILLed 20 times at random
//! moments and restarted complete the experiment with the same results, a clean `cache verify`,
//! and no lock left that blocks anyone (a killed process's locks are taken over by the next
//! process that needs them, since its pid is gone; `cache gc` removes the rest).
use std::path::Path;
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

mod common;
use common::{command, ok, untimed_rows};

const EXPERIMENT: &str = r#"
name = "hammer"
scenes = ["gen:sphere:n=20000", "gen:city:blocks=12", "gen:terrain:n=20000", "gen:hairball:n=600"]
repeat = 1
[[chain]]
build = "binned-sah"
bins = [4, 8, 16]
compact = ["none", "collapse"]
[[chain]]
build = "sweep-sah"
[[chain]]
build = ["lbvh", "aac", "ploc"]
encode = ["morton", "emc64-var"]
[rays]
sets = ["random:4000"]
"#;

fn reference(cwd: &Path) -> (u64, Vec<Vec<(String, String)>>) {
    let v = ok(
        command(
            &[
                "sweep",
                "h.toml",
                "--cache",
                "single",
                "--out",
                "single-rep",
                "--threads",
                "1",
            ],
            cwd,
        )
        .output()
        .unwrap(),
        "single sweep",
    );
    (
        v["computed"].as_u64().unwrap(),
        untimed_rows(&cwd.join("single-rep")),
    )
}

fn lock_files(cache: &Path) -> Vec<String> {
    let mut v = Vec::new();
    let Ok(stages) = std::fs::read_dir(cache.join("locks")) else {
        return v;
    };
    for d in stages.flatten() {
        for f in std::fs::read_dir(d.path()).into_iter().flatten().flatten() {
            v.push(f.path().display().to_string());
        }
    }
    v
}

fn verify_clean(cwd: &Path, cache: &str, when: &str) {
    let o = command(&["cache", "verify", "--cache", cache], cwd)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "cache verify {when}: {}",
        String::from_utf8_lossy(&o.stdout)
    );
}

#[test]
fn eight_concurrent_sweeps_compute_each_stage_once() {
    let dir = tempfile::tempdir().unwrap();
    let cwd = dir.path();
    std::fs::write(cwd.join("h.toml"), EXPERIMENT).unwrap();
    let (single, rows) = reference(cwd);
    let t0 = Instant::now();
    let children: Vec<Child> = (0..8)
        .map(|i| {
            command(
                &[
                    "sweep",
                    "h.toml",
                    "--cache",
                    "shared",
                    "--out",
                    &format!("rep{i}"),
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
    for (i, c) in children.into_iter().enumerate() {
        let v = ok(c.wait_with_output().unwrap(), "concurrent sweep");
        computed += v["computed"].as_u64().unwrap();
        assert_eq!(
            v["computed"].as_u64().unwrap() + v["cached"].as_u64().unwrap(),
            single,
            "{v}"
        );
        assert_eq!(
            untimed_rows(&cwd.join(format!("rep{i}"))),
            rows,
            "sweep {i}: same rows as one sweep"
        );
    }
    eprintln!(
        "8 concurrent sweeps of {single} stages: {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    assert_eq!(
        computed, single,
        "each stage computed exactly once across 8 processes"
    );
    verify_clean(cwd, "shared", "after 8 concurrent sweeps");
    assert_eq!(
        lock_files(&cwd.join("shared")),
        Vec::<String>::new(),
        "every lock released"
    );
}

/// xorshift64*: a seeded, dependency-free PRNG for the kill schedule.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
}

#[test]
fn twenty_sigkills_of_shard_processes_then_resumption_completes() {
    let dir = tempfile::tempdir().unwrap();
    let cwd = dir.path();
    std::fs::write(cwd.join("h.toml"), EXPERIMENT).unwrap();
    let (_, rows) = reference(cwd);
    let shards = 4;
    let spawn = |cache: &str, i: usize| {
        command(
            &[
                "sweep",
                "h.toml",
                "--cache",
                cache,
                "--shard",
                &format!("{i}/{shards}"),
                "--threads",
                "1",
            ],
            cwd,
        )
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
    };
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let (mut kills, mut took_over, mut dead_locks) = (0, 0, 0);
    let t0 = Instant::now();
    let mut round = 0;
    // Rounds on fresh caches until 20 kills have hit running shards; each round then runs to the
    // end and is checked in full.
    while kills < 20 {
        let cache = format!("shared{round}");
        let mut running: Vec<Option<Child>> =
            (1..=shards).map(|i| Some(spawn(&cache, i))).collect();
        loop {
            assert!(
                t0.elapsed() < Duration::from_secs(900),
                "took too long ({kills} kills)"
            );
            std::thread::sleep(Duration::from_millis(20 + rng.next() % 300));
            for (j, slot) in running.iter_mut().enumerate() {
                if let Some(c) = slot {
                    if let Some(st) = c.try_wait().unwrap() {
                        assert!(st.success(), "shard {} failed: {st}", j + 1);
                        *slot = None;
                    }
                }
            }
            let live: Vec<usize> = (0..shards).filter(|&j| running[j].is_some()).collect();
            if live.is_empty() || kills >= 20 {
                break;
            }
            let j = live[(rng.next() % live.len() as u64) as usize];
            let c = running[j].as_mut().unwrap();
            c.kill().unwrap(); // SIGKILL at any moment: mid-write, holding locks, ...
            c.wait().unwrap();
            kills += 1;
            verify_clean(cwd, &cache, &format!("right after kill {kills}"));
            running[j] = Some(spawn(&cache, j + 1));
        }
        for (j, slot) in running.iter_mut().enumerate() {
            if let Some(c) = slot.take() {
                let o = c.wait_with_output().unwrap();
                assert!(
                    o.status.success(),
                    "shard {}: {}",
                    j + 1,
                    String::from_utf8_lossy(&o.stderr)
                );
                took_over += String::from_utf8_lossy(&o.stderr)
                    .matches("took over the stale compute lock")
                    .count();
            }
        }
        let t1 = Instant::now();
        let v = ok(
            command(
                &[
                    "sweep",
                    "h.toml",
                    "--cache",
                    &cache,
                    "--report-only",
                    "--out",
                    "rep",
                    "--threads",
                    "1",
                ],
                cwd,
            )
            .output()
            .unwrap(),
            "report after the kills",
        );
        assert!(
            t1.elapsed() < Duration::from_secs(60),
            "no lock left that blocks"
        );
        assert_eq!(
            v["missing_chains"].as_array().map(|a| a.len()),
            Some(0),
            "round {round}: {v}"
        );
        assert_eq!(
            untimed_rows(&cwd.join("rep")),
            rows,
            "round {round}: same results as an uninterrupted sweep"
        );
        let v = ok(
            command(
                &["sweep", "h.toml", "--cache", &cache, "--out", "warm"],
                cwd,
            )
            .output()
            .unwrap(),
            "warm",
        );
        assert_eq!(v["computed"].as_u64(), Some(0));
        verify_clean(cwd, &cache, "after the resumption");
        // Locks a killed process held on entries it had already committed are never needed
        // again; gc removes them (their owner is dead).
        dead_locks += lock_files(&cwd.join(&cache)).len();
        ok(
            command(&["cache", "gc", "--cache", &cache], cwd)
                .output()
                .unwrap(),
            "gc",
        );
        assert_eq!(
            lock_files(&cwd.join(&cache)),
            Vec::<String>::new(),
            "gc removes dead owners' locks"
        );
        round += 1;
    }
    eprintln!(
        "{kills} SIGKILLs over {round} rounds of 4 shards; {took_over} stale locks taken over by the final runs, \
         {dead_locks} dead locks left for gc; {:.1} s",
        t0.elapsed().as_secs_f64()
    );
}
