mod common;
use bvhlab_bvh::{Bvh, CostParams, Node};
use bvhlab_geom::{Aabb, Triangle, Vec3};
use bvhlab_layout::chunks::chunk_bfs;
use bvhlab_layout::{build, Layout, LayoutSpec};
use bvhlab_trace::{brute_force, Ray};
use common::*;

/// Exact byte counts: chunks * chunk_bytes + ceil(slots * 6 * bits / 8) node info + 24-byte
/// root box; total adds (leaves + 1) offsets and one u32 per triangle.
fn check_memory(c: &Case, l: &Layout, chunk_bytes: u64, bits: u64) {
    let bvh = &c.bvh;
    let kids: Vec<[u32; 2]> = bvh
        .nodes
        .iter()
        .map(|n| [n.first, n.first.wrapping_add(1)])
        .collect();
    let groups = ((chunk_bytes / 8 - 5) * 32) as usize;
    let ch = chunk_bfs(0, 2, groups, |i| {
        (!bvh.nodes[i as usize].is_leaf()).then(|| &kids[i as usize][..])
    })
    .unwrap();
    let nodes = bvh.nodes.len() as u64;
    let leaves = bvh.nodes.iter().filter(|n| n.is_leaf()).count() as u64;
    let tris = c.scene.triangles.len() as u64;
    let m = l.memory();
    let topo = ch.chunks.len() as u64 * chunk_bytes + ((nodes - 1) * 6 * bits).div_ceil(8) + 24;
    assert_eq!(m.topology_bytes, topo, "{}", c.spec);
    assert_eq!(m.total_bytes, topo + 4 * (leaves + 1) + 4 * tris);
    assert_eq!(m.nodes, nodes);
    assert_eq!(m.chunks, ch.chunks.len() as u64);
    assert_eq!(m.chunk_fill, ch.fill());
    assert_eq!(m.prim_refs, tris);
}

#[test]
fn every_scene_chunk_size_frame_and_bits_matches_brute_force() {
    let cost = CostParams::default();
    for s in SCENES {
        for leaf in [1, 2] {
            let c = case(s, leaf, 150, 11 + leaf as u64);
            let exact = bvhlab_bvh::metrics(&c.bvh, cost).sah_cost;
            for chunk in [48u64, 64, 128, 256] {
                for frame in ["chunk", "parent"] {
                    for bits in [1u64, 4, 8, 16] {
                        let (cs, bs) = (chunk.to_string(), bits.to_string());
                        let sp = spec(
                            "qbvh_chunks",
                            &[("chunk_bytes", &cs), ("frame", frame), ("bits", &bs)],
                        );
                        let l = check(&c, &sp);
                        check_memory(&c, &l, chunk, bits);
                        same_as_portable(&c, &l);
                        // Quantized boxes contain the exact ones, so eq. 4 can only grow.
                        let q = l.sah_cost(cost);
                        assert!(
                            q >= exact * (1.0 - 1e-9),
                            "{s} leaf {leaf} {sp:?}: quantized SAH {q} < exact {exact}"
                        );
                        if bits == 16 && frame == "parent" {
                            assert!(q <= exact * 1.05 + 1e-9, "{s}: 16-bit SAH {q} vs {exact}");
                        }
                    }
                }
            }
        }
    }
}

/// The SIMD traversal (when the CPU has it) computes the same floats as the portable one.
fn same_as_portable(c: &Case, l: &Layout) {
    let Layout::QbvhChunks(q) = l else { unreachable!() };
    let (a, b) = (
        q.trace(&c.scene.triangles, &c.rays),
        q.trace_portable(&c.scene.triangles, &c.rays),
    );
    assert_eq!(a.steps, b.steps, "{}", c.spec);
    assert_eq!(a.intersections, b.intersections);
    for (x, y) in a.hits.iter().zip(&b.hits) {
        assert_eq!((x.t.to_bits(), x.prim), (y.t.to_bits(), y.prim));
    }
}

#[test]
fn default_qbvh_chunks_matches_brute_force_on_more_rays_and_is_deterministic() {
    for s in SCENES {
        let c = case(s, 2, 2000, 5);
        for frame in ["chunk", "parent"] {
            let sp = spec("qbvh_chunks", &[("frame", frame)]);
            let a = check(&c, &sp);
            same_as_portable(&c, &a);
            let b = build(&sp, &c.bvh, &c.scene.triangles).unwrap();
            assert_eq!(a, b, "build is deterministic");
            let (ta, tb) = (
                a.trace(&c.scene.triangles, &c.rays),
                b.trace(&c.scene.triangles, &c.rays),
            );
            assert_eq!(ta.steps, tb.steps);
            // Conservative boxes: at least as many entered nodes in total as the exact BVH
            // (the same topology, boxes only grow).
            let exact = bvhlab_trace::trace(&c.bvh, &c.scene.triangles, &c.rays);
            assert!(ta.total_steps >= exact.total_steps * 9 / 10, "{s} {frame}");
        }
    }
}

