//! Every builder the pipeline offers (the registry, so builders added later are covered without
//! touching this file), with and without SAH compaction, on every generated scene type: the BVH passes
//! structural validation and finds the same closest hit as brute force on random rays (thesis 4.4).
use bvhlab_bvh::{collapse::collapse, validate, CostParams};
use bvhlab_geom::load_scene;
use bvhlab_pipeline::registry::Registry;
use bvhlab_trace::{brute_force, random_rays, trace};
use std::collections::BTreeMap;

const SCENES: &[&str] = &[
    "gen:sphere:n=3000",
    "gen:terrain:n=3000",
    "gen:hairball:n=500",
    "gen:city:blocks=6",
    "gen:outlier:e=20,n=2000",
    "gen:degenerate:n=2000",
];

#[test]
fn every_registered_builder_matches_brute_force() {
    let reg = Registry::standard();
    let cost = CostParams::default();
    for spec in SCENES {
        let scene = load_scene(spec).unwrap();
        let (boxes, centers) = scene.boxes_and_centers();
        let b = scene.bounds();
        let radius = centers.iter().map(|c| (*c - b.center()).length()).fold(0.0, f32::max);
        let rays = random_rays(&b, radius, 3000, 7);
        let want = brute_force(&scene.triangles, &rays);
        for info in &reg.builders {
            for leaf in ["1", "2"] {
                let raw: BTreeMap<String, String> = [("leaf".to_string(), leaf.to_string())].into();
                let resolved = reg.resolve(info.name, &raw, cost).unwrap();
                let built = (info.run)(&boxes, &centers, &resolved);
                for (what, bvh) in [("built", built.clone()), ("collapsed", collapse(&built, cost))] {
                    let ctx = format!("{spec} {} leaf={leaf} {what}", info.name);
                    validate(&bvh, &boxes).unwrap_or_else(|e| panic!("{ctx}: invalid: {e}"));
                    let got = trace(&bvh, &scene.triangles, &rays);
                    for (i, (g, w)) in got.hits.iter().zip(&want).enumerate() {
                        let same = g.prim == w.prim
                            || (g.is_hit() && w.is_hit() && (g.t - w.t).abs() <= 1e-4 * w.t.abs().max(1e-30));
                        assert!(same, "{ctx}: ray {i} got {g:?}, brute force {w:?}");
                    }
                }
            }
        }
    }
}
