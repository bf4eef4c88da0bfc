//! Octree layouts (Kilian 4.1, 4.2): exact closest hits on every generated scene, every chunk size
//! and fill, several construction parameters; degenerate inputs; the 1-bit octree traverses the
//! same topology as the basic octree (same per-ray steps and tests); exact byte counts.
mod common;
use bvhlab_bvh::CostParams;
use bvhlab_geom::{Triangle, Vec3};
use bvhlab_layout::octree::{self, centre, child_box, Octree};
use bvhlab_layout::octree_1bit::{self, Fill, Octree1Bit};
use bvhlab_layout::{build, Layout};
use bvhlab_trace::{brute_force, Ray};
use common::*;

const RAYS: usize = 300;

fn memory_formulas(l: &Layout) {
    let m = l.memory();
    match l {
        Layout::Octree(o) => {
            assert_eq!(m.nodes, o.nodes.len() as u64);
            assert_eq!(m.topology_bytes, 4 * m.nodes);
            assert_eq!(m.prim_refs, o.prims.len() as u64);
            assert_eq!(m.total_bytes, 8 * m.nodes + 4 * m.prim_refs + 24);
            assert_eq!(m.topology_bits_per_node(), 32.0);
            assert_eq!((m.chunks, m.chunk_fill), (0, 0.0));
        }
        Layout::Octree1Bit(o) => {
            let b = o.config.chunk_bytes as u64;
            assert_eq!(m.topology_bytes, m.chunks * b);
            assert_eq!(o.words.len() as u64 * 8, m.topology_bytes);
            let leaves = o.leaves() as u64;
            assert_eq!(
                m.total_bytes,
                m.topology_bytes + 4 * (leaves + 1) + 4 * m.prim_refs + 24
            );
            // Octree: 7 leaves per interior node; nodes = 8 * interior + 1.
            assert_eq!((m.nodes - 1) % 8, 0);
            assert_eq!(leaves, m.nodes - (m.nodes - 1) / 8);
            match o.config.fill {
                Fill::Dense => {
                    let bpc = b * 8 - 32;
                    assert_eq!(m.chunks, (m.nodes - 1).div_ceil(bpc));
                    if m.chunks > 0 {
                        let f = (m.nodes - 1) as f64 / (m.chunks * bpc) as f64;
                        assert!((m.chunk_fill - f).abs() < 1e-12);
                    }
                }
                Fill::Bfs => {
                    let slots = (b - 8) * 8;
                    assert!(m.chunks * slots >= m.nodes - 1);
                    assert!(m.chunk_fill > 0.0 || m.chunks == 0);
                    assert!(m.chunk_fill <= 1.0);
                }
            }
        }
        _ => unreachable!(),
    }
}

/// Builds octree_1bit and checks it against brute force, its byte formulas, and (same topology) its
/// uncompressed octree: equal memory.nodes/prim_refs and identical per-ray steps and tests.
fn check_pair(c: &Case, kv: &[(&str, &str)], chunk: &str, fill: &str) {
    let o = check(c, &spec("octree", kv));
    memory_formulas(&o);
    let mut kv1 = kv.to_vec();
    kv1.push(("chunk_bytes", chunk));
    kv1.push(("fill", fill));
    let l = check(c, &spec("octree_1bit", &kv1));
    memory_formulas(&l);
    if chunk == "16" {
        // (Rebuilds the octree: once per scene and parameter set is enough.)
        let u = l
            .uncompressed(&c.bvh, &c.scene.triangles)
            .expect("octree_1bit has an uncompressed octree");
        assert_eq!(
            u, o,
            "uncompressed() is the octree with the same parameters"
        );
    }
    let (mo, ml) = (o.memory(), l.memory());
    assert_eq!((mo.nodes, mo.prim_refs), (ml.nodes, ml.prim_refs));
    let a = o.trace(&c.scene.triangles, &c.rays);
    let b = l.trace(&c.scene.triangles, &c.rays);
    assert_eq!(
        a.steps, b.steps,
        "{} {kv:?} {chunk} {fill}: same topology, same steps",
        c.spec
    );
    assert_eq!(a.intersections, b.intersections, "same tests");
    let cost = CostParams::default();
    assert!((o.sah_cost(cost) - l.sah_cost(cost)).abs() <= 1e-9 * o.sah_cost(cost).abs());
}

