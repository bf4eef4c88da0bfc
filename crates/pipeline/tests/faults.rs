//! Cache fault tolerance with the real stages: every kind of damage a crash, a disk or a careless
//! copy can do to a cache entry is detected, the entry recomputed with identical results, and
//! `Store::check` reports it (and repairs it so a second check is clean). Also: compute locks are
//! released after a failed chain, and two runners on one cache compute every node once.
use bvhlab_pipeline::{ChainSpec, Key, RaySpec, ResultRow, Runner, Store};
use std::path::{Path, PathBuf};

fn chain(n: u32, compact: &str) -> ChainSpec {
    let mut c = ChainSpec::new(&format!("gen:sphere:n={n}"), "binned-sah");
    c.compact = compact.into();
    c.repeat = 1;
    c.rays = Some(RaySpec::Random { count: 500 });
    c
}

fn chains() -> Vec<ChainSpec> {
    vec![
        chain(2000, "none"),
        chain(2000, "collapse"),
        chain(3000, "none"),
    ]
}

fn untimed(rows: &[ResultRow]) -> Vec<ResultRow> {
    rows.iter().map(ResultRow::untimed).collect()
}

/// Runs every chain with a fresh runner; returns rows and computed count.
fn run(root: &Path) -> (Vec<ResultRow>, u64) {
    let mut r = Runner::new(Store::open(root).unwrap());
    let rows = chains()
        .iter()
        .map(|c| r.run_chain(c, "t").unwrap())
        .collect();
    assert_eq!(r.store.held_locks(), 0, "no lock outlives its chain");
    (rows, r.counts.computed)
}

struct Fixture {
    _dir: tempfile::TempDir,
    root: PathBuf,
    rows: Vec<ResultRow>,
    store: Store,
}

fn fixture() -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("c");
    let (rows, computed) = run(&root);
    // 2 loads, 2 builds, 1 compaction, 3 measures.
    assert_eq!(computed, 8);
    let store = Store::open(&root).unwrap();
    assert!(store.check(false).clean());
    Fixture {
        _dir: dir,
        root,
        rows,
        store,
    }
}

fn key(f: &Fixture, row: usize, stage: &str) -> Key {
    Key::from_hex(&f.rows[row].keys[stage]).unwrap()
}

/// Damage, then: `check(false)` reports exactly `bad` files and touches nothing; a run recomputes
/// `recompute` nodes with identical rows; afterwards the cache is clean. Then the same damage again,
/// repaired by `check(true)` first: a second check is clean and the next run recomputes.
fn assert_detected(damage: impl Fn(&Fixture), bad: usize, recompute: u64) {
    let f = fixture();
    damage(&f);
    let r = f.store.check(false);
    assert_eq!(r.bad.len(), bad, "{:?}", r.bad);
    assert_eq!(
        f.store.check(false).bad.len(),
        bad,
        "a report-only check changes nothing"
    );
    let (rows, computed) = run(&f.root);
    assert_eq!(computed, recompute, "recomputed nodes");
    assert_eq!(untimed(&rows), untimed(&f.rows));
    if recompute > 0 {
        let r = f.store.check(false);
        assert!(r.clean(), "clean after the run: {:?}", r.bad);
    }

    let f = fixture();
    damage(&f);
    let r = f.store.check(true);
    assert_eq!(r.bad.len(), bad, "{:?}", r.bad);
    let r = f.store.check(false);
    assert!(r.clean(), "clean after repair: {:?}", r.bad);
    let (rows, computed) = run(&f.root);
    assert!(computed <= recompute.max(1), "{computed}");
    assert_eq!(untimed(&rows), untimed(&f.rows));
    assert!(f.store.check(false).clean());
}

fn rewrite(p: &Path, f: impl FnOnce(&mut Vec<u8>)) {
    let mut b = std::fs::read(p).unwrap();
    f(&mut b);
    std::fs::write(p, b).unwrap();
}

#[test]
fn truncated_artifacts() {
    // The measure summary (what a warm run reads): the measure is recomputed.
    assert_detected(
        |f| {
            rewrite(
                &f.store.path("measure", &key(f, 0, "measure"), "sum"),
                |b| b.truncate(b.len() / 2),
            )
        },
        1,
        1,
    );
    // A scene truncated to less than a header: found by check; a warm run never reads it, so
    // nothing is recomputed (the build summaries are intact).
    assert_detected(
        |f| {
            rewrite(&f.store.path("load", &key(f, 0, "load"), "bin"), |b| {
                b.truncate(20)
            })
        },
        1,
        0,
    );
}

#[test]
fn bit_flipped_artifacts() {
    // Both files of a build: the build is recomputed, and so is nothing else (its key is the same,
    // so the compaction and measures downstream stay valid).
    assert_detected(
        |f| {
            for ext in ["bin", "sum"] {
                rewrite(&f.store.path("build", &key(f, 0, "build"), ext), |b| {
                    let i = b.len() / 2;
                    b[i] ^= 0x10
                });
            }
        },
        2,
        1,
    );
}

