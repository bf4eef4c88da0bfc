//! The runner with the real loaders, builders, metrics and tracer on small generated scenes.
use bvhlab_pipeline::{with_threads, ChainSpec, RaySpec, Registry, Runner, Store};

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
        assert!(
            row.hits.unwrap() > 0 || rays.starts_with("shadow"),
            "{rays}: {row:?}"
        );
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

/// Every registered builder (code-using ones with morton and emc64-var) gives the same BVH bytes
/// with 1 and 2 threads on a scene of >= 20k triangles (large enough for the parallel paths).
#[test]
fn builds_are_bit_identical_at_any_thread_count() {
    let scene = "gen:hairball:n=20000";
    let reg = Registry::standard();
    let mut chains = Vec::new();
    for b in &reg.builders {
        let encoders: &[Option<&str>] = if b.codes.is_some() {
            &[Some("morton"), Some("emc64-var")]
        } else {
            &[None]
        };
        for e in encoders {
            let mut c = ChainSpec::new(scene, b.name);
            c.encode = e.map(str::to_string);
            c.repeat = 1;
            chains.push(c);
        }
    }
    assert!(chains.len() >= 3 + 3 * 2);
    let rows = |t: usize| {
        let mut r = Runner::new(Store::temporary().unwrap());
        with_threads(Some(t), || {
            chains
                .iter()
                .map(|c| r.run_chain(c, "t").unwrap())
                .collect::<Vec<_>>()
        })
        .unwrap()
    };
    let (one, two) = (rows(1), rows(2));
    assert!(one[0].triangles >= 20_000, "{}", one[0].triangles);
    for (a, b) in one.iter().zip(&two) {
        assert!(a.valid, "{}", a.method);
        assert_eq!((a.threads, b.threads), (1, 2));
        assert_eq!(a.bvh_hash, b.bvh_hash, "{}", a.method);
        assert_eq!(a.keys, b.keys, "{}", a.method);
        assert_eq!(
            a.duplicate_code_fraction, b.duplicate_code_fraction,
            "{}",
            a.method
        );
    }
}

/// The bottom-up chain end to end: encode -> build (+ compaction) -> measure and focus, with the row
/// fields of the encode stage.
#[test]
fn bottom_up_chain_rows() {
    let dir = tempfile::tempdir().unwrap();
    let mut r = Runner::new(Store::open(dir.path()).unwrap());
    let mut c = ChainSpec::new("gen:outlier:e=20,n=3000", "aac");
    c.encode = Some("morton".into());
    c.params.insert("preset".into(), "fast".into());
    c.repeat = 2;
    c.rays = Some(RaySpec::parse("random:1000").unwrap());
    // The sphere (radius 1 at the origin) without the outlier.
    c.focus = Some(bvhlab_bvh::Aabb::new(
        glam::Vec3::splat(-1.5),
        glam::Vec3::splat(1.5),
    ));
    let row = r.run_chain(&c, "t").unwrap();
    assert!(row.valid);
    assert_eq!(row.method, "aac fast \u{b7} morton");
    assert_eq!(row.build_params, "delta=4,epsilon=0.2");
    assert_eq!(
        row.encode_params.as_deref(),
        Some("bits=auto:aac,bounds=scene,grid_bits=0")
    );
    assert!(row.code_bits.unwrap() > 0);
    // The far outlier squeezes the sphere into few Morton cells: many shared codes.
    assert!(
        row.duplicate_code_fraction.unwrap() > 0.5,
        "{:?}",
        row.duplicate_code_fraction
    );
    assert_eq!(row.focus_triangles, Some(row.triangles - 1));
    let f = row.focus_sah_cost.unwrap();
    assert!(f.is_finite() && f > 0.0);
    assert_eq!(r.counts.computed, 5, "load, encode, build, measure, focus");
    let mut r2 = Runner::new(Store::open(dir.path()).unwrap());
    let warm = r2.run_chain(&c, "t").unwrap();
    assert_eq!((r2.counts.computed, r2.counts.cached), (0, 5));
    assert_eq!(warm, row);
}

#[test]
fn gen_spellings_share_a_key() {
    let dir = tempfile::tempdir().unwrap();
    let mut r = Runner::new(Store::open(dir.path()).unwrap());
    let a = r
        .run_chain(
            &ChainSpec {
                repeat: 1,
                ..ChainSpec::new("gen:sphere", "sweep-sah")
            },
            "t",
        )
        .unwrap();
    let b = r
        .run_chain(
            &ChainSpec {
                repeat: 1,
                ..ChainSpec::new("gen:sphere:n=20000", "sweep-sah")
            },
            "t",
        )
        .unwrap();
    assert_eq!(a.keys, b.keys);
    assert_eq!(r.counts.computed, 2);
}
