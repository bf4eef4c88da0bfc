//! LBVH and PLOC: structural validity, same closest hits as brute force, the radix-tree split rule,
//! PLOC against a plain sequential reading of Meister and Bittner 2018, and bit-identical output at
//! 1 and 2 threads.
mod common;
use bvhlab_builders::bottomup::{to_bvh, ClusterTree};
use bvhlab_builders::ploc::PlocConfig;
use bvhlab_builders::{lbvh, ploc, SortedCodes};
use bvhlab_bvh::{validate, Aabb, Bvh, Vec3};
use bvhlab_trace::{brute_force, random_rays, trace};
use common::*;

/// Codes owned by the test: `bits` per axis of plain Morton over the centroid bounds, sorted by
/// (code, index). Small `bits` force many duplicate codes. The tests pin the builders, not the
/// encoder (bvhlab_morton, which is tested on its own and used in `with_the_real_encoder`).
struct Codes {
    order: Vec<u32>,
    codes: Vec<u64>,
    bits: u32,
}

impl Codes {
    fn sorted(&self) -> SortedCodes<'_> {
        SortedCodes {
            order: &self.order,
            codes: &self.codes,
            code_bits: 3 * self.bits,
        }
    }
}

fn morton(centers: &[Vec3], bits: u32) -> Codes {
    let mut b = Aabb::EMPTY;
    for c in centers {
        b.grow_point(*c);
    }
    let cells = (1u64 << bits) as f32;
    let q = |v: f32, lo: f32, hi: f32| -> u64 {
        let e = hi - lo;
        if e > 0.0 {
            (((v - lo) / e * cells) as u64).min((1 << bits) - 1)
        } else {
            0
        }
    };
    let mut keyed: Vec<(u64, u32)> = centers
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let (x, y, z) = (
                q(c.x, b.min.x, b.max.x),
                q(c.y, b.min.y, b.max.y),
                q(c.z, b.min.z, b.max.z),
            );
            let mut code = 0u64;
            for k in (0..bits).rev() {
                code = (code << 3) | ((x >> k) & 1) << 2 | ((y >> k) & 1) << 1 | ((z >> k) & 1);
            }
            (code, i as u32)
        })
        .collect();
    keyed.sort_unstable();
    Codes {
        order: keyed.iter().map(|k| k.1).collect(),
        codes: keyed.iter().map(|k| k.0).collect(),
        bits,
    }
}

type Builder = (String, Box<dyn Fn(&[Aabb], &SortedCodes) -> Bvh + Sync>);

fn builders() -> Vec<Builder> {
    let mut v: Vec<Builder> = vec![("lbvh".into(), Box::new(lbvh::build))];
    for radius in [1, 2, 10, 25] {
        v.push((
            format!("ploc:{radius}"),
            Box::new(move |b, s| ploc::build(b, s, &PlocConfig { radius })),
        ));
    }
    v
}

fn single_prim_leaves(bvh: &Bvh, n: usize) {
    assert_eq!(bvh.nodes.len(), 2 * n - 1);
    assert_eq!(max_leaf_size(bvh), 1);
}

#[test]
fn closest_hits_match_brute_force() {
    for spec in [
        "gen:sphere:n=2000",
        "gen:degenerate:n=1500",
        "gen:outlier:n=2000,e=30",
        "gen:city:blocks=4",
    ] {
        let scene = bvhlab_geom::load_scene(spec).expect("generated scene");
        let (boxes, centers) = scene.boxes_and_centers();
        // Rays over the whole scene, plus rays over all but the last triangle: the outlier scene
        // appends its far tiny triangle last, and whole-scene rays would all miss the sphere.
        let mut rays = random_rays(&scene.bounds(), 0.0, 1000, 11);
        let mut core = Aabb::EMPTY;
        for b in &boxes[..boxes.len() - 1] {
            core.grow(b);
        }
        rays.extend(random_rays(&core, 0.0, 1000, 12));
        let oracle = brute_force(&scene.triangles, &rays);
        let hits = oracle.iter().filter(|h| h.is_hit()).count();
        assert!(hits > 20, "{spec}: rays should hit ({hits})");
        eprintln!("{spec}: {hits} hits");
        for bits in [10, 3] {
            let codes = morton(&centers, bits);
            for (name, build) in builders() {
                let bvh = build(&boxes, &codes.sorted());
                if let Err(e) = validate(&bvh, &boxes) {
                    panic!("{name} on {spec} ({bits} bits): {e}");
                }
                single_prim_leaves(&bvh, boxes.len());
                let got = trace(&bvh, &scene.triangles, &rays);
                for (i, (g, o)) in got.hits.iter().zip(&oracle).enumerate() {
                    assert_eq!(g, o, "{name} on {spec} ({bits} bits), ray {i}");
                }
            }
        }
    }
}