#[test]
fn every_scene_chunk_size_and_fill_matches_brute_force() {
    for s in SCENES {
        let c = case(s, 2, RAYS, 11);
        for chunk in ["16", "32", "64", "128"] {
            for fill in ["bfs", "dense"] {
                check_pair(&c, &[], chunk, fill);
            }
        }
    }
}

#[test]
fn construction_parameters_match_brute_force() {
    for s in SCENES {
        let c = case(s, 2, RAYS, 12);
        for kv in [
            &[("prim_threshold", "4")][..],
            &[("mult_threshold", "1.3")],
            &[("mult_threshold", "2.4"), ("prim_threshold", "4")],
            &[("prim_threshold", "1"), ("max_depth", "6")],
            &[("overlap", "aabb"), ("prim_threshold", "4")],
        ] {
            check_pair(&c, kv, "16", "bfs");
            check_pair(&c, kv, "24", "dense");
        }
    }
}

#[test]
fn thresholds_follow_kilian_algorithm_1() {
    let c = case("gen:sphere:n=3000", 2, 10, 1);
    let t = &c.scene.triangles;
    let b = |kv: &[(&str, &str)]| match build(&spec("octree", kv), &c.bvh, t).unwrap() {
        Layout::Octree(o) => o,
        _ => unreachable!(),
    };
    // n < prim_threshold => leaf: with a threshold above the scene size the root is a leaf.
    let n = t.len().to_string();
    let n1 = (t.len() + 1).to_string();
    let o = b(&[("prim_threshold", &n1)]);
    assert_eq!(o.nodes.len(), 1);
    let o = b(&[("prim_threshold", &n)]);
    assert!(
        o.nodes.len() > 1,
        "n == prim_threshold splits (Alg. 1: leaf iff n < threshold)"
    );
    // Every interior node has >= prim_threshold references and at most mult * n in its children.
    for (pt, mult) in [(20u32, 2.0f64), (4, 1.3), (8, 1.0)] {
        let o = b(&[
            ("prim_threshold", &pt.to_string()),
            ("mult_threshold", &mult.to_string()),
        ]);
        for n in 0..o.nodes.len() {
            let v = o.nodes[n];
            if v & 1 == 1 {
                let own = node_refs(&o, n);
                let base = (v >> 1) as usize;
                let kids: usize = (0..8).map(|k| node_refs(&o, base + k)).sum();
                assert!(own >= pt as usize, "interior node with {own} < {pt} refs");
                assert!(
                    kids as f64 <= mult * own as f64,
                    "mult rule: {kids} > {mult} * {own}"
                );
            }
        }
    }
}

/// References a node was decided on: the distinct triangles of its subtree (every triangle of a
/// node's list goes to at least one child).
fn node_refs(o: &Octree, n: usize) -> usize {
    let mut set = std::collections::BTreeSet::<u32>::new();
    let mut st = vec![n];
    while let Some(m) = st.pop() {
        let v = o.nodes[m];
        if v & 1 == 1 {
            st.extend((0..8).map(|k| (v >> 1) as usize + k));
        } else {
            let s = (v >> 1) as usize;
            set.extend(&o.prims[s..s + o.sizes[m] as usize]);
        }
    }
    set.len()
}

