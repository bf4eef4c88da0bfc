//! Unit tests of `store.rs`, in their own file beside it.
use super::*;

fn key(n: u8) -> Key {
    Key([n; 32])
}

fn manifest(stage: &str, k: &Key, files: BTreeMap<String, String>) -> Manifest {
    Manifest {
        key: k.hex(),
        stage: stage.into(),
        version: 1,
        params: BTreeMap::new(),
        inputs: vec![],
        files,
        versions: BTreeMap::new(),
        machine: Machine::current(),
        time_unix: now_unix(),
        compute_seconds: 0.0,
    }
}

#[test]
fn put_get_verify_gc() {
    let dir = tempfile::tempdir().unwrap();
    let s = Store::open(dir.path()).unwrap();
    let k = key(1);
    assert_eq!(s.get::<Vec<u32>>("build", &k, "bin"), None);
    let h = s.put("build", &k, "bin", &vec![1u32, 2, 3]).unwrap();
    s.commit(&manifest("build", &k, [("bin".to_string(), h)].into()))
        .unwrap();
    assert_eq!(s.get::<Vec<u32>>("build", &k, "bin"), Some(vec![1, 2, 3]));
    assert_eq!(s.entries().len(), 1);
    let v = s.verify();
    assert_eq!((v.entries, v.files_ok, v.bad.len()), (1, 1, 0));

    // An orphan (no manifest) and a temp file are garbage.
    s.put("build", &key(2), "bin", &5u8).unwrap();
    // Writer pid above Linux's pid_max: dead, so its temp file is garbage.
    fs::write(dir.path().join("build").join(".tmp-4999999-0-x.bin"), b"x").unwrap();
    // A live writer's (ours) temp file is left alone.
    let live = dir
        .path()
        .join("build")
        .join(format!(".tmp-{}-0-y.bin", std::process::id()));
    fs::write(&live, b"y").unwrap();
    let g = s.gc();
    assert_eq!(g.removed_files, 2);
    assert!(s.path("build", &k, "bin").is_file());
    assert!(!s.path("build", &key(2), "bin").exists());
    assert!(live.exists());
}

#[test]
fn corrupt_file_is_quarantined_not_used() {
    let dir = tempfile::tempdir().unwrap();
    let s = Store::open(dir.path()).unwrap();
    let k = key(3);
    let h = s.put("load", &k, "bin", &vec![9u64; 100]).unwrap();
    s.commit(&manifest("load", &k, [("bin".to_string(), h)].into()))
        .unwrap();
    let p = s.path("load", &k, "bin");
    let mut b = fs::read(&p).unwrap();
    let last = b.len() - 1;
    b[last] ^= 1;
    fs::write(&p, b).unwrap();
    let v = s.verify();
    assert_eq!(v.bad.len(), 1);
    assert!(!p.exists(), "verify quarantines the bad file");
    assert_eq!(s.get::<Vec<u64>>("load", &k, "bin"), None);
    assert_eq!(
        fs::read_dir(dir.path().join("quarantine")).unwrap().count(),
        1
    );
}

#[test]
fn get_quarantines_corrupt() {
    let dir = tempfile::tempdir().unwrap();
    let s = Store::open(dir.path()).unwrap();
    let k = key(4);
    s.put("load", &k, "sum", &"abc".to_string()).unwrap();
    let p = s.path("load", &k, "sum");
    fs::write(&p, b"garbage").unwrap();
    assert_eq!(s.get::<String>("load", &k, "sum"), None);
    assert!(!p.exists());
}

#[test]
fn temporary_store_is_removed() {
    let root;
    {
        let s = Store::temporary().unwrap();
        root = s.root().to_path_buf();
        s.put("x", &key(5), "bin", &1u8).unwrap();
        assert!(root.is_dir());
    }
    assert!(!root.exists());
}

#[test]
fn gc_removes_lock_leftovers_of_dead_processes_only() {
    let dir = tempfile::tempdir().unwrap();
    let s = Store::open(dir.path()).unwrap();
    let d = dir.path().join("locks").join("build");
    fs::create_dir_all(&d).unwrap();
    // Writer pid above Linux's pid_max: dead; ours: alive.
    let dead = format!("ab.lock.new-{}-4999999-0-0", lockfile::host_tag());
    let live = format!(
        "cd.lock.new-{}-{}-0-0",
        lockfile::host_tag(),
        std::process::id()
    );
    fs::write(d.join(&dead), b"x").unwrap();
    fs::write(d.join(&live), b"y").unwrap();
    // A lock held by this store is not removed either.
    s.lock("build", &key(9));
    let g = s.gc();
    assert_eq!(g.removed_locks, 1);
    assert!(!d.join(&dead).exists());
    assert!(d.join(&live).exists());
    assert!(s.lock_path("build", &key(9)).exists());
}

#[test]
fn root_resolution_prefers_cli() {
    assert_eq!(resolve_root(Some(Path::new("/a/b"))), PathBuf::from("/a/b"));
}
