//! AAC (thesis 3.2): validity, same closest hits as brute force, an exact match with a naive
//! reference clustering (no distance matrix, everything recomputed), and thread-count determinism.
mod common;
use bvhlab_builders::aac::{self, AacConfig};
use bvhlab_builders::{binned_sah, SortedCodes, TopDownConfig};
use bvhlab_bvh::{collapse::collapse, metrics, validate, Aabb, Bvh, CostParams};
use bvhlab_morton::{AutoFor, Bits, EncodeConfig, Encoding};
use bvhlab_trace::{brute_force, random_rays, trace};
use common::*;

const CONFIGS: [AacConfig; 6] = [
    AacConfig::HQ,
    AacConfig::FAST,
    AacConfig {
        delta: 1,
        epsilon: 0.0,
    },
    AacConfig {
        delta: 2,
        epsilon: 0.5,
    },
    AacConfig {
        delta: 2,
        epsilon: 0.0,
    },
    AacConfig {
        delta: 7,
        epsilon: 0.5,
    },
];

fn encode(boxes: &[Aabb]) -> Encoding {
    let cfg = EncodeConfig {
        bits: Bits::Auto(AutoFor::Aac),
        ..Default::default()
    };
    bvhlab_morton::encode(boxes, &centers_of(boxes), &cfg)
}

fn build(boxes: &[Aabb], enc: &Encoding, cfg: &AacConfig) -> Bvh {
    let sorted = SortedCodes {
        order: &enc.order,
        codes: &enc.codes,
        code_bits: enc.code_bits,
    };
    aac::build(boxes, &sorted, cfg)
}

fn assert_single_prim_tree(bvh: &Bvh, boxes: &[Aabb], what: &str) {
    if let Err(e) = validate(bvh, boxes) {
        panic!("{what}: {e}");
    }
    assert_eq!(bvh.nodes.len(), 2 * boxes.len() - 1, "{what}");
    assert_eq!(max_leaf_size(bvh), 1, "{what}");
}

#[test]
fn closest_hits_match_brute_force() {
    for spec in [
        "gen:sphere:n=1500",
        "gen:degenerate:n=1500",
        "gen:outlier:n=1500,e=30",
        "gen:city:blocks=5",
    ] {
        let scene = bvhlab_geom::load_scene(spec).expect("generated scene");
        let (boxes, _) = scene.boxes_and_centers();
        let enc = encode(&boxes);
        // Rays around the main object: with the outlier 2^30 sizes away, rays over the whole scene
        // bounds would miss everything.
        let mut near = Aabb::EMPTY;
        boxes
            .iter()
            .filter(|b| b.center().length() < 1e3)
            .for_each(|b| near.grow(b));
        let rays = random_rays(&near, 0.0, 1000, 3);
        let oracle = brute_force(&scene.triangles, &rays);
        assert!(
            oracle.iter().any(|h| h.is_hit()),
            "{spec}: rays should hit something"
        );
        for cfg in CONFIGS {
            let what = format!("{spec} {cfg:?}");
            let bvh = build(&boxes, &enc, &cfg);
            assert_single_prim_tree(&bvh, &boxes, &what);
            let compact = collapse(&bvh, CostParams::default());
            validate(&compact, &boxes).unwrap_or_else(|e| panic!("{what} collapsed: {e}"));
            for b in [&bvh, &compact] {
                let got = trace(b, &scene.triangles, &rays);
                for (i, (g, o)) in got.hits.iter().zip(&oracle).enumerate() {
                    assert_eq!(g, o, "{what}, ray {i}");
                }
            }
        }
    }
}

