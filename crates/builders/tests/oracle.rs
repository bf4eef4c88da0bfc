//! Every builder finds the same closest hit as brute force on random rays (DEVELOPERS.md).
mod common;
use bvhlab_builders::TopDownConfig;
use bvhlab_trace::{brute_force, random_rays, trace};
use common::BUILDERS;

#[test]
fn closest_hits_match_brute_force() {
    for spec in [
        "gen:sphere:n=3000",
        "gen:terrain:n=3000",
        "gen:degenerate:n=2000",
        "gen:city:blocks=6",
    ] {
        let scene = bvhlab_geom::load_scene(spec).expect("generated scene");
        let (boxes, centers) = scene.boxes_and_centers();
        let rays = random_rays(&scene.bounds(), 0.0, 3000, 5);
        let oracle = brute_force(&scene.triangles, &rays);
        assert!(
            oracle.iter().any(|h| h.is_hit()),
            "{spec}: rays should hit something"
        );
        for leaf in [1, 2, 4] {
            let cfg = TopDownConfig {
                leaf,
                ..Default::default()
            };
            for (name, build) in BUILDERS {
                let bvh = build(&boxes, &centers, &cfg);
                let got = trace(&bvh, &scene.triangles, &rays);
                for (i, (g, o)) in got.hits.iter().zip(&oracle).enumerate() {
                    assert_eq!(g, o, "{name} leaf {leaf} on {spec}, ray {i}");
                }
            }
        }
    }
}