fn tri(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> Triangle {
    Triangle::new(Vec3::from(a), Vec3::from(b), Vec3::from(c))
}

/// Builds every octree variant on `tris`, validates, and compares `rays` with brute force.
fn check_tris(name: &str, tris: &[Triangle], rays: &[Ray]) {
    let want = brute_force(tris, rays);
    let cfg = octree::Config {
        prim_threshold: 1,
        ..Default::default()
    };
    let o = Octree::build(tris, &cfg).unwrap_or_else(|e| panic!("{name}: {e}"));
    o.validate(tris).unwrap_or_else(|e| panic!("{name}: {e}"));
    let got = o.trace(tris, rays);
    for (i, (g, w)) in got.hits.iter().zip(&want).enumerate() {
        assert!(same_hit(g, w), "{name} octree ray {i}: {g:?} vs {w:?}");
    }
    for fill in [Fill::Bfs, Fill::Dense] {
        for chunk_bytes in [16, 32, 128] {
            let c1 = octree_1bit::Config {
                base: cfg.clone(),
                chunk_bytes,
                fill,
            };
            let l = Octree1Bit::build(tris, &c1).unwrap_or_else(|e| panic!("{name}: {e}"));
            l.validate(tris)
                .unwrap_or_else(|e| panic!("{name} {fill:?}: {e}"));
            let g1 = l.trace(tris, rays);
            assert_eq!(g1.steps, got.steps, "{name} {fill:?} {chunk_bytes}");
            assert_eq!(g1.intersections, got.intersections);
            for (i, (g, w)) in g1.hits.iter().zip(&want).enumerate() {
                assert!(same_hit(g, w), "{name} octree_1bit ray {i}: {g:?} vs {w:?}");
            }
        }
    }
}

/// Rays through a grid of points of `b` from 6 directions (axis-parallel included).
fn grid_rays(lo: Vec3, hi: Vec3) -> Vec<Ray> {
    let mut rays = Vec::new();
    let e = (hi - lo).max(Vec3::splat(1e-3));
    let dirs = [
        Vec3::new(1.0, 0.0, 0.0),
        Vec3::new(0.0, -1.0, 0.0),
        Vec3::new(0.0, 0.0, 1.0),
        Vec3::new(0.3, 0.5, -0.8),
        Vec3::new(-0.7, 0.2, 0.1),
        Vec3::new(0.577, 0.577, 0.577),
    ];
    for i in 0..5 {
        for j in 0..5 {
            for k in 0..5 {
                let p = lo + e * Vec3::new(i as f32, j as f32, k as f32) / 4.0;
                for d in dirs {
                    rays.push(Ray {
                        origin: p - d * 3.0 * e.max_element(),
                        dir: d,
                        tmax: f32::INFINITY,
                    });
                }
            }
        }
    }
    rays
}

#[test]
fn degenerate_inputs() {
    // Empty scene: root leaf, no chunks, no hits.
    let none: Vec<Triangle> = vec![];
    let o = Octree::build(&none, &Default::default()).unwrap();
    o.validate(&none).unwrap();
    assert_eq!(o.memory().nodes, 1);
    let r = grid_rays(Vec3::ZERO, Vec3::ONE);
    assert!(o.trace(&none, &r).hits.iter().all(|h| !h.is_hit()));

    // One triangle (and one flat one: the world box is flat in z).
    let one = vec![tri([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])];
    check_tris("one triangle", &one, &grid_rays(Vec3::ZERO, Vec3::ONE));

    // All triangles sharing one centroid (a fan of 64 triangles through one point): the root
    // must stop splitting (every child gets every primitive), not recurse to max_depth.
    let mut fan = Vec::new();
    for i in 0..64 {
        let a = i as f32 * 0.1;
        let (s, c) = a.sin_cos();
        fan.push(tri([c, s, 0.3], [-c, -s, -0.3], [0.2 * s, -0.2 * c, 0.0]));
    }
    check_tris(
        "shared centroid",
        &fan,
        &grid_rays(Vec3::splat(-1.0), Vec3::ONE),
    );
    let o = Octree::build(
        &fan,
        &octree::Config {
            prim_threshold: 1,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(o.nodes.len() <= 1 + 8 * 4, "fan: {} nodes", o.nodes.len());

    // Coincident triangles (exact duplicates): max_depth / collapse terminates.
    let dup = vec![tri([0.0, 0.0, 0.0], [1.0, 0.0, 1.0], [0.0, 1.0, 0.5]); 50];
    check_tris("duplicates", &dup, &grid_rays(Vec3::ZERO, Vec3::ONE));

    // Triangles exactly on the centre planes of the world box [-1, 1]^3 (and corners on them).
    let mut planes = vec![
        tri([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [1.0, -1.0, 1.0]),
        tri([0.0, -1.0, -1.0], [0.0, 1.0, -1.0], [0.0, 0.0, 1.0]),
        tri([-1.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
        tri([-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0]),
        tri([0.0, 0.0, 0.0], [0.25, 0.0, 0.0], [0.0, 0.25, 0.0]),
    ];
    for i in 0..40 {
        let x = -1.0 + i as f32 * 0.05;
        planes.push(tri([x, 0.0, 0.0], [x + 0.05, 0.0, 0.5], [x, 0.5, 0.0]));
        planes.push(tri([0.0, x, 0.0], [0.0, x, 0.5], [0.5, x + 0.05, 0.0]));
    }
    check_tris(
        "centre planes",
        &planes,
        &grid_rays(Vec3::splat(-1.0), Vec3::ONE),
    );

    // Zero-area triangles (points and segments) among normal ones, huge and tiny coordinates.
    let mut deg = vec![
        tri([0.5, 0.5, 0.5], [0.5, 0.5, 0.5], [0.5, 0.5, 0.5]),
        tri([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.5, 0.5, 0.5]),
    ];
    deg.extend(planes.iter().take(10).cloned());
    check_tris("zero area", &deg, &grid_rays(Vec3::splat(-1.0), Vec3::ONE));
    let huge: Vec<Triangle> = planes
        .iter()
        .map(|t| Triangle {
            v: t.v.map(|p| p * 1e30),
        })
        .collect();
    check_tris(
        "huge",
        &huge,
        &grid_rays(Vec3::splat(-1e30), Vec3::splat(1e30)),
    );
    let tiny: Vec<Triangle> = planes
        .iter()
        .map(|t| Triangle {
            v: t.v.map(|p| p * 1e-30),
        })
        .collect();
    check_tris(
        "tiny",
        &tiny,
        &grid_rays(Vec3::splat(-1e-30), Vec3::splat(1e-30)),
    );

    // Non-finite input is an error, not a panic.
    let bad = vec![tri([f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])];
    assert!(Octree::build(&bad, &Default::default())
        .unwrap_err()
        .contains("non-finite"));
}

#[test]
fn child_boxes_tile_the_parent_bit_exactly() {
    let b = bvhlab_geom::Aabb::new(Vec3::new(-1.0, 0.1, 3.0), Vec3::new(7.3, 0.1, 3.0 + 1e-6));
    let c = centre(&b);
    let mut u = bvhlab_geom::Aabb::EMPTY;
    for k in 0..8 {
        let cb = child_box(&b, c, k);
        assert!(b.contains(&cb));
        // Octant index bits b_z b_y b_x: bit set = the half above the centre.
        assert_eq!(cb.min.x == c.x, k & 1 == 1);
        assert_eq!(cb.max.z == c.z, k & 4 == 0);
        u.grow(&cb);
    }
    assert_eq!(u, b);
    let big = bvhlab_geom::Aabb::new(Vec3::splat(-f32::MAX), Vec3::splat(f32::MAX));
    assert_eq!(centre(&big), Vec3::ZERO);
}

#[test]
fn chunk_byte_formulas_and_kilian_slots() {
    // Kilian 4.2.2.5: 16 B -> 64 slots, 32 -> 192, 64 -> 448, 128 -> 960 (bfs); dense: B*8 - 32.
    let c = case("gen:terrain:n=3000", 2, 10, 3);
    for (b, slots) in [(16u64, 64u64), (32, 192), (64, 448), (128, 960)] {
        let l = build(
            &spec(
                "octree_1bit",
                &[("chunk_bytes", &b.to_string()), ("prim_threshold", "4")],
            ),
            &c.bvh,
            &c.scene.triangles,
        )
        .unwrap();
        let Layout::Octree1Bit(o) = &l else {
            unreachable!()
        };
        let m = l.memory();
        // Recount the fill from the chunk bit fields: used slots are exactly nodes - 1.
        let used = m.nodes - 1;
        assert!(m.chunks * slots >= used);
        assert!(m.chunk_fill <= 1.0 && m.chunk_fill > 0.0);
        assert_eq!(o.words.len() as u64, m.chunks * b / 8);
        let d = build(
            &spec(
                "octree_1bit",
                &[
                    ("chunk_bytes", &b.to_string()),
                    ("prim_threshold", "4"),
                    ("fill", "dense"),
                ],
            ),
            &c.bvh,
            &c.scene.triangles,
        )
        .unwrap()
        .memory();
        assert_eq!(d.chunks, used.div_ceil(b * 8 - 32));
        assert!(d.topology_bytes <= m.topology_bytes);
        if b == 16 {
            assert!(d.topology_bits_per_node() <= 128.0 / 96.0 + 128.0 / d.nodes as f64);
        }
    }
}

#[test]
fn deterministic_bytes_and_bad_parameters() {
    let c = case("gen:hairball:n=500", 2, 10, 5);
    for (name, kv) in [
        ("octree", vec![]),
        ("octree_1bit", vec![("fill", "dense")]),
        ("octree_1bit", vec![("chunk_bytes", "64")]),
    ] {
        let a = build(&spec(name, &kv), &c.bvh, &c.scene.triangles).unwrap();
        let b = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| build(&spec(name, &kv), &c.bvh, &c.scene.triangles).unwrap());
        assert_eq!(a, b, "{name} {kv:?}: identical at any thread count");
    }
    use bvhlab_layout::LayoutSpec;
    let raw = |kv: &[(&str, &str)]| {
        kv.iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    };
    for kv in [
        &[("chunk_bytes", "20")][..],
        &[("chunk_bytes", "8")],
        &[("fill", "sparse")],
        &[("mult_threshold", "0.5")],
        &[("max_depth", "99")],
        &[("overlap", "exact")],
        &[("prim_threshold", "-1")],
    ] {
        assert!(LayoutSpec::parse("octree_1bit", &raw(kv)).is_err(), "{kv:?}");
    }
    let d = LayoutSpec::parse("octree_1bit", &raw(&[])).unwrap();
    assert_eq!(
        d.params_string(),
        "chunk_bytes=16,fill=bfs,max_depth=24,mult_threshold=2.0,overlap=sat,prim_threshold=20"
    );
}

#[test]
fn sat_overlap_is_tighter_than_bounding_boxes() {
    // Long thin diagonal triangles (hairball): the bounding-box test puts many of them into
    // octants they never touch.
    let c = case("gen:hairball:n=500", 2, 10, 9);
    let m = |kv: &[(&str, &str)]| {
        build(&spec("octree", kv), &c.bvh, &c.scene.triangles)
            .unwrap()
            .memory()
    };
    // mult 8 never stops a split: both trees are full to depth 2, only the references differ.
    let kv = [
        ("prim_threshold", "4"),
        ("mult_threshold", "8"),
        ("max_depth", "2"),
    ];
    let sat = m(&kv);
    let aabb = m(&[kv[0], kv[1], kv[2], ("overlap", "aabb")]);
    assert_eq!((sat.nodes, aabb.nodes), (73, 73));
    assert!(sat.prim_refs < aabb.prim_refs, "sat {sat:?} aabb {aabb:?}");
}

/// Issue 15: octree builds can take minutes (a huge ground plane under a dense city); a caller with
/// a deadline gets a recognizable error instead, and without one the same layout as `build`.
#[test]
fn octree_builds_stop_at_their_deadline() {
    use bvhlab_layout::{build_until, DEADLINE_REACHED};
    let c = case("gen:hairball:n=500", 2, 10, 5);
    let past = std::time::Instant::now();
    for (name, kv) in [("octree", vec![]), ("octree_1bit", vec![("fill", "dense")])] {
        let e = build_until(&spec(name, &kv), &c.bvh, &c.scene.triangles, Some(past)).unwrap_err();
        assert!(e.starts_with(DEADLINE_REACHED), "{name}: {e}");
        let far = past + std::time::Duration::from_secs(3600);
        assert_eq!(
            build_until(&spec(name, &kv), &c.bvh, &c.scene.triangles, Some(far)).unwrap(),
            build(&spec(name, &kv), &c.bvh, &c.scene.triangles).unwrap(),
            "{name}"
        );
    }
    // BVH layouts are one linear pass: no deadline check.
    assert!(build_until(&spec("qbvh_chunks", &[]), &c.bvh, &c.scene.triangles, Some(past)).is_ok());
}
