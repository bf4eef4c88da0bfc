//! Issue 12: a row says which CPU model timed its stages, read from the stages' manifests, and
//! flags rows whose stages were timed on different models (a sharded run on a mixed cluster).
use bvhlab_pipeline::store::{self, Manifest};
use bvhlab_pipeline::{ChainSpec, Key, RaySpec, Runner, Store};

fn chain() -> ChainSpec {
    let mut c = ChainSpec::new("gen:sphere:n=2000", "lbvh");
    c.compact = "collapse".into();
    c.rays = Some(RaySpec::parse("random:500").unwrap());
    c.repeat = 1;
    c
}

#[test]
fn machine_comes_from_the_manifests_and_mixed_models_are_flagged() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("c");
    let row = Runner::new(Store::open(&root).unwrap())
        .run_chain(&chain(), "t")
        .unwrap();
    assert_eq!(
        row.machine,
        store::cpu_model(),
        "computed here: this machine's model"
    );
    assert!(!row.machine_mixed);
    let m: Manifest = {
        let key = Key::from_hex(&row.keys["measure"]).unwrap();
        Store::open(&root)
            .unwrap()
            .read_manifest("measure", &key)
            .unwrap()
    };
    assert_eq!(m.machine.cpu_model, store::cpu_model());

    // The measure stage "ran" on another model (edit its manifest: manifests are not checksummed,
    // the data files they list are).
    let mpath = root
        .join("measure")
        .join(format!("{}.json", row.keys["measure"]));
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&mpath).unwrap()).unwrap();
    v["machine"]["cpu_model"] = "Other CPU 9000".into();
    std::fs::write(&mpath, serde_json::to_vec_pretty(&v).unwrap()).unwrap();
    let mut r = Runner::new(Store::open(&root).unwrap());
    let warm = r.run_chain(&chain(), "t").unwrap();
    assert_eq!(r.counts.computed, 0, "still a cache hit");
    assert!(warm.machine_mixed, "{}", warm.machine);
    assert_eq!(
        warm.machine,
        format!("{} + Other CPU 9000", store::cpu_model())
    );
    assert_eq!(
        warm.build_machine,
        store::cpu_model(),
        "built here: the build time stays comparable"
    );

    // The compaction ran on yet another model: the construction itself mixes models.
    let cpath = root
        .join("compact")
        .join(format!("{}.json", row.keys["compact"]));
    let mut c: serde_json::Value = serde_json::from_slice(&std::fs::read(&cpath).unwrap()).unwrap();
    c["machine"]["cpu_model"] = "Third CPU".into();
    std::fs::write(&cpath, serde_json::to_vec_pretty(&c).unwrap()).unwrap();
    let both = Runner::new(Store::open(&root).unwrap())
        .run_chain(&chain(), "t")
        .unwrap();
    assert_eq!(
        both.build_machine,
        format!("{} + Third CPU", store::cpu_model())
    );
    assert_eq!(
        both.machine,
        format!("{} + Third CPU + Other CPU 9000", store::cpu_model())
    );
    c["machine"]["cpu_model"] = store::cpu_model().into();
    std::fs::write(&cpath, serde_json::to_vec_pretty(&c).unwrap()).unwrap();

    // A manifest from before models were recorded (no field): unknown, compatible with any.
    v["machine"].as_object_mut().unwrap().remove("cpu_model");
    std::fs::write(&mpath, serde_json::to_vec_pretty(&v).unwrap()).unwrap();
    let old = Runner::new(Store::open(&root).unwrap())
        .run_chain(&chain(), "t")
        .unwrap();
    assert!(!old.machine_mixed);
    assert_eq!(old.machine, store::cpu_model());
}
