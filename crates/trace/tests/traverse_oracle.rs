//! trace == brute_force on hand-made BVHs, counters behave, no NaN from zero direction components,
//! and results are identical at any thread count.
mod common;
use bvhlab_bvh::{Bvh, Node};
use bvhlab_geom::{Aabb, Triangle, Vec3};
use bvhlab_trace::{brute_force, random_rays, trace, Hit, Ray};
use common::*;

fn centroid_radius(tris: &[Triangle], b: &Aabb) -> f32 {
    tris.iter()
        .map(|t| (t.bounds().center() - b.center()).length())
        .fold(0.0, f32::max)
}

fn rays_for(tris: &[Triangle], n: usize, seed: u64) -> Vec<Ray> {
    let idx: Vec<u32> = (0..tris.len() as u32).collect();
    let b = bounds_of(tris, &idx);
    random_rays(&b, centroid_radius(tris, &b), n, seed)
}

fn assert_same(bvh: &Bvh, tris: &[Triangle], rays: &[Ray]) -> u64 {
    let got = trace(bvh, tris, rays);
    let want = brute_force(tris, rays);
    assert_eq!(got.hits.len(), rays.len());
    for (i, (g, w)) in got.hits.iter().zip(&want).enumerate() {
        assert_eq!(g, w, "ray {i}: {:?}", rays[i]);
    }
    assert_eq!(
        got.hit_count,
        want.iter().filter(|h| h.is_hit()).count() as u64
    );
    got.hit_count
}

#[test]
fn two_leaves_match_brute_force() {
    let tris = vec![
        Triangle::new(
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ),
        Triangle::new(
            Vec3::new(2.0, 0.0, 1.0),
            Vec3::new(3.0, 0.0, 1.0),
            Vec3::new(2.0, 1.0, 1.0),
        ),
    ];
    let b0 = tris[0].bounds();
    let b1 = tris[1].bounds();
    let bvh = Bvh {
        nodes: vec![
            Node::inner(b0.union(&b1), 1),
            Node::leaf(b0, 0, 1),
            Node::leaf(b1, 1, 1),
        ],
        prim_indices: vec![0, 1],
    };
    // A ray straight down -z through each triangle: known hits.
    let rays = [
        Ray {
            origin: Vec3::new(0.25, 0.25, 5.0),
            dir: Vec3::NEG_Z,
            tmax: f32::INFINITY,
        },
        Ray {
            origin: Vec3::new(2.25, 0.25, 5.0),
            dir: Vec3::NEG_Z,
            tmax: f32::INFINITY,
        },
        Ray {
            origin: Vec3::new(1.5, 0.25, 5.0),
            dir: Vec3::NEG_Z,
            tmax: f32::INFINITY,
        },
        Ray {
            origin: Vec3::new(2.25, 0.25, 5.0),
            dir: Vec3::NEG_Z,
            tmax: 3.9,
        },
    ];
    let s = trace(&bvh, &tris, &rays);
    assert_eq!(s.hits[0], Hit { t: 5.0, prim: 0 });
    assert_eq!(s.hits[1], Hit { t: 4.0, prim: 1 });
    assert!(!s.hits[2].is_hit());
    assert!(
        !s.hits[3].is_hit(),
        "tmax 3.9 stops short of the hit at t = 4"
    );
    // Root, then only the leaf the ray's box test admits.
    assert_eq!((s.steps[0], s.intersections[0]), (2, 1));
    assert_eq!((s.steps[1], s.intersections[1]), (2, 1));
    // Ray 2 passes between the leaf boxes: it enters the root only.
    assert_eq!((s.steps[2], s.intersections[2]), (1, 0));
    assert_eq!(
        s.total_steps,
        s.steps.iter().map(|&x| x as u64).sum::<u64>()
    );
    assert_eq!(s.hit_count, 2);

    let rays = rays_for(&tris, 2000, 1);
    assert_same(&bvh, &tris, &rays);
}

#[test]
fn one_leaf_matches_brute_force() {
    let tris = random_triangles(300, 0.2, 7);
    let bvh = one_leaf(&tris);
    let rays = rays_for(&tris, 3000, 2);
    let hits = assert_same(&bvh, &tris, &rays);
    assert!(
        hits > 300,
        "random rays through 300 triangles should hit often, got {hits}"
    );
    let s = trace(&bvh, &tris, &rays);
    // Every ray that meets the root box tests all triangles; nothing else is a step.
    for (st, it) in s.steps.iter().zip(&s.intersections) {
        assert!(*st <= 1);
        assert_eq!(*it, if *st == 1 { 300 } else { 0 });
    }
}

#[test]
fn median_tree_matches_brute_force_and_saves_work() {
    let tris = random_triangles(4000, 0.05, 11);
    let rays = rays_for(&tris, 10_000, 3);
    for leaf in [1, 4] {
        let bvh = median_bvh(&tris, leaf);
        let hits = assert_same(&bvh, &tris, &rays);
        assert!(hits > 1000, "hits {hits}");
        let s = trace(&bvh, &tris, &rays);
        let per_ray = s.total_intersections as f64 / rays.len() as f64;
        assert!(
            per_ray < 400.0,
            "a BVH should test far fewer than 4000 triangles per ray, got {per_ray}"
        );
    }
}

#[test]
fn deep_tree_spills_stack_without_panic() {
    // Depth 299 with a stack that grows to the depth: beyond any fixed array.
    let tris = random_triangles(300, 0.1, 5);
    let bvh = caterpillar(&tris);
    let rays = rays_for(&tris, 500, 4);
    assert_same(&bvh, &tris, &rays);
    let s = trace(&bvh, &tris, &rays);
    assert!(
        s.steps.iter().any(|&x| x as usize >= 300),
        "some ray should enter the whole chain"
    );
}

