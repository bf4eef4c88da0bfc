//! Oracle property (issue 6): on random small triangle soups with grid-snapped coordinates (so
//! ties, exact duplicates, shared edges, zero-area triangles and flat boxes are common) and random
//! rays (many aimed exactly at vertices and edges), every registered method — builders with every
//! encoder variant, compaction, optimizers — and every layout returns the brute-force closest hit
//! (same triangle, or same t within 1e-6 relative), or a clear error; never a panic.
mod methods;

use bvhlab_geom::{Scene, Triangle, Vec3};
use bvhlab_trace::Ray;
use methods::{run_all, Input, Opts, Tally};
use proptest::prelude::*;

/// A coordinate on a coarse lattice (half units in -3..=3): coincident vertices and equal box
/// bounds are the rule, not the exception.
fn coord() -> impl Strategy<Value = f32> {
    (-6i32..=6).prop_map(|i| i as f32 * 0.5)
}

fn vertex() -> impl Strategy<Value = Vec3> {
    (coord(), coord(), coord()).prop_map(|(x, y, z)| Vec3::new(x, y, z))
}

/// 1..=20 triangles; then some are replaced by exact copies of others, some flattened to z = 0.
fn soup() -> impl Strategy<Value = Vec<Triangle>> {
    (
        prop::collection::vec((vertex(), vertex(), vertex()), 1..=20),
        prop::collection::vec((any::<prop::sample::Index>(), any::<prop::sample::Index>(), 0u8..4), 0..8),
    )
        .prop_map(|(v, edits)| {
            let mut t: Vec<Triangle> = v.into_iter().map(|(a, b, c)| Triangle::new(a, b, c)).collect();
            for (i, j, kind) in edits {
                let (i, j) = (i.index(t.len()), j.index(t.len()));
                match kind {
                    0 | 1 => t[i] = t[j],
                    2 => t[i].v.iter_mut().for_each(|p| p.z = 0.0),
                    _ => t[i].v[2] = t[i].v[1],
                }
            }
            t
        })
}

/// Rays from lattice points (a wider ring around the soup) to lattice points or to a triangle's
/// vertex / edge midpoint / centroid; tmax infinite or the segment length.
fn rays() -> impl Strategy<Value = Vec<(Vec3, Option<(usize, u8)>, Vec3, bool)>> {
    prop::collection::vec(
        (
            vertex().prop_map(|v| v * 2.5),
            prop::option::of((0usize..64, 0u8..7)),
            vertex(),
            any::<bool>(),
        ),
        16,
    )
}

fn make_rays(tris: &[Triangle], spec: &[(Vec3, Option<(usize, u8)>, Vec3, bool)]) -> Vec<Ray> {
    spec.iter()
        .filter_map(|&(o, aim, p, finite)| {
            let target = match aim {
                Some((i, k)) => {
                    let t = &tris[i % tris.len()];
                    match k {
                        0..=2 => t.v[k as usize],
                        3..=5 => (t.v[(k - 3) as usize] + t.v[(k - 2) as usize % 3]) * 0.5,
                        _ => (t.v[0] + t.v[1] + t.v[2]) / 3.0,
                    }
                }
                None => p,
            };
            let d = target - o;
            let len = d.length();
            (len > 0.0).then(|| Ray {
                origin: o,
                dir: d / len,
                tmax: if finite { len * 1.5 } else { f32::INFINITY },
            })
        })
        .collect()
}

proptest! {
    // 64 cases by default (debug: about a second); PROPTEST_CASES=N for a longer search.
    #![proptest_config(ProptestConfig {
        cases: std::env::var("PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(64),
        ..ProptestConfig::default()
    })]

    #[test]
    fn every_method_returns_the_brute_force_hit(tris in soup(), spec in rays()) {
        let scene = Scene::from_triangles(tris);
        let rays = make_rays(&scene.triangles, &spec);
        let want = bvhlab_trace::brute_force(&scene.triangles, &rays);
        let input = Input::new(&scene, &rays);
        let mut tally = Tally::default();
        let opts = Opts { max_passes: 2, ..Opts::FULL };
        run_all(&input, opts, &mut |label, o| tally.add("soup", label, o, &want));
        prop_assert!(tally.failures.is_empty(), "{}", tally.summary());
    }
}
