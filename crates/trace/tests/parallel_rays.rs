//! Regression (issue 6 proptest oracle): a ray with a zero direction component whose origin lies
//! exactly on a box's far plane along that axis. The slab product 0 * huge = 0 ended the interval at
//! t = 0, so the box was culled and the hit on its boundary (a vertex) was missed.
use bvhlab_builders::{binned_sah, TopDownConfig};
use bvhlab_geom::{Triangle, Vec3};
use bvhlab_trace::{brute_force, trace, Hit, Ray};

#[test]
fn axis_parallel_ray_on_the_box_plane_finds_the_vertex_hit() {
    // The shrunk proptest case: the ray runs in the plane z = 2.5 = the triangle box's max z and
    // hits the triangle exactly at its vertex (-3, 3, 2.5).
    let tris = vec![
        Triangle::new(
            Vec3::new(-3.0, 3.0, 2.5),
            Vec3::new(-0.5, 1.5, -2.0),
            Vec3::new(-0.5, -2.5, 0.0),
        ),
        Triangle::new(
            Vec3::new(2.0, 1.5, 0.5),
            Vec3::new(3.0, 1.0, -2.0),
            Vec3::new(1.5, 0.0, 0.5),
        ),
    ];
    let o = Vec3::new(5.0, 5.0, 2.5);
    let d = (Vec3::new(-3.0, 3.0, 2.5) - o).normalize();
    assert_eq!(d.z, 0.0);
    let rays = vec![Ray {
        origin: o,
        dir: d,
        tmax: f32::INFINITY,
    }];
    let want = brute_force(&tris, &rays);
    assert_eq!(want[0].prim, 0);
    let (boxes, centers): (Vec<_>, Vec<_>) = tris
        .iter()
        .map(|t| (t.bounds(), t.bounds().center()))
        .unzip();
    for leaf in [1, 2] {
        let bvh = binned_sah::build(
            &boxes,
            &centers,
            16,
            &TopDownConfig {
                leaf,
                ..Default::default()
            },
        );
        assert_eq!(trace(&bvh, &tris, &rays).hits, want, "leaf={leaf}");
    }
}

#[test]
fn axis_parallel_rays_on_box_planes_match_brute_force() {
    // Boxes on a half-unit lattice, rays along the axes and the face diagonals starting on lattice
    // planes: many run exactly in a box's min or max plane.
    let mut rng = bvhlab_geom::rng::SplitMix64::new(3);
    let mut g = || (rng.below(13) as f32 - 6.0) * 0.5;
    let tris: Vec<Triangle> = (0..60)
        .map(|_| {
            Triangle::new(
                Vec3::new(g(), g(), g()),
                Vec3::new(g(), g(), g()),
                Vec3::new(g(), g(), g()),
            )
        })
        .collect();
    let mut rays = Vec::new();
    for t in &tris {
        for v in t.v {
            for d in [
                Vec3::X,
                Vec3::NEG_Y,
                Vec3::Z,
                Vec3::new(1.0, 1.0, 0.0).normalize(),
                Vec3::new(0.0, -1.0, 1.0).normalize(),
            ] {
                rays.push(Ray {
                    origin: v - d * 10.0,
                    dir: d,
                    tmax: f32::INFINITY,
                });
            }
        }
    }
    let want = brute_force(&tris, &rays);
    let (boxes, centers): (Vec<_>, Vec<_>) = tris
        .iter()
        .map(|t| (t.bounds(), t.bounds().center()))
        .unzip();
    let hits = want.iter().filter(|h: &&Hit| h.is_hit()).count();
    assert!(hits > 100, "{hits}");
    for leaf in [1, 4] {
        let bvh = binned_sah::build(
            &boxes,
            &centers,
            16,
            &TopDownConfig {
                leaf,
                ..Default::default()
            },
        );
        let got = trace(&bvh, &tris, &rays).hits;
        let wrong = (0..rays.len()).filter(|&i| got[i] != want[i]).count();
        assert_eq!(wrong, 0, "leaf={leaf}: {wrong} of {} rays", rays.len());
    }
}