#[test]
fn topology_is_under_half_of_bvh2_at_chunk_64_bits_8() {
    for s in SCENES {
        for leaf in [1, 2] {
            let c = case(s, leaf, 0, 1);
            let l = build(&spec("qbvh_chunks", &[]), &c.bvh, &c.scene.triangles).unwrap();
            let m = l.memory();
            let bvh2 = c.bvh.nodes.len() as u64 * 32;
            assert!(
                (m.topology_bytes as f64) < 0.5 * bvh2 as f64,
                "{s} leaf {leaf}: qbvh_chunks topology {} vs bvh2 {bvh2} ({:.1} bits/node, fill {:.3})",
                m.topology_bytes,
                m.topology_bits_per_node(),
                m.chunk_fill
            );
        }
    }
}

fn tri_at_x(x: f32) -> Triangle {
    Triangle::new(
        Vec3::new(x, -1.0, -1.0),
        Vec3::new(x, 2.0, -1.0),
        Vec3::new(x, -1.0, 2.0),
    )
}

fn compare(tris: &[Triangle], bvh: &Bvh, rays: &[Ray], kv: &[(&str, &str)]) -> Layout {
    let want = brute_force(tris, rays);
    let sp = spec("qbvh_chunks", kv);
    let l = build(&sp, bvh, tris).unwrap();
    l.validate(tris).unwrap();
    let got = l.trace(tris, rays);
    for (i, (g, w)) in got.hits.iter().zip(&want).enumerate() {
        assert!(same_hit(g, w), "{kv:?} ray {i}: {g:?} vs {w:?}");
    }
    l
}

#[test]
fn a_leaf_only_root_is_one_leaf_without_chunks() {
    let tris = vec![tri_at_x(0.5)];
    let bvh = Bvh {
        nodes: vec![Node::leaf(tris[0].bounds(), 0, 1)],
        prim_indices: vec![0],
    };
    let rays: Vec<Ray> = (0..50)
        .map(|i| Ray {
            origin: Vec3::new(-1.0, -0.5 + 0.05 * i as f32, 0.1),
            dir: Vec3::X,
            tmax: 10.0,
        })
        .collect();
    for frame in ["chunk", "parent"] {
        let l = compare(&tris, &bvh, &rays, &[("frame", frame), ("bits", "3")]);
        let m = l.memory();
        assert_eq!(m.chunks, 0);
        assert_eq!(m.topology_bytes, 24);
        assert_eq!(m.total_bytes, 24 + 4 * 2 + 4);
        assert_eq!(m.nodes, 1);
        let st = l.trace(&tris, &rays);
        assert!(st.hit_count > 0 && st.steps.iter().all(|&s| s <= 1));
        let sah = l.sah_cost(CostParams::default());
        assert_eq!(
            sah,
            bvhlab_bvh::metrics(&bvh, CostParams::default()).sah_cost
        );
    }
    // An empty BVH traces to misses.
    let empty = build(&spec("qbvh_chunks", &[]), &Bvh::default(), &[]).unwrap();
    empty.validate(&[]).unwrap();
    assert!(!empty.trace(&[], &rays).hits[0].is_hit());
}

/// A 10^4-deep staircase: node i = (leaf with triangle i, the rest). Rays along -x push one entry
/// per level (the rest is nearer), so the traversal stack spills and the chunks are chains.
#[test]
fn a_ten_thousand_deep_chain_traces_without_recursion() {
    let n = 10_001usize;
    let tris: Vec<Triangle> = (0..n).map(|i| tri_at_x(i as f32)).collect();
    let mut nodes = Vec::with_capacity(2 * n - 1);
    // Node indices: inner node of level i at 2i, its leaf child at 2i + 1, the rest at 2i + 2.
    for i in 0..n {
        let mut b = Aabb::EMPTY;
        for t in &tris[i..] {
            b.grow(&t.bounds());
        }
        if i + 1 < n {
            nodes.push(Node::inner(b, 2 * i as u32 + 1));
            nodes.push(Node::leaf(tris[i].bounds(), i as u32, 1));
        } else {
            nodes.push(Node::leaf(b, i as u32, 1));
        }
    }
    let bvh = Bvh {
        nodes,
        prim_indices: (0..n as u32).collect(),
    };
    let boxes: Vec<Aabb> = tris.iter().map(|t| t.bounds()).collect();
    bvhlab_bvh::validate(&bvh, &boxes).unwrap();
    let mut rays: Vec<Ray> = (0..20)
        .map(|i| Ray {
            origin: Vec3::new(n as f32 + 1.0, -0.5 + 0.1 * i as f32, 0.2),
            dir: -Vec3::X,
            tmax: 2.0 * n as f32,
        })
        .collect();
    rays.push(Ray {
        origin: Vec3::new(-1.0, 0.0, 0.0),
        dir: Vec3::X,
        tmax: 1e9,
    });
    for (chunk, frame) in [("48", "chunk"), ("64", "parent"), ("256", "chunk")] {
        let l = compare(
            &tris,
            &bvh,
            &rays,
            &[("chunk_bytes", chunk), ("frame", frame)],
        );
        let m = l.memory();
        // A chain fills every chunk but the last.
        assert!(m.chunk_fill > 0.9, "{chunk}: fill {}", m.chunk_fill);
        let st = l.trace(&tris, &rays);
        assert!(st.steps[0] as usize >= n, "went down the whole chain");
    }
}

