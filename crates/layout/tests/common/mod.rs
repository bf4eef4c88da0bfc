//! Shared oracle for the layout tests: generated scenes, seeded random rays, brute-force hits, and
//! the comparison the issue asks for (same triangle, or same t within 1e-6 relative).
#![allow(dead_code)]
use bvhlab_builders::{binned_sah, TopDownConfig};
use bvhlab_bvh::Bvh;
use bvhlab_geom::{load_scene, Scene};
use bvhlab_layout::{build, Layout, LayoutSpec};
use bvhlab_trace::{brute_force, random_rays, Hit, Ray};
use std::collections::BTreeMap;

pub const SCENES: &[&str] = &[
    "gen:sphere:n=3000",
    "gen:terrain:n=3000",
    "gen:hairball:n=500",
    "gen:city:blocks=6",
    "gen:outlier:e=20,n=2000",
    "gen:degenerate:n=2000",
];

pub struct Case {
    pub spec: String,
    pub scene: Scene,
    pub bvh: Bvh,
    pub rays: Vec<Ray>,
    pub want: Vec<Hit>,
}

/// Scene, a binned-SAH BVH (leaf = `leaf`), `n` random rays and their brute-force hits.
pub fn case(spec: &str, leaf: u32, n: usize, seed: u64) -> Case {
    let scene = load_scene(spec).unwrap();
    let (boxes, centers) = scene.boxes_and_centers();
    let cfg = TopDownConfig {
        leaf,
        ..Default::default()
    };
    let bvh = binned_sah::build(&boxes, &centers, 16, &cfg);
    let b = scene.bounds();
    let radius = centers
        .iter()
        .map(|c| (*c - b.center()).length())
        .fold(0.0, f32::max);
    let rays = random_rays(&b, radius, n, seed);
    let want = brute_force(&scene.triangles, &rays);
    Case {
        spec: spec.to_string(),
        scene,
        bvh,
        rays,
        want,
    }
}

pub fn spec(name: &str, kv: &[(&str, &str)]) -> LayoutSpec {
    let raw: BTreeMap<String, String> = kv
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    LayoutSpec::parse(name, &raw).unwrap_or_else(|e| panic!("{name} {kv:?}: {e}"))
}

/// Builds `spec` on the case, validates it and compares every ray with brute force.
pub fn check(c: &Case, spec: &LayoutSpec) -> Layout {
    let ctx = format!("{} {} [{}]", c.spec, spec.name, spec.params_string());
    let l = build(spec, &c.bvh, &c.scene.triangles)
        .unwrap_or_else(|e| panic!("{ctx}: build failed: {e}"));
    l.validate(&c.scene.triangles)
        .unwrap_or_else(|e| panic!("{ctx}: invalid: {e}"));
    let got = l.trace(&c.scene.triangles, &c.rays);
    assert_eq!(got.hits.len(), c.rays.len());
    for (i, (g, w)) in got.hits.iter().zip(&c.want).enumerate() {
        assert!(
            same_hit(g, w),
            "{ctx}: ray {i} got {g:?}, brute force {w:?}"
        );
    }
    l
}

/// Same triangle, or both hit at the same t within 1e-6 relative.
pub fn same_hit(g: &Hit, w: &Hit) -> bool {
    g.prim == w.prim || (g.is_hit() && w.is_hit() && (g.t - w.t).abs() <= 1e-6 * w.t.abs())
}