#[test]
fn tiny_and_degenerate_inputs() {
    let mut inputs: Vec<(String, Vec<Aabb>)> = Vec::new();
    for n in 0..=3 {
        inputs.push((format!("random {n}"), random_boxes(n, 0.1, 40 + n as u64)));
        inputs.push((format!("points {n}"), point_boxes(n)));
    }
    inputs.push(("equal centroids".into(), equal_centroid_boxes(300)));
    inputs.push(("flat".into(), flat_boxes(500, 3)));
    inputs.push(("points 700".into(), point_boxes(700)));
    // Coordinates near 1e30 and far outliers: areas would overflow f32 without PLOC's rescaling.
    let mut huge = random_boxes(400, 0.05, 5);
    for b in huge.iter_mut() {
        *b = Aabb::new(b.min * 1e30, b.max * 1e30);
    }
    huge.push(Aabb::from_point(Vec3::splat(-3e38)));
    huge.push(Aabb::new(Vec3::splat(3e38), Vec3::splat(3.4e38)));
    inputs.push(("huge".into(), huge));
    for (what, boxes) in inputs {
        let centers = centers_of(&boxes);
        for bits in [10, 1] {
            let codes = morton(&centers, bits);
            for (name, build) in builders() {
                let bvh = build(&boxes, &codes.sorted());
                if let Err(e) = validate(&bvh, &boxes) {
                    panic!("{name} on {what}: {e}");
                }
                assert_eq!(bvh.prim_indices.len(), boxes.len(), "{name} on {what}");
                if !boxes.is_empty() {
                    single_prim_leaves(&bvh, boxes.len());
                }
            }
        }
    }
}

/// Leaf ranges (in leaf-slot order) of every node, by an explicit-stack post-order walk.
fn leaf_ranges(bvh: &Bvh) -> Vec<(usize, usize)> {
    let mut range = vec![(0, 0); bvh.nodes.len()];
    let mut stack = vec![(0usize, false)];
    while let Some((i, done)) = stack.pop() {
        let n = bvh.nodes[i];
        if n.is_leaf() {
            range[i] = (n.first as usize, (n.first + n.count) as usize);
        } else if done {
            let (l, r) = (n.first as usize, n.first as usize + 1);
            assert_eq!(range[l].1, range[r].0, "children's leaves must be adjacent");
            range[i] = (range[l].0, range[r].1);
        } else {
            stack.push((i, true));
            stack.push((n.first as usize + 1, false));
            stack.push((n.first as usize, false));
        }
    }
    range
}

#[test]
fn lbvh_is_the_radix_tree_of_the_augmented_keys() {
    // Karras 2012: leaves in key order; every inner node splits its key range where its highest
    // differing bit flips, i.e. at the unique adjacent pair with the shortest common prefix of the
    // keys augmented by their position (section 4).
    let scene = bvhlab_geom::load_scene("gen:degenerate:n=3000").unwrap();
    let (boxes, centers) = scene.boxes_and_centers();
    for bits in [10, 4, 1] {
        let codes = morton(&centers, bits);
        let bvh = lbvh::build(&boxes, &codes.sorted());
        assert_eq!(
            bvh.prim_indices, codes.order,
            "leaves in key order ({bits} bits)"
        );
        let key = |i: usize| ((codes.codes[i] as u128) << 64) | i as u128;
        let prefix = |i: usize| (key(i) ^ key(i + 1)).leading_zeros();
        let ranges = leaf_ranges(&bvh);
        for (k, node) in bvh.nodes.iter().enumerate() {
            if node.is_leaf() {
                continue;
            }
            let (a, b) = ranges[k];
            let split = ranges[node.first as usize].1 - 1; // last leaf of the left child
            let shortest = (a..b - 1).map(prefix).min().unwrap();
            assert_eq!(prefix(split), shortest, "node {k} ({bits} bits)");
            assert_eq!(
                (a..b - 1).filter(|&i| prefix(i) == shortest).count(),
                1,
                "node {k}"
            );
        }
    }
}