#[test]
fn tiny_and_degenerate_inputs() {
    let inputs = [
        ("one", random_boxes(1, 0.1, 1)),
        ("two", random_boxes(2, 0.1, 2)),
        ("three", random_boxes(3, 0.1, 3)),
        ("two-equal", point_boxes(2)),
        // All codes equal: the constraint tree splits in the middle until ranges are below delta.
        ("points", point_boxes(300)),
        ("equal-centroids", equal_centroid_boxes(200)),
        ("flat", flat_boxes(500, 4)),
    ];
    for (name, boxes) in inputs {
        let enc = encode(&boxes);
        for cfg in CONFIGS {
            assert_single_prim_tree(
                &build(&boxes, &enc, &cfg),
                &boxes,
                &format!("{name} {cfg:?}"),
            );
        }
    }
    let empty = aac::build(
        &[],
        &SortedCodes {
            order: &[],
            codes: &[],
            code_bits: 0,
        },
        &AacConfig::HQ,
    );
    assert!(empty.nodes.is_empty() && empty.prim_indices.is_empty());
    // Odd parameters must not panic or loop: delta 0, epsilon outside [0, 0.5], NaN.
    let boxes = random_boxes(400, 0.05, 5);
    let enc = encode(&boxes);
    for cfg in [
        AacConfig {
            delta: 0,
            epsilon: 0.2,
        },
        AacConfig {
            delta: 1000,
            epsilon: 0.2,
        },
        AacConfig {
            delta: 4,
            epsilon: -1.0,
        },
        AacConfig {
            delta: 4,
            epsilon: 3.0,
        },
        AacConfig {
            delta: 4,
            epsilon: f32::NAN,
        },
    ] {
        assert_single_prim_tree(&build(&boxes, &enc, &cfg), &boxes, &format!("{cfg:?}"));
    }
}

#[test]
fn non_finite_boxes_do_not_panic() {
    // Loading drops non-finite triangles, but the builder must still terminate with a complete tree.
    let mut boxes = random_boxes(300, 0.05, 12);
    boxes[3] = Aabb::new(bvhlab_bvh::Vec3::NAN, bvhlab_bvh::Vec3::NAN);
    boxes[50].max.x = f32::INFINITY;
    boxes[60] = Aabb::new(
        bvhlab_bvh::Vec3::splat(-f32::MAX),
        bvhlab_bvh::Vec3::splat(f32::MAX),
    );
    boxes[70] = Aabb::EMPTY;
    // Inverted on one axis with huge coordinates: -inf + inf in the area unless sanitized.
    boxes[80] = Aabb::new(
        bvhlab_bvh::Vec3::new(3e38, -3e38, -3e38),
        bvhlab_bvh::Vec3::new(-3e38, 3e38, 3e38),
    );
    let codes: Vec<u64> = (0..boxes.len() as u64).map(|i| i / 7).collect();
    let order: Vec<u32> = (0..boxes.len() as u32).collect();
    for cfg in CONFIGS {
        let bvh = aac::build(
            &boxes,
            &SortedCodes {
                order: &order,
                codes: &codes,
                code_bits: 6,
            },
            &cfg,
        );
        assert_eq!(bvh.nodes.len(), 2 * boxes.len() - 1, "{cfg:?}");
        let mut prims = bvh.prim_indices.clone();
        prims.sort_unstable();
        assert!(
            prims.iter().enumerate().all(|(i, &p)| p as usize == i),
            "{cfg:?}: every primitive once"
        );
    }
}

#[test]
fn huge_coordinates_do_not_panic() {
    // Areas overflow to infinity: every distance ties, the lowest position wins, the tree is valid.
    let mut boxes = random_boxes(300, 0.05, 6);
    for b in boxes.iter_mut().step_by(3) {
        b.min *= 1e30;
        b.max *= 1e30;
    }
    let enc = encode(&boxes);
    for cfg in CONFIGS {
        assert_single_prim_tree(&build(&boxes, &enc, &cfg), &boxes, &format!("{cfg:?}"));
    }
}