#[test]
fn foreign_artifacts() {
    // A valid artifact of another key copied over this one: its codec checksum is fine, only the
    // manifest's blake3 tells it apart.
    assert_detected(
        |f| {
            let (a, b) = (key(f, 0, "build"), key(f, 2, "build"));
            for ext in ["bin", "sum"] {
                std::fs::copy(
                    f.store.path("build", &b, ext),
                    f.store.path("build", &a, ext),
                )
                .unwrap();
            }
        },
        2,
        1,
    );
    // Another entry's manifest too (the whole entry copied): the manifest names another key.
    assert_detected(
        |f| {
            let (a, b) = (key(f, 0, "measure"), key(f, 2, "measure"));
            for ext in ["sum", "json"] {
                std::fs::copy(
                    f.store.path("measure", &b, ext),
                    f.store.path("measure", &a, ext),
                )
                .unwrap();
            }
        },
        1,
        1,
    );
}

#[test]
fn broken_manifest_and_missing_file() {
    assert_detected(
        |f| {
            rewrite(
                &f.store.path("compact", &key(f, 1, "compact"), "json"),
                |b| b.truncate(b.len() - 3),
            )
        },
        1,
        1,
    );
    assert_detected(
        |f| std::fs::remove_file(f.store.path("measure", &key(f, 2, "measure"), "sum")).unwrap(),
        1,
        1,
    );
}

#[test]
fn leftovers_of_a_killed_run_are_harmless() {
    let f = fixture();
    let k = key(&f, 0, "build");
    // A temp file of a dead writer with a complete copy of a manifest: never read as an entry.
    let dead = f
        .root
        .join("build")
        .join(format!(".tmp-4999999-0-{}.json", Key([7; 32]).hex()));
    std::fs::copy(f.store.path("build", &k, "json"), &dead).unwrap();
    // Data files of an entry whose manifest was never written.
    let orphan = f.store.path("build", &Key([9; 32]), "bin");
    std::fs::copy(f.store.path("build", &k, "bin"), &orphan).unwrap();
    let entries = f.store.entries().len();
    let r = f.store.check(false);
    assert!(r.clean());
    assert_eq!((r.stale_temp, r.incomplete), (1, 1));
    let (rows, computed) = run(&f.root);
    assert_eq!(computed, 0);
    assert_eq!(rows, f.rows);
    assert_eq!(
        f.store.entries().len(),
        entries,
        "temp manifest is not an entry"
    );
    let r = f.store.check(true);
    assert_eq!(r.stale_temp, 1);
    assert!(!dead.exists());
    assert!(f.store.gc().removed_files >= 1);
    assert!(!orphan.exists());
    let r = f.store.check(false);
    assert_eq!((r.stale_temp, r.incomplete, r.bad.len()), (0, 0, 0));
}

#[test]
fn failed_chain_releases_its_locks() {
    let dir = tempfile::tempdir().unwrap();
    let obj = dir.path().join("bad.obj");
    std::fs::write(&obj, "v 0 0 0\nv 1 0 0\nf 1 2 9\n").unwrap();
    let root = dir.path().join("c");
    let mut r = Runner::new(Store::open(&root).unwrap());
    let c = ChainSpec::new(obj.to_str().unwrap(), "binned-sah");
    let e = r.run_chain(&c, "t").unwrap_err();
    assert_eq!(e.exit_code(), 2, "{e}");
    assert_eq!(r.store.held_locks(), 0);
    // The lock files are removed with the chain's end, so another store takes the load lock at once.
    let lock_dir = root.join("locks").join("load");
    let left: Vec<_> = std::fs::read_dir(&lock_dir).unwrap().flatten().collect();
    assert!(left.is_empty(), "lock released after the failed chain: {left:?}");
    let other = Store::open(&root).unwrap();
    let t0 = std::time::Instant::now();
    other.lock("load", &bvhlab_pipeline::Key([7; 32]));
    assert!(t0.elapsed() < std::time::Duration::from_secs(1));
    assert_eq!(other.held_locks(), 1);
}

#[test]
fn two_runners_compute_each_node_once() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("c");
    let single = {
        let d2 = tempfile::tempdir().unwrap();
        run(d2.path()).1
    };
    let handles: Vec<_> = (0..2)
        .map(|_| {
            let root = root.clone();
            std::thread::spawn(move || run(&root))
        })
        .collect();
    let results: Vec<_> = handles.into_iter().map(|h| h.join().unwrap()).collect();
    assert_eq!(
        results[0].1 + results[1].1,
        single,
        "each node computed once in total"
    );
    assert_eq!(untimed(&results[0].0), untimed(&results[1].0));
    assert!(Store::open(&root).unwrap().check(false).clean());
}