/// PLOC exactly as thesis 3.6.1 reads, sequential and without any of the builder's tricks: nearest
/// neighbour by (distance, index) over the r clusters on each side, mutual pairs merged by the lower
/// index in place, compaction, inner-node ids in merge order. Plus the builder's one addition:
/// runs of at least 64 consecutive identical boxes are first merged into balanced trees.
fn ploc_reference(boxes: &[Aabb], order: &[u32], r: usize) -> (Vec<[u32; 2]>, u32) {
    let n = order.len();
    let mut children = Vec::new();
    let mut cl: Vec<(Aabb, u32)> = Vec::new();
    let mut i = 0;
    while i < n {
        let b = boxes[order[i] as usize];
        let mut j = i + 1;
        while j < n && boxes[order[j] as usize] == b {
            j += 1;
        }
        if j - i < 64 {
            cl.extend((i..j).map(|k| (boxes[order[k] as usize], k as u32)));
        } else {
            let mut level: Vec<u32> = (i as u32..j as u32).collect();
            while level.len() > 1 {
                level = level
                    .chunks(2)
                    .map(|p| {
                        if p.len() == 1 {
                            return p[0];
                        }
                        children.push([p[0], p[1]]);
                        (n + children.len() - 1) as u32
                    })
                    .collect();
            }
            cl.push((b, level[0]));
        }
        i = j;
    }
    let dist = |a: &Aabb, b: &Aabb| {
        let e = a.union(b).extent();
        (e.x * e.y + e.y * e.z + e.z * e.x).min(f32::MAX)
    };
    while cl.len() > 1 {
        let c = cl.len();
        let nn: Vec<usize> = (0..c)
            .map(|i| {
                let cand = (i.saturating_sub(r)..(i + r + 1).min(c)).filter(|&j| j != i);
                cand.min_by(|&j, &k| {
                    dist(&cl[i].0, &cl[j].0)
                        .total_cmp(&dist(&cl[i].0, &cl[k].0))
                        .then(j.cmp(&k))
                })
                .unwrap()
            })
            .collect();
        let mut next = Vec::with_capacity(c);
        for i in 0..c {
            let j = nn[i];
            if nn[j] != i {
                next.push(cl[i]);
            } else if i < j {
                children.push([cl[i].1, cl[j].1]);
                next.push((cl[i].0.union(&cl[j].0), (n + children.len() - 1) as u32));
            }
        }
        cl = next;
    }
    (children, cl[0].1)
}

#[test]
fn ploc_matches_the_sequential_reading_of_the_paper() {
    // Enough clusters for several parallel chunks (2048 each), with exact distance ties
    // (duplicates, points, shared centres) so the tie rule is exercised.
    let mut runs = random_boxes(3000, 0.02, 21);
    // Runs of identical boxes around the pre-merge threshold (63, 64, 65, 300), some touching.
    for (at, len) in [(100usize, 63usize), (700, 64), (764, 65), (1500, 300)] {
        let b = runs[at];
        runs[at..at + len].fill(b);
    }
    let inputs: Vec<(&str, Vec<Aabb>)> = ["gen:degenerate:n=6000", "gen:terrain:n=5000"]
        .into_iter()
        .map(|spec| {
            (
                spec,
                bvhlab_geom::load_scene(spec).unwrap().boxes_and_centers().0,
            )
        })
        .chain([("runs", runs), ("points", point_boxes(500))])
        .collect();
    for (spec, boxes) in inputs {
        let centers = centers_of(&boxes);
        let codes = morton(&centers, 10);
        // 300: neighbour-search chunks grow to 8 r = 2400 clusters; still two of them on "runs".
        let radii: &[u32] = if spec == "runs" {
            &[1, 3, 10, 40, 300]
        } else {
            &[1, 3, 10, 40]
        };
        for &radius in radii {
            let (children, root) = ploc_reference(&boxes, &codes.order, radius as usize);
            let want = to_bvh(
                &boxes,
                &ClusterTree {
                    leaf_prims: &codes.order,
                    children: &children,
                    root,
                },
            );
            let got = ploc::build(&boxes, &codes.sorted(), &PlocConfig { radius });
            assert!(
                got.canonical_bytes() == want.canonical_bytes(),
                "{spec} r={radius}"
            );
        }
    }
}