/// Naive AAC: the same constraint tree, reduction function and merge bookkeeping (new cluster at the
/// lower position, last cluster into the higher one), but every nearest neighbour recomputed from
/// scratch before each merge. The fast version must produce exactly the same tree.
fn reference(boxes: &[Aabb], enc: &Encoding, cfg: &AacConfig) -> Bvh {
    struct Cl {
        b: Aabb,
        id: u32,
    }
    let n = enc.order.len();
    let delta = cfg.delta.max(1) as usize;
    let dist = |a: &Aabb, b: &Aabb| {
        // The f32 half area, as the builder's kernel computes it (its power-of-two prescale keeps
        // the order of these values exactly on the test's unit-size scenes).
        let e = a.union(b).extent();
        let d = e.x * e.y + e.y * e.z + e.z * e.x;
        if d.is_nan() {
            f32::INFINITY
        } else {
            d
        }
    };
    let mut merges: Vec<[u32; 2]> = Vec::new();
    let mut reduce = |set: &mut Vec<Cl>, target: usize| {
        while set.len() > target.max(1) {
            // Lexicographic minimum of (distance, position) per cluster, then over clusters.
            let near = |i: usize| {
                (0..set.len())
                    .filter(|&j| j != i)
                    .map(|j| (dist(&set[i].b, &set[j].b), j))
                    .fold((f32::INFINITY, usize::MAX), |m, x| {
                        if x.0 < m.0 || (x.0 == m.0 && x.1 < m.1) {
                            x
                        } else {
                            m
                        }
                    })
            };
            let mut best = (f32::INFINITY, usize::MAX, usize::MAX);
            for i in 0..set.len() {
                let (d, j) = near(i);
                if best.1 == usize::MAX || d < best.0 {
                    best = (d, i, j);
                }
            }
            let (p, q) = (best.1.min(best.2), best.1.max(best.2));
            merges.push([set[p].id, set[q].id]);
            set[p] = Cl {
                b: set[p].b.union(&set[q].b),
                id: n as u32 + merges.len() as u32 - 1,
            };
            set.swap_remove(q);
        }
    };
    let f = |x: usize| aac::reduction(cfg, x);
    // Recursive (test inputs are small).
    fn walk(lo: usize, hi: usize, delta: usize, codes: &[u64], visit: &mut dyn FnMut(Node)) {
        let m = hi - lo;
        if m < delta || m <= 1 {
            return visit(Node::Leaf(lo, hi));
        }
        let x = codes[lo] ^ codes[hi - 1];
        let mid = if x == 0 {
            lo + m / 2
        } else {
            let bit = 1u64 << (63 - x.leading_zeros());
            lo + codes[lo..hi].iter().take_while(|&&c| c & bit == 0).count()
        };
        walk(lo, mid, delta, codes, visit);
        walk(mid, hi, delta, codes, visit);
        visit(Node::Inner(m));
    }
    enum Node {
        Leaf(usize, usize),
        Inner(usize),
    }
    let mut stack: Vec<Vec<Cl>> = Vec::new();
    walk(0, n, delta, &enc.codes, &mut |node| match node {
        Node::Leaf(lo, hi) => {
            let mut set: Vec<Cl> = (lo..hi)
                .map(|i| Cl {
                    b: boxes[enc.order[i] as usize],
                    id: i as u32,
                })
                .collect();
            reduce(&mut set, f(delta));
            stack.push(set);
        }
        Node::Inner(m) => {
            let r = stack.pop().unwrap();
            let mut l = stack.pop().unwrap();
            l.extend(r);
            reduce(&mut l, f(m));
            stack.push(l);
        }
    });
    let mut root = stack.pop().unwrap();
    reduce(&mut root, 1);
    bvhlab_builders::bottomup::to_bvh(
        boxes,
        &bvhlab_builders::bottomup::ClusterTree {
            leaf_prims: &enc.order,
            children: &merges,
            root: root[0].id,
        },
    )
}

