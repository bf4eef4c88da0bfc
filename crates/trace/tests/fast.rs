//! The timed path (`fast`): with the exact test it equals `trace` (hits and counters) bit for bit;
//! with the watertight f32 test it agrees with brute force within `fast::agrees`' tolerance; it
//! is watertight on shared edges, scale-free, and identical at any thread count.
mod common;
use bvhlab_bvh::Bvh;
use bvhlab_geom::{Triangle, Vec3};
use bvhlab_trace::fast::{Exact, Watertight};
use bvhlab_trace::{brute_force, check_agreement, random_rays, trace, FastBvh2, Ray};
use common::*;

fn rays_for(tris: &[Triangle], n: usize, seed: u64) -> Vec<Ray> {
    let idx: Vec<u32> = (0..tris.len() as u32).collect();
    let b = bounds_of(tris, &idx);
    let r = tris
        .iter()
        .map(|t| (t.bounds().center() - b.center()).length())
        .fold(0.0, f32::max);
    random_rays(&b, r, n, seed)
}

/// Exact instantiation == the reference traversal; watertight == brute force within tolerance
/// (at most `edge` rays differing at all).
fn check(bvh: &Bvh, tris: &[Triangle], rays: &[Ray], edge: usize) {
    let f = FastBvh2::new(bvh, tris);
    let want = trace(bvh, tris, rays);
    let got = f.trace::<Exact>(rays);
    assert_eq!(got.hits, want.hits);
    assert_eq!(got.steps, want.steps);
    assert_eq!(got.intersections, want.intersections);
    let fast = f.hits(rays);
    assert_eq!(
        fast,
        f.trace::<Watertight>(rays).hits,
        "counting changes no hit"
    );
    let bf = brute_force(tris, rays);
    check_agreement(tris, rays, &fast, &bf, edge).unwrap();
}

#[test]
fn fast_path_matches_the_reference_on_hand_made_trees() {
    let tris = random_triangles(3000, 0.05, 3);
    let rays = rays_for(&tris, 4000, 1);
    for leaf in [1, 2, 4, 16] {
        check(&median_bvh(&tris, leaf), &tris, &rays, 4);
    }
    check(&one_leaf(&tris[..200]), &tris[..200], &rays[..500], 2);
    let small = random_triangles(300, 0.1, 5);
    check(&caterpillar(&small), &small, &rays_for(&small, 500, 4), 2);
}

#[test]
fn zero_direction_components_and_empty_inputs() {
    let tris = random_triangles(500, 0.1, 9);
    let bvh = median_bvh(&tris, 2);
    let mut rays = Vec::new();
    for t in tris.iter().take(100) {
        let (b, c) = (t.bounds(), t.bounds().center());
        for (o, d) in [
            (Vec3::new(b.min.x, c.y, -1.0), Vec3::Z),
            (Vec3::new(c.x, b.max.y, 2.0), Vec3::NEG_Z),
            (Vec3::new(-1.0, b.min.y, b.min.z), Vec3::X),
            (Vec3::new(c.x, -1.0, c.z), Vec3::Y),
            (Vec3::new(c.x, c.y, c.z), Vec3::ZERO),
        ] {
            rays.push(Ray {
                origin: o,
                dir: d,
                tmax: f32::INFINITY,
            });
        }
    }
    check(&bvh, &tris, &rays, 5);
    let f = FastBvh2::new(&bvh, &tris);
    assert!(f.hits(&rays).iter().skip(4).step_by(5).all(|h| !h.is_hit()));
    let empty = Bvh::default();
    assert!(FastBvh2::new(&empty, &tris)
        .hits(&rays)
        .iter()
        .all(|h| !h.is_hit()));
}

/// A grid of quads split into triangles: rays aimed exactly at shared edges and vertices (in the
/// grid's plane coordinates) must hit something (Woop 2013: no ray passes between triangles).
#[test]
fn watertight_on_shared_edges_and_vertices() {
    let n = 40;
    let mut tris = Vec::new();
    let p = |i: usize, j: usize| {
        Vec3::new(
            i as f32 * 0.37,
            j as f32 * 0.29,
            0.5 + 0.01 * (i * j) as f32,
        )
    };
    for i in 0..n {
        for j in 0..n {
            tris.push(Triangle::new(p(i, j), p(i + 1, j), p(i + 1, j + 1)));
            tris.push(Triangle::new(p(i, j), p(i + 1, j + 1), p(i, j + 1)));
        }
    }
    let bvh = median_bvh(&tris, 2);
    let f = FastBvh2::new(&bvh, &tris);
    let mut rays = Vec::new();
    for i in 1..n {
        for j in 1..n {
            let v = p(i, j);
            let mid = (p(i, j) + p(i + 1, j + 1)) * 0.5; // on the diagonal edge
            for target in [v, mid] {
                let origin = Vec3::new(3.0, 4.0, 20.0);
                let d = (target - origin).normalize();
                rays.push(Ray {
                    origin,
                    dir: d,
                    tmax: f32::INFINITY,
                });
            }
        }
    }
    let hits = f.hits(&rays);
    let missed = hits.iter().filter(|h| !h.is_hit()).count();
    assert_eq!(
        missed, 0,
        "rays through shared edges or vertices passed through the mesh"
    );
}