#[test]
fn zero_direction_components_give_no_nan() {
    // Axis-aligned rays whose origins lie exactly on box planes: (bound - origin) * (1/0) would be
    // NaN in a naive slab test.
    let tris = random_triangles(500, 0.1, 9);
    let bvh = median_bvh(&tris, 2);
    let mut rays = Vec::new();
    for t in tris.iter().take(100) {
        let b = t.bounds();
        let c = t.bounds().center();
        for (o, d) in [
            (Vec3::new(b.min.x, c.y, -1.0), Vec3::Z),
            (Vec3::new(c.x, b.max.y, 2.0), Vec3::NEG_Z),
            (Vec3::new(-1.0, b.min.y, b.min.z), Vec3::X),
            (Vec3::new(c.x, -1.0, c.z), Vec3::Y),
            (Vec3::new(c.x, c.y, -1.0), Vec3::new(0.0, 0.0, 1.0)),
            (Vec3::new(c.x, c.y, c.z), Vec3::ZERO),
        ] {
            rays.push(Ray {
                origin: o,
                dir: d,
                tmax: f32::INFINITY,
            });
        }
    }
    let s = trace(&bvh, &tris, &rays);
    let want = brute_force(&tris, &rays);
    assert!(s.hits.iter().all(|h| !h.t.is_nan()));
    assert!(s.hits.iter().all(|h| h.is_hit() == h.t.is_finite()));
    assert_eq!(s.hits, want);
    // The +z rays through triangle centres must hit something (each triangle's centre of box is
    // not always inside the triangle, so only require many hits).
    let hits = s.hits.iter().filter(|h| h.is_hit()).count();
    assert!(hits > 100, "hits {hits}");
    // A zero direction never hits.
    assert!(s.hits.iter().skip(5).step_by(6).all(|h| !h.is_hit()));
}

#[test]
fn empty_and_malformed_inputs_do_not_panic() {
    let tris = random_triangles(10, 0.3, 1);
    let rays = rays_for(&tris, 50, 1);
    let s = trace(&Bvh::default(), &tris, &rays);
    assert_eq!(s.hit_count, 0);
    // An empty scene's tree: a root with the empty box is not entered.
    let empty = Bvh {
        nodes: vec![
            Node::inner(Aabb::EMPTY, 1),
            Node::leaf(Aabb::EMPTY, 0, 1),
            Node::leaf(Aabb::EMPTY, 0, 1),
        ],
        prim_indices: vec![],
    };
    let s = trace(&empty, &[], &rays);
    assert_eq!(
        (s.hit_count, s.total_steps, s.total_intersections),
        (0, 0, 0)
    );
    // Out-of-range child and primitive indices are skipped.
    let bad = Bvh {
        nodes: vec![Node::inner(bounds_of(&tris, &[0, 1, 2]), 7)],
        prim_indices: vec![],
    };
    let _ = trace(&bad, &tris, &rays);
    let bad = Bvh {
        nodes: vec![Node::leaf(bounds_of(&tris, &[0]), 0, 5)],
        prim_indices: vec![0, 99],
    };
    let _ = trace(&bad, &tris, &rays);
    // A cycle (node 1 points back at node 0's children) terminates.
    let all = bounds_of(&tris, &(0..10).collect::<Vec<_>>());
    let cyc = Bvh {
        nodes: vec![
            Node::inner(all, 1),
            Node::inner(all, 1),
            Node::leaf(all, 0, 10),
        ],
        prim_indices: (0..10).collect(),
    };
    let _ = trace(&cyc, &tris, &rays);
    assert!(brute_force(&[], &rays).iter().all(|h| !h.is_hit()));
}

#[test]
fn identical_at_any_thread_count() {
    let tris = random_triangles(2000, 0.05, 21);
    let bvh = median_bvh(&tris, 2);
    let rays = rays_for(&tris, 5000, 8);
    let run = |n| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap();
        pool.install(|| trace(&bvh, &tris, &rays))
    };
    let (a, b) = (run(1), run(3));
    assert_eq!(a.hits, b.hits);
    assert_eq!(a.steps, b.steps);
    assert_eq!(a.intersections, b.intersections);
}

/// Regression (found by the Bonsai tests): duplicate triangles in sibling subtrees under a flat box.
/// The popped node's entry distance rounded one ulp above the equal-t hit and the node was culled,
/// so the lower-index tie went missing (ray 51: prim 747 instead of 119). The pop test now uses the
/// child test's slab margin; traversal must equal brute force exactly, ties included.
#[test]
fn equal_t_ties_behind_flat_boxes_are_found() {
    let scene = bvhlab_geom::load_scene("gen:degenerate:n=2000").unwrap();
    let (boxes, centers) = scene.boxes_and_centers();
    let cfg = bvhlab_builders::bonsai::BonsaiConfig {
        n: 16,
        t: 0.1,
        prune: true,
        top: bvhlab_builders::TopDownConfig {
            leaf: 1,
            ..Default::default()
        },
    };
    let bvh = bvhlab_builders::bonsai::build(&boxes, &centers, &cfg);
    let tris = &scene.triangles;
    let all = bounds_of(tris, &(0..tris.len() as u32).collect::<Vec<_>>());
    let core = bounds_of(tris, &(0..tris.len() as u32 - 1).collect::<Vec<_>>());
    let mut rays = random_rays(&all, 0.0, 1000, 7);
    rays.extend(random_rays(&core, 0.0, 1000, 8));
    assert_same(&bvh, tris, &rays);
}