#[test]
fn matches_naive_reference_clustering() {
    let inputs = [
        ("random", random_boxes(700, 0.05, 7)),
        // Many equal distances: checks that the tie-breaks of the incremental bookkeeping are exact.
        ("points", point_boxes(120)),
        ("equal-centroids", equal_centroid_boxes(150)),
        ("flat", flat_boxes(400, 8)),
        (
            "grid",
            (0..400)
                .map(|i| {
                    Aabb::from_point(bvhlab_bvh::Vec3::new((i % 20) as f32, (i / 20) as f32, 0.0))
                })
                .collect(),
        ),
    ];
    for (name, boxes) in inputs {
        let enc = encode(&boxes);
        for cfg in CONFIGS {
            let got = build(&boxes, &enc, &cfg);
            let want = reference(&boxes, &enc, &cfg);
            assert_eq!(
                got.canonical_bytes(),
                want.canonical_bytes(),
                "{name} {cfg:?}"
            );
        }
    }
}

#[test]
fn identical_output_at_any_thread_count() {
    // Large enough for several parallel levels (aac::PAR_MIN primitives per forked subtree).
    let scene = bvhlab_geom::load_scene("gen:sphere:n=40000").unwrap();
    let (boxes, _) = scene.boxes_and_centers();
    assert!(boxes.len() >= 8 * aac::PAR_MIN);
    let enc = encode(&boxes);
    for cfg in [AacConfig::HQ, AacConfig::FAST] {
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| build(&boxes, &enc, &cfg)).canonical_bytes()
        };
        let one = run(1);
        assert!(one == run(2), "{cfg:?}: 1 vs 2 threads");
        assert!(one == run(3), "{cfg:?}: 1 vs 3 threads");
    }
}

#[test]
fn quality_is_in_the_expected_range() {
    let cost = CostParams::default();
    let sah = |b: &Bvh| metrics(&collapse(b, cost), cost).sah_cost;
    let binned = |boxes: &[Aabb]| {
        sah(&binned_sah::build(
            boxes,
            &centers_of(boxes),
            16,
            &TopDownConfig::default(),
        ))
    };
    // On a uniform cloud of boxes (like the thesis' scanned objects, table 10: dragon AHQ 160.0, BIN
    // 144.8) AAC stays within ~10-15% of top-down binned SAH.
    let boxes = random_boxes(5000, 0.03, 9);
    let enc = encode(&boxes);
    let (hq, fast) = (
        sah(&build(&boxes, &enc, &AacConfig::HQ)),
        sah(&build(&boxes, &enc, &AacConfig::FAST)),
    );
    let bin = binned(&boxes);
    assert!(
        hq <= bin * 1.2 && fast <= bin * 1.2,
        "random: hq {hq} fast {fast} binned {bin}"
    );
    // Small buildings on a huge ground quad (an architectural scene): clustering beats top-down
    // binning by far (thesis table 10, Conference: AHQ 84.3, BIN 136.1), and beats delta = 2,
    // epsilon = 0.5 (f = 1 everywhere: every constraint node reduced to one cluster, i.e. the plain
    // Morton spatial-median hierarchy).
    let scene = bvhlab_geom::load_scene("gen:city:blocks=8").unwrap();
    let (boxes, _) = scene.boxes_and_centers();
    let enc = encode(&boxes);
    let (hq, fast) = (
        sah(&build(&boxes, &enc, &AacConfig::HQ)),
        sah(&build(&boxes, &enc, &AacConfig::FAST)),
    );
    let median = sah(&build(
        &boxes,
        &enc,
        &AacConfig {
            delta: 2,
            epsilon: 0.5,
        },
    ));
    let bin = binned(&boxes);
    assert!(
        hq < bin && fast < bin,
        "city: hq {hq} fast {fast} binned {bin}"
    );
    assert!(
        hq * 2.0 < median && fast * 2.0 < median,
        "city: hq {hq} fast {fast} one-cluster {median}"
    );
}