#[test]
fn validate_rejects_broken_layouts() {
    let c = case("gen:sphere:n=500", 2, 0, 1);
    let l = build(&spec("qbvh_chunks", &[]), &c.bvh, &c.scene.triangles).unwrap();
    let Layout::QbvhChunks(q) = l else { unreachable!() };
    q.validate(&c.scene.triangles).unwrap();
    // Collapsing every key to 0 makes the boxes points: not conservative.
    let mut bad = q.clone();
    bad.keys.iter_mut().for_each(|k| *k = 0);
    assert!(bad
        .validate(&c.scene.triangles)
        .unwrap_err()
        .contains("contain"));
    // A duplicated primitive.
    let mut bad = q.clone();
    bad.prims[1] = bad.prims[0];
    assert!(bad.validate(&c.scene.triangles).is_err());
    // A bit flipped in the first chunk's bit field changes the structure.
    let mut bad = q.clone();
    bad.words[5] ^= 1;
    assert!(bad.validate(&c.scene.triangles).is_err());
    // Truncated node info.
    let mut bad = q;
    bad.keys.pop();
    assert!(bad.validate(&c.scene.triangles).is_err());
}

#[test]
fn bad_parameters_are_rejected() {
    let raw = |kv: &[(&str, &str)]| {
        kv.iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    };
    for kv in [
        [("bits", "0")],
        [("bits", "17")],
        [("chunk_bytes", "40")],
        [("chunk_bytes", "60")],
        [("frame", "grandparent")],
    ] {
        assert!(LayoutSpec::parse("qbvh_chunks", &raw(&kv)).is_err(), "{kv:?}");
    }
    assert!(LayoutSpec::parse("qbvh_chunks", &raw(&[("chunk_bytes", "48"), ("bits", "16")])).is_ok());
}

/// Axis-parallel rays whose origins lie on triangle (hence box) planes: `RayBox::hit` tests a
/// zero-direction axis by the origin's position; the SIMD pair test must agree.
#[test]
fn axis_parallel_rays_on_box_planes() {
    let c = case("gen:city:blocks=6", 1, 0, 1);
    let tris = &c.scene.triangles;
    let b = c.scene.bounds();
    let mut coords: Vec<Vec3> = tris.iter().flat_map(|t| t.v).collect();
    coords.sort_by(|a, b| a.to_array().partial_cmp(&b.to_array()).unwrap());
    coords.dedup();
    let mut rays = Vec::new();
    for (i, v) in coords.iter().step_by(7).take(300).enumerate() {
        let d = [Vec3::X, Vec3::Y, Vec3::Z][i % 3] * if i % 2 == 0 { 1.0 } else { -1.0 };
        // Start outside the scene along the axis, keep the other two coordinates on the vertex.
        let back = (b.max - b.min).length() + 1.0;
        rays.push(Ray {
            origin: *v - d * back,
            dir: d,
            tmax: 3.0 * back,
        });
        rays.push(Ray {
            origin: *v,
            dir: d,
            tmax: back,
        });
    }
    let want = brute_force(tris, &rays);
    for frame in ["chunk", "parent"] {
        for bits in ["8", "3"] {
            let sp = spec("qbvh_chunks", &[("frame", frame), ("bits", bits)]);
            let l = build(&sp, &c.bvh, tris).unwrap();
            let got = l.trace(tris, &rays);
            for (i, (g, w)) in got.hits.iter().zip(&want).enumerate() {
                assert!(same_hit(g, w), "{frame} {bits} ray {i}: {g:?} vs {w:?}");
            }
            let cc = Case {
                spec: c.spec.clone(),
                scene: c.scene.clone(),
                bvh: c.bvh.clone(),
                rays: rays.clone(),
                want: want.clone(),
            };
            same_as_portable(&cc, &l);
        }
    }
}