/// The f32 test falls back to f64 outside its trusted range: the same scene at 1e-30 and 1e30.
#[test]
fn tiny_and_huge_scenes() {
    let base = random_triangles(1000, 0.05, 11);
    for s in [1e-30f32, 1e-12, 1e12, 1e30] {
        let tris: Vec<Triangle> = base
            .iter()
            .map(|t| Triangle {
                v: t.v.map(|v| v * s),
            })
            .collect();
        let bvh = median_bvh(&tris, 2);
        let rays = rays_for(&tris, 1500, 2);
        check(&bvh, &tris, &rays, 3);
        let hits = FastBvh2::new(&bvh, &tris)
            .hits(&rays)
            .iter()
            .filter(|h| h.is_hit())
            .count();
        assert!(hits > 50, "scale {s}: {hits} hits");
    }
}

#[test]
fn identical_at_any_thread_count() {
    let tris = random_triangles(2000, 0.05, 21);
    let bvh = median_bvh(&tris, 2);
    let rays = rays_for(&tris, 5000, 8);
    let f = FastBvh2::new(&bvh, &tris);
    let run = |n| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
            .install(|| f.hits(&rays))
    };
    assert_eq!(run(1), run(3));
}

/// The four-at-a-time watertight leaf test (SSE) finds, for every leaf length and ray, the hit the
/// one-at-a-time watertight test finds, bit for bit: on random triangles, on a fan of triangles
/// sharing edges and a vertex hit by rays through the vertex (the edge-function-0 fallback lanes),
/// and at scales 1e-20 and 1e20 (the |det| fallback).
#[test]
fn four_wide_leaf_test_equals_the_scalar_one() {
    use bvhlab_trace::fast::{intersect_watertight, TriStore, TriTest, WoopRay};
    use bvhlab_trace::packs::packs_for;
    use bvhlab_trace::{accept, Hit, PackStore};
    let mut sets = vec![random_triangles(64, 0.3, 11)];
    let fan: Vec<Triangle> = (0..8)
        .map(|k| {
            let a = |i: f32| {
                let t = (k as f32 + i) * std::f32::consts::FRAC_PI_4;
                Vec3::new(t.cos(), t.sin(), 0.0)
            };
            Triangle {
                v: [Vec3::ZERO, a(0.0), a(1.0)],
            }
        })
        .collect();
    sets.push(fan);
    for scale in [1e-20f32, 1e20] {
        sets.push(
            random_triangles(64, 0.3, 12)
                .iter()
                .map(|t| Triangle {
                    v: t.v.map(|v| v * scale),
                })
                .collect(),
        );
    }
    for (si, tris) in sets.iter().enumerate() {
        let ids: Vec<u32> = (0..tris.len() as u32).collect();
        let mut rays = rays_for(tris, 300, 5 + si as u64);
        // Rays straight through the shared vertex and along the fan's edges.
        for d in [
            Vec3::new(0.0, 0.0, -1.0),
            Vec3::new(0.3, 0.0, -1.0),
            Vec3::new(0.0, 0.7, -1.0),
        ] {
            rays.push(Ray {
                origin: Vec3::new(0.0, 0.0, 1.0),
                dir: d,
                tmax: f32::INFINITY,
            });
        }
        for len in 1..=9usize {
            // Leaves of `len` triangles, each ending with a mark.
            let leaves: Vec<[u32; 2]> = (0..tris.len() as u32 / len as u32)
                .map(|k| [k * len as u32, len as u32])
                .collect();
            let store = TriStore::with_leaves(&ids, tris, &leaves);
            // The same leaves in packs of four (the wide layouts' store).
            let mut next = 0;
            let packed: Vec<[u32; 3]> = leaves
                .iter()
                .map(|&[f, c]| {
                    let p = next;
                    next += packs_for(c);
                    [f, c, p]
                })
                .collect();
            let packs = PackStore::new(&ids, tris, &packed);
            for r in &rays {
                let wr = WoopRay::new(r.origin, r.dir);
                for (&[first, _], &[_, _, pack]) in leaves.iter().zip(&packed) {
                    let leaf = &store.tris[first as usize..];
                    let (mut got, mut want) = (Hit::within(r.tmax), Hit::within(r.tmax));
                    let n = Watertight::test_leaf(&wr, leaf, &mut got);
                    for t in &leaf[..len] {
                        if let Some(d) = intersect_watertight(&wr, t) {
                            accept(d, t.prim, &mut want);
                        }
                    }
                    assert_eq!(n as usize, len);
                    assert_eq!(
                        (got.t.to_bits(), got.prim),
                        (want.t.to_bits(), want.prim),
                        "set {si} len {len}"
                    );
                    let mut in_packs = Hit::within(r.tmax);
                    let n = Watertight::test_packs(&wr, &packs.packs[pack as usize..], &mut in_packs);
                    assert_eq!((n as usize, in_packs), (len, got), "packs: set {si} len {len}");
                    #[cfg(target_arch = "x86_64")]
                    if std::is_x86_feature_detected!("avx2") {
                        let mut avx = Hit::within(r.tmax);
                        // SAFETY: AVX2 was detected.
                        let n = unsafe { Watertight::test_packs_avx2(&wr, &packs.packs[pack as usize..], &mut avx) };
                        assert_eq!((n as usize, avx), (len, got), "packs, AVX2: set {si} len {len}");
                    }
                }
            }
        }
    }
}

