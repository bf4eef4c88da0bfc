//! The SBVH (Stich et al. 2009): valid with repeated references (`validate_split`), the same
//! closest hits as brute force, bounded reference growth, identical trees at any thread count, and
//! spatial splits that pay off where they should (long thin triangles).
use bvhlab_builders::sbvh::{build, SbvhConfig};
use bvhlab_builders::TopDownConfig;
use bvhlab_bvh::{metrics, validate_split, CostParams};
use bvhlab_trace::{brute_force, random_rays, trace};

const SCENES: &[&str] = &[
    "gen:sphere:n=3000",
    "gen:terrain:n=3000",
    "gen:hairball:n=400",
    "gen:city:blocks=5",
    "gen:degenerate:n=2000",
    "gen:huge-edge",
    "gen:flat",
    "gen:slivers",
    "gen:dups",
    "gen:same-centroid",
    "gen:single",
    "gen:outlier:e=20,n=2000",
];

fn cfg(leaf: u32, growth: f64) -> SbvhConfig {
    SbvhConfig { growth, top: TopDownConfig { leaf, ..Default::default() }, ..Default::default() }
}

#[test]
fn valid_and_exact_on_every_scene() {
    for spec in SCENES {
        let scene = bvhlab_geom::load_scene(spec).expect("generated scene");
        let (boxes, _) = scene.boxes_and_centers();
        let b = scene.bounds();
        let radius = b.extent().length();
        let rays = random_rays(&b, radius, 2000, 3);
        let want = brute_force(&scene.triangles, &rays);
        for (leaf, growth) in [(1, 1.5), (2, 1.5), (4, 4.0), (2, 1.0)] {
            let c = cfg(leaf, growth);
            let bvh = build(&scene.triangles, &c);
            let ctx = format!("{spec} leaf={leaf} growth={growth}");
            validate_split(&bvh, &boxes).unwrap_or_else(|e| panic!("{ctx}: {e}"));
            let n = scene.triangles.len();
            assert!(
                bvh.prim_indices.len() as f64 <= (growth * n as f64).floor().max(n as f64),
                "{ctx}: {} references for {n} triangles",
                bvh.prim_indices.len()
            );
            let got = trace(&bvh, &scene.triangles, &rays);
            for (i, (g, w)) in got.hits.iter().zip(&want).enumerate() {
                let same = g.prim == w.prim || (g.is_hit() && w.is_hit() && (g.t - w.t).abs() <= 1e-6 * w.t.abs());
                assert!(same, "{ctx}: ray {i} got {g:?}, brute force {w:?}");
            }
        }
    }
}

#[test]
fn same_tree_at_any_thread_count() {
    // Large enough for the parallel split (subtrees of 4096 references and more).
    let scene = bvhlab_geom::load_scene("gen:city:blocks=32").unwrap();
    let c = SbvhConfig::default();
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(|| build(&scene.triangles, &c));
    let four = rayon::ThreadPoolBuilder::new().num_threads(4).build().unwrap().install(|| build(&scene.triangles, &c));
    assert!(scene.triangles.len() > 8192, "{}", scene.triangles.len());
    assert_eq!(one, four);
}

#[test]
fn spatial_splits_lower_the_cost_of_long_triangles() {
    // Long diagonal slivers overlap everywhere: object splits cannot separate them, spatial
    // splits can (Stich 2009, figure 1).
    let cost = CostParams::default();
    for spec in ["gen:slivers", "gen:hairball:n=400"] {
        let scene = bvhlab_geom::load_scene(spec).unwrap();
        let object = metrics(&build(&scene.triangles, &cfg(2, 1.0)), cost).sah_cost;
        let spatial = metrics(&build(&scene.triangles, &cfg(2, 1.5)), cost).sah_cost;
        assert!(spatial < object, "{spec}: with spatial splits {spatial}, object splits only {object}");
    }
}
