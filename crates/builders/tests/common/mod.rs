//! Shared helpers for the builder tests: deterministic synthetic inputs and the builders as a list.
#![allow(dead_code)]
use bvhlab_builders::{binned_sah, spatial_median, sweep_sah, TopDownConfig};
use bvhlab_bvh::{Aabb, Bvh, Vec3};

pub type BuildFn = fn(&[Aabb], &[Vec3], &TopDownConfig) -> Bvh;

fn binned16(b: &[Aabb], c: &[Vec3], cfg: &TopDownConfig) -> Bvh {
    binned_sah::build(b, c, 16, cfg)
}

fn binned16_all(b: &[Aabb], c: &[Vec3], cfg: &TopDownConfig) -> Bvh {
    let opts = binned_sah::BinnedOptions {
        axes: binned_sah::Axes::All,
        ..binned_sah::BinnedOptions::new(16)
    };
    binned_sah::build_with_options(b, c, &opts, cfg)
}

pub const BUILDERS: [(&str, BuildFn); 4] = [
    ("spatial-median", spatial_median::build),
    ("binned-sah", binned16),
    ("binned-sah axes=all", binned16_all),
    ("sweep-sah", sweep_sah::build),
];

pub use bvhlab_geom::rng::SplitMix64 as Rng;

pub fn centers_of(boxes: &[Aabb]) -> Vec<Vec3> {
    boxes.iter().map(|b| b.center()).collect()
}

/// `n` small random boxes in the unit cube (sizes up to `size`).
pub fn random_boxes(n: usize, size: f32, seed: u64) -> Vec<Aabb> {
    let mut r = Rng(seed);
    (0..n)
        .map(|_| {
            let p = Vec3::new(r.f32(), r.f32(), r.f32());
            let e = Vec3::new(r.f32(), r.f32(), r.f32()) * size;
            Aabb::new(p, p + e)
        })
        .collect()
}

/// Boxes of different sizes that all share one centre.
pub fn equal_centroid_boxes(n: usize) -> Vec<Aabb> {
    (0..n)
        .map(|i| {
            let h = Vec3::splat(0.01 + i as f32 * 0.001);
            Aabb::new(Vec3::splat(0.5) - h, Vec3::splat(0.5) + h)
        })
        .collect()
}

/// Boxes of triangles lying in the plane z = 0.25 (zero extent on z).
pub fn flat_boxes(n: usize, seed: u64) -> Vec<Aabb> {
    let mut r = Rng(seed);
    (0..n)
        .map(|_| {
            let p = Vec3::new(r.f32(), r.f32(), 0.25);
            let e = Vec3::new(r.f32() * 0.02, r.f32() * 0.02, 0.0);
            Aabb::new(p, p + e)
        })
        .collect()
}

/// All identical point boxes: zero surface area everywhere.
pub fn point_boxes(n: usize) -> Vec<Aabb> {
    vec![Aabb::from_point(Vec3::new(1.0, 2.0, 3.0)); n]
}

/// Eq. 4 of the thesis, computed here independently of bvhlab_bvh::metrics (cross-check).
pub fn sah(bvh: &Bvh, c_t: f64, c_i: f64) -> f64 {
    let root = bvh.nodes[0].bounds.area_f64();
    let mut s = 0.0;
    for n in &bvh.nodes {
        let a = n.bounds.area_f64() / root;
        s += if n.is_leaf() {
            c_i * a * n.count as f64
        } else {
            c_t * a
        };
    }
    s
}

pub fn max_leaf_size(bvh: &Bvh) -> u32 {
    bvh.nodes
        .iter()
        .filter(|n| n.is_leaf())
        .map(|n| n.count)
        .max()
        .unwrap_or(0)
}