/// The one-pass root test answers as the slab test it stands for, on ordinary, huge, tiny,
/// infinite and NaN values (the products may then be inf or NaN: the SIMD max / min must treat
/// them as `hit`'s comparisons do).
#[test]
fn one_pass_root_test_equals_the_slab_test() {
    use bvhlab_geom::Aabb;
    use bvhlab_trace::fast::SlabRay;
    let mut x = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = |odd: bool| {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        let u = (x >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0;
        match (x % 41, odd) {
            (0, true) => f32::NAN,
            (1, true) => f32::INFINITY,
            (2, true) => -f32::INFINITY,
            (3, true) => u * 1e38,
            (4, true) => u * 1e-38,
            (5, true) => 0.0,
            _ => u * 10.0,
        }
    };
    let (mut n, mut hits) = (0, 0);
    for k in 0..200_000 {
        let odd = k % 3 == 0;
        let v = |next: &mut dyn FnMut(bool) -> f32| Vec3::new(next(odd), next(odd), next(odd));
        let (a, b) = (v(&mut next), v(&mut next));
        let bx = Aabb { min: a.min(b), max: a.max(b) };
        let ray = Ray { origin: v(&mut next), dir: v(&mut next), tmax: if k % 5 == 0 { next(odd).abs() } else { f32::INFINITY } };
        let sr = SlabRay::new(&ray);
        if sr.parallel || bx.is_empty() {
            continue;
        }
        let want = sr.hit(&bx, ray.tmax).is_some();
        assert_eq!(sr.enters(&bx, ray.tmax), want, "{ray:?} {bx:?}");
        n += 1;
        hits += want as u32;
    }
    assert!(n > 100_000 && hits > 10_000 && hits < n - 10_000, "{n} cases, {hits} entered");
}

/// The timed path's arena names each child by its offset: a pair's at 4 units per pair, a leaf's
/// first triangle after the pairs at 3 units per slot; its triangles are the store's. A leaf range
/// past the triangles gives no arena.
#[test]
fn arena_offsets_name_the_pairs_and_the_leaf_triangles() {
    use bvhlab_trace::pairs::{Arena, Pairs};
    use bvhlab_trace::TriStore;
    let tris = random_triangles(2000, 0.05, 13);
    for bvh in [median_bvh(&tris, 1), median_bvh(&tris, 5), caterpillar(&tris[..300])] {
        let pairs = Pairs::new(&bvh.nodes).expect("pairs");
        let store = TriStore::new(&bvh.prim_indices, &tris);
        let arena = Arena::new(&pairs, &store.tris).expect("arena");
        assert!(arena.tris() == &store.tris[..]);
        let np = pairs.pairs().len() as u32;
        assert_eq!(arena.pairs().len(), pairs.pairs().len());
        for (a, p) in arena.pairs().iter().zip(pairs.pairs()) {
            assert_eq!(a.axis, p.axis);
            assert_eq!(a.count, p.count);
            for side in 0..2 {
                let want = if p.count[side] > 0 { 4 * np + 3 * p.child[side] } else { 4 * p.child[side] };
                assert_eq!(a.child[side], want);
            }
        }
        assert!(Arena::new(&pairs, &store.tris[..store.tris.len() - 1]).is_none(), "the last leaf ends past the triangles");
    }
}

/// The child-pair layout of the timed path holds every inner node's two children once, with the
/// children's boxes and leaf ranges as they are; a malformed tree gives none (the flat traversal
/// then serves every ray, with the same hits).
#[test]
fn child_pairs_hold_every_child_once() {
    use bvhlab_trace::pairs::Pairs;
    let tris = random_triangles(2000, 0.05, 11);
    for bvh in [
        median_bvh(&tris, 1),
        median_bvh(&tris, 3),
        caterpillar(&tris[..300]),
    ] {
        let pairs = Pairs::new(&bvh.nodes).expect("a valid tree with an inner root has pairs");
        let inner = bvh.nodes.iter().filter(|n| !n.is_leaf()).count();
        assert_eq!(pairs.pairs().len(), inner);
        // Walk the pairs and collect every leaf child's range and box.
        let mut leaves: Vec<(u32, u32, [f32; 6])> = Vec::new();
        let mut todo = vec![0usize];
        let mut reached = vec![0u32; pairs.pairs().len()];
        while let Some(p) = todo.pop() {
            reached[p] += 1;
            let pair = &pairs.pairs()[p];
            for side in 0..2 {
                let b = [0, 1, 2].map(|a| pair.axis[a][side]);
                let e = [0, 1, 2].map(|a| pair.axis[a][side + 2]);
                if pair.count[side] > 0 {
                    leaves.push((
                        pair.child[side],
                        pair.count[side],
                        [b[0], b[1], b[2], e[0], e[1], e[2]],
                    ));
                } else {
                    todo.push(pair.child[side] as usize);
                }
            }
        }
        assert!(
            reached.iter().all(|&r| r == 1),
            "every pair reached exactly once"
        );
        let mut want: Vec<(u32, u32, [f32; 6])> = bvh
            .nodes
            .iter()
            .filter(|n| n.is_leaf())
            .map(|n| {
                (
                    n.first,
                    n.count,
                    [
                        n.bounds.min.x,
                        n.bounds.min.y,
                        n.bounds.min.z,
                        n.bounds.max.x,
                        n.bounds.max.y,
                        n.bounds.max.z,
                    ],
                )
            })
            .collect();
        leaves.sort_by(|a, b| a.partial_cmp(b).unwrap());
        want.sort_by(|a, b| a.partial_cmp(b).unwrap());
        assert_eq!(leaves, want);
    }
    assert!(
        Pairs::new(&one_leaf(&tris[..10]).nodes).is_none(),
        "a leaf root has nothing to pair"
    );
    // Malformed: a child index past the end; two inner nodes sharing children (a DAG).
    let mut bad = median_bvh(&tris, 2);
    bad.nodes[0].first = bad.nodes.len() as u32 - 1;
    assert!(Pairs::new(&bad.nodes).is_none());
    let mut dag = median_bvh(&tris, 2);
    let inner: Vec<usize> = (1..dag.nodes.len())
        .filter(|&i| !dag.nodes[i].is_leaf())
        .take(2)
        .collect();
    dag.nodes[inner[1]].first = dag.nodes[inner[0]].first;
    assert!(Pairs::new(&dag.nodes).is_none());
    let rays = rays_for(&tris, 2000, 12);
    let f = FastBvh2::new(&dag, &tris);
    assert_eq!(
        f.hits(&rays),
        f.hits_flat(&rays),
        "without pairs the flat traversal serves every ray"
    );
    // An inverted child box (which the flat test always misses): no pairs either.
    let mut inverted = median_bvh(&tris, 2);
    let c = inverted.nodes[0].first as usize;
    let b = &mut inverted.nodes[c].bounds;
    std::mem::swap(&mut b.min.y, &mut b.max.y);
    assert!(Pairs::new(&inverted.nodes).is_none());
    // Rays with infinite or NaN origins and directions get the flat traversal's hits.
    let good = median_bvh(&tris, 2);
    let f = FastBvh2::new(&good, &tris);
    let mut odd = rays[..200].to_vec();
    for (i, r) in odd.iter_mut().enumerate() {
        match i % 4 {
            0 => r.dir.x = f32::INFINITY,
            1 => r.origin.y = f32::NEG_INFINITY,
            2 => r.dir.z = f32::NAN,
            _ => r.dir *= 1e30,
        }
    }
    assert_eq!(f.hits(&odd), f.hits_flat(&odd));
}