#[test]
fn identical_bytes_at_one_and_two_threads() {
    // Sizes above the builders' parallel grain (LBVH 4096 nodes, PLOC 2048 clusters per task).
    for spec in ["gen:sphere:n=30000", "gen:degenerate:n=20000"] {
        let scene = bvhlab_geom::load_scene(spec).unwrap();
        let (boxes, centers) = scene.boxes_and_centers();
        let codes = morton(&centers, 10);
        for (name, build) in builders() {
            let run = |threads| {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                pool.install(|| build(&boxes, &codes.sorted()).canonical_bytes())
            };
            assert!(run(1) == run(2), "{name} on {spec}");
        }
    }
}

#[test]
fn with_the_real_encoder() {
    // Whatever bvhlab_morton produces (Morton or EMC, any length) is a valid input.
    use bvhlab_morton::{encode, AutoFor, Bits, EncodeConfig, Scheme};
    let scene = bvhlab_geom::load_scene("gen:outlier:n=3000,e=30").unwrap();
    let (boxes, centers) = scene.boxes_and_centers();
    let cfgs = [
        EncodeConfig {
            bits: Bits::Auto(AutoFor::Lbvh),
            ..Default::default()
        },
        EncodeConfig {
            bits: Bits::Auto(AutoFor::Ploc),
            ..Default::default()
        },
        EncodeConfig {
            scheme: Scheme::Emc64Var,
            ..Default::default()
        },
    ];
    for cfg in cfgs {
        let enc = encode(&boxes, &centers, &cfg);
        let sorted = SortedCodes {
            order: &enc.order,
            codes: &enc.codes,
            code_bits: enc.code_bits,
        };
        for (name, build) in builders() {
            let bvh = build(&boxes, &sorted);
            if let Err(e) = validate(&bvh, &boxes) {
                panic!("{name} with {cfg:?}: {e}");
            }
        }
    }
}

#[test]
fn compacted_builds_equal_the_compaction_of_the_full_tree() {
    // `build_compacted` reads the cluster tree instead of the single-triangle layout; the bytes must
    // be `collapse(build(..))`'s for every bottom-up builder, shape and cost (leaves of 1..many).
    use bvhlab_builders::aac::{self, AacConfig};
    use bvhlab_bvh::collapse::collapse;
    use bvhlab_bvh::CostParams;
    let mut inputs: Vec<(String, Vec<Aabb>)> = Vec::new();
    for n in 0..=3 {
        inputs.push((format!("random {n}"), random_boxes(n, 0.1, 70 + n as u64)));
    }
    inputs.push(("random 5000".into(), random_boxes(5000, 0.02, 9)));
    inputs.push(("equal centroids".into(), equal_centroid_boxes(300)));
    inputs.push(("flat".into(), flat_boxes(2000, 3)));
    inputs.push(("points".into(), point_boxes(700)));
    let costs = [CostParams::default(), CostParams { c_t: 1.0, c_i: 1.0 }, CostParams { c_t: 3.0, c_i: 0.25 }];
    let mut collapsed_some = false;
    for (what, boxes) in &inputs {
        let centers = centers_of(boxes);
        for bits in [10, 2] {
            let codes = morton(&centers, bits);
            let s = codes.sorted();
            for cost in costs {
                let pairs: [(&str, Bvh, Bvh); 4] = [
                    ("lbvh", lbvh::build(boxes, &s), lbvh::build_compacted(boxes, &s, cost)),
                    ("ploc 1", ploc::build(boxes, &s, &PlocConfig { radius: 1 }), ploc::build_compacted(boxes, &s, &PlocConfig { radius: 1 }, cost)),
                    ("ploc 10", ploc::build(boxes, &s, &PlocConfig { radius: 10 }), ploc::build_compacted(boxes, &s, &PlocConfig { radius: 10 }, cost)),
                    ("aac hq", aac::build(boxes, &s, &AacConfig::HQ), aac::build_compacted(boxes, &s, &AacConfig::HQ, cost)),
                ];
                for (name, full, direct) in pairs {
                    let expected = collapse(&full, cost);
                    collapsed_some |= expected.nodes.len() < full.nodes.len();
                    assert!(direct.canonical_bytes() == expected.canonical_bytes(), "{name} on {what}, {bits} bits, {cost:?}");
                }
            }
        }
    }
    assert!(collapsed_some, "some compaction must merge leaves");
}
