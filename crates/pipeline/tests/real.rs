//! The runner with the real loaders, builders, metrics and tracer on small generated scenes.
use bvhlab_pipeline::{with_threads, ChainSpec, RaySpec, Runner, Store};

fn chain(build: &str, rays: Option<RaySpec>) -> ChainSpec {
    let mut c = ChainSpec::new("gen:sphere:n=3000", build);
    c.repeat = 2;
    c.rays = rays;
    c
}

#[test]
fn all_ray_sets_measure_and_heatmap() {
    let dir = tempfile::tempdir().unwrap();
    let mut r = Runner::new(Store::open(dir.path()).unwrap());
    for rays in ["primary:40x30", "shadow:40x30", "random:2000"] {
        let mut c = chain("binned-sah", Some(RaySpec::parse(rays).unwrap()));
        c.compact = "collapse".into();
        let row = r.run_chain(&c, "t").unwrap();
        assert!(row.valid, "{rays}");
        assert_eq!(row.rays_kind.as_deref(), Some(rays));
        assert!(row.hits.unwrap() > 0 || rays.starts_with("shadow"), "{rays}: {row:?}");
        assert!(row.traversal_steps_per_ray.unwrap() > 0.0);
        assert!(row.trace_seconds.unwrap() > 0.0);
        match rays {
            "primary:40x30" => {
                assert_eq!(row.rays, Some(1200));
                assert!(std::path::Path::new(row.heatmap.as_ref().unwrap()).is_file());
            }
            "shadow:40x30" => assert!(row.rays.unwrap() <= 1200 && row.heatmap.is_none()),
            _ => assert_eq!(row.rays, Some(2000)),
        }
    }
    // 1 load, 1 build, 1 compact, 3 measures.
    assert_eq!(r.counts.computed, 6);
    assert!(Store::open(dir.path()).unwrap().verify().bad.is_empty());
}

#[test]
fn builds_are_bit_identical_at_any_thread_count() {
    for build in ["spatial-median", "sweep-sah", "binned-sah"] {
        let hashes: Vec<String> = [1usize, 2]
            .iter()
            .map(|&t| {
                let mut r = Runner::new(Store::temporary().unwrap());
                let c = chain(build, None);
                with_threads(Some(t), || r.run_chain(&c, "t")).unwrap().unwrap().bvh_hash
            })
            .collect();
        assert_eq!(hashes[0], hashes[1], "{build}");
    }
}

#[test]
fn gen_spellings_share_a_key() {
    let dir = tempfile::tempdir().unwrap();
    let mut r = Runner::new(Store::open(dir.path()).unwrap());
    let a = r.run_chain(&ChainSpec { repeat: 1, ..ChainSpec::new("gen:sphere", "sweep-sah") }, "t").unwrap();
    let b = r.run_chain(&ChainSpec { repeat: 1, ..ChainSpec::new("gen:sphere:n=20000", "sweep-sah") }, "t").unwrap();
    assert_eq!(a.keys, b.keys);
    assert_eq!(r.counts.computed, 2);
}
