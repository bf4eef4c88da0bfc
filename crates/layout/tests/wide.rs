//! bvh4 and bvh8 (issue 19 item 2) against brute force: the counting traversal (exact test) equals
//! it; the timed path with every box test (AVX2, SSE, scalar) equals it with the exact test and
//! agrees within `bvhlab_trace::agrees`' tolerance with the watertight f32 test. Structural
//! validation accepts the collapse and rejects broken copies.
mod common;
use bvhlab_bvh::{Bvh, Node};
use bvhlab_geom::Vec3;
use bvhlab_layout::wide::{Simd, WideBvh, EMPTY, LEAF_BIT, LEAF_BLOCK};
use bvhlab_layout::{build, Layout};
use bvhlab_trace::fast::{Exact, Watertight};
use bvhlab_trace::{brute_force, check_agreement, Ray, TriStore};
use common::*;

const SIMDS: [Simd; 4] = [Simd::Best, Simd::Avx2, Simd::Sse, Simd::Scalar];

fn wide_of(l: &Layout) -> &WideBvh {
    match l {
        Layout::Wide(w) => w,
        _ => panic!("not a wide layout"),
    }
}

/// Every box test, exact and watertight, against brute force.
fn check_timed(c: &Case, w: &WideBvh, rays: &[Ray], want: &[bvhlab_trace::Hit], edge: usize) {
    let store = w.store(&c.scene.triangles);
    for simd in SIMDS {
        let got = w.hits_with::<Exact>(&store, rays, simd);
        assert_eq!(got, want, "{} bvh{} {simd:?} exact", c.spec, w.width);
        let fast = w.hits_with::<Watertight>(&store, rays, simd);
        check_agreement(&c.scene.triangles, rays, &fast, want, edge)
            .unwrap_or_else(|e| panic!("{} bvh{} {simd:?}: {e}", c.spec, w.width));
    }
    assert_eq!(w.hits(&store, rays), w.hits_with::<Watertight>(&store, rays, Simd::Best));
}

#[test]
fn wide_layouts_match_brute_force() {
    for s in SCENES {
        for leaf in [1, 2, 8] {
            let c = case(s, leaf, 2000, 7);
            for name in ["bvh4", "bvh8"] {
                let l = check(&c, &spec(name, &[]));
                let w = wide_of(&l);
                check_timed(&c, w, &c.rays, &c.want, 8);
                let m = l.memory();
                let width = if name == "bvh4" { 4 } else { 8 };
                assert_eq!(m.topology_bytes, (w.nodes() * 28 * width) as u64);
                assert_eq!(m.prim_refs, c.scene.triangles.len() as u64);
                // Fewer nodes than the binary tree's inner nodes; its leaves, or subtrees of at
                // most LEAF_BLOCK references combined into one leaf.
                let bin_leaves = c.bvh.nodes.iter().filter(|n| n.is_leaf()).count();
                assert!(w.leaves.len() <= bin_leaves);
                let bin_max = c.bvh.nodes.iter().filter(|n| n.is_leaf()).map(|n| n.count).max().unwrap_or(0);
                assert!(w.leaves.iter().all(|l| l[1] <= LEAF_BLOCK.max(bin_max)), "{} leaf {leaf}", c.spec);
                assert!(w.nodes() <= (c.bvh.nodes.len() - bin_leaves).max(1));
            }
        }
    }
}

#[test]
fn collapse_fills_nodes_and_lowers_node_visits() {
    let c = case("gen:sphere:n=3000", 2, 2000, 3);
    let b2 = build(&spec("bvh2", &[]), &c.bvh, &c.scene.triangles).unwrap();
    let s2 = b2.trace(&c.scene.triangles, &c.rays);
    for (name, width) in [("bvh4", 4usize), ("bvh8", 8)] {
        let l = build(&spec(name, &[]), &c.bvh, &c.scene.triangles).unwrap();
        let w = wide_of(&l);
        // Greedy collapse: each wide node stands for up to width - 1 binary inner nodes
        // (on average at least 1.5 here: nodes over two leaves keep two children).
        let inner = c.bvh.nodes.iter().filter(|n| !n.is_leaf()).count();
        assert!(w.nodes() * 3 <= inner * 2, "{name}: {} wide nodes for {inner} binary inner nodes", w.nodes());
        let _ = width;
        let s = l.trace(&c.scene.triangles, &c.rays);
        // Binary leaves of up to two triangles, combined into leaves of up to four: more tests,
        // but not twice as many (culling differs a little too), and far fewer node visits.
        let ratio = s.total_intersections as f64 / s2.total_intersections as f64;
        assert!((1.0..2.0).contains(&ratio), "{name}: tests {ratio} of bvh2's");
        let steps = s.total_steps as f64 / s2.total_steps as f64;
        assert!(steps < 0.75, "{name}: node visits {steps} of bvh2's");
        eprintln!("{name}: tests {ratio:.3}, steps {steps:.3} of bvh2's");
    }
}

#[test]
fn deep_trees_axis_rays_and_empty_inputs() {
    let c = case("gen:sphere:n=600", 1, 10, 1);
    let tris = &c.scene.triangles;
    // A caterpillar: depth n - 1, every box the whole scene: the stack spills past its array.
    let n = tris.len();
    let mut all = bvhlab_geom::Aabb::EMPTY;
    for t in tris {
        all = all.union(&t.bounds());
    }
    let mut nodes = Vec::new();
    for k in 0..n - 1 {
        nodes.push(Node::inner(all, 2 * k as u32 + 1));
        nodes.push(Node::leaf(tris[k].bounds(), k as u32, 1));
        if k == n - 2 {
            nodes.push(Node::leaf(tris[n - 1].bounds(), n as u32 - 1, 1));
        }
    }
    let cat = Bvh {
        nodes,
        prim_indices: (0..n as u32).collect(),
    };
    let mut rays = c.rays.clone();
    for t in tris.iter().take(60) {
        let (b, m) = (t.bounds(), t.bounds().center());
        for (o, d) in [
            (Vec3::new(b.min.x, m.y, -5.0), Vec3::Z),
            (Vec3::new(m.x, b.max.y, 5.0), Vec3::NEG_Z),
            (Vec3::new(-5.0, b.min.y, b.min.z), Vec3::X),
            (m, Vec3::ZERO),
        ] {
            rays.push(Ray {
                origin: o,
                dir: d,
                tmax: f32::INFINITY,
            });
        }
    }
    let want = brute_force(tris, &rays);
    for bvh in [&cat, &c.bvh] {
        for width in [4, 8] {
            let w = WideBvh::build(bvh, width).unwrap();
            w.validate(tris).unwrap();
            assert_eq!(w.trace(tris, &rays).hits, want);
            let cc = Case {
                spec: "deep".into(),
                scene: c.scene.clone(),
                bvh: bvh.clone(),
                rays: rays.clone(),
                want: want.clone(),
            };
            check_timed(&cc, &w, &rays, &want, 8);
        }
    }
    let empty = WideBvh::build(&Bvh::default(), 8).unwrap();
    empty.validate(&[]).unwrap();
    assert!(empty.trace(&[], &rays).hits.iter().all(|h| !h.is_hit()));
    // A one-leaf BVH: a root with one leaf child.
    let one = Bvh {
        nodes: vec![Node::leaf(all, 0, n as u32)],
        prim_indices: (0..n as u32).collect(),
    };
    let w = WideBvh::build(&one, 4).unwrap();
    w.validate(tris).unwrap();
    assert_eq!(w.trace(tris, &rays).hits, want);
}

#[test]
fn validation_rejects_broken_layouts() {
    let c = case("gen:terrain:n=2000", 2, 10, 1);
    let tris = &c.scene.triangles;
    let w = WideBvh::build(&c.bvh, 8).unwrap();
    w.validate(tris).unwrap();
    // A shrunken child box.
    let mut b = w.clone();
    let i = 8; // node 0, row min.y, slot 0
    let words = b.words_mut();
    words[i] = (f32::from_bits(words[i]) + 1.0).to_bits();
    assert!(b.validate(tris).is_err());
    // A leaf referenced twice instead of another.
    let mut b = w.clone();
    let codes = 6 * 8;
    let n = b.nodes();
    let words = b.words_mut();
    let leaf_slots: Vec<usize> = (0..n * 56)
        .filter(|&k| k % 56 >= codes && words[k] != EMPTY && words[k] & LEAF_BIT != 0)
        .collect();
    words[leaf_slots[1]] = words[leaf_slots[0]];
    assert!(b.validate(tris).is_err());
    // A triangle twice, another never.
    let mut b = w.clone();
    b.prim_indices[0] = b.prim_indices[1];
    assert!(b.validate(tris).is_err());
}

#[test]
fn identical_at_any_thread_count() {
    let c = case("gen:hairball:n=500", 2, 5000, 9);
    let w = WideBvh::build(&c.bvh, 8).unwrap();
    let store = w.store(&c.scene.triangles);
    let run = |n| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
            .install(|| (w.hits(&store, &c.rays), w.trace(&c.scene.triangles, &c.rays)))
    };
    let (a, b) = (run(1), run(3));
    assert_eq!(a.0, b.0);
    assert_eq!(a.1.steps, b.1.steps);
}

/// A leaf child names its first triangle slot and its triangles run to the store's end mark, so a
/// store without marks is refused (it would test the following leaves' triangles too), and every
/// leaf's last slot carries the mark.
#[test]
#[should_panic(expected = "leaf ends marked")]
fn timed_path_refuses_a_store_without_leaf_ends() {
    let c = case("gen:sphere:n=500", 2, 10, 5);
    let w = WideBvh::build(&c.bvh, 8).unwrap();
    let store = w.store(&c.scene.triangles);
    let ends: Vec<usize> = w.leaves.iter().map(|l| (l[0] + l[1] - 1) as usize).collect();
    let marked: Vec<usize> = (0..store.tris.len()).filter(|&i| store.tris[i].last != 0).collect();
    let mut want = ends.clone();
    want.sort_unstable();
    assert_eq!(marked, want);
    w.hits(&TriStore::new(&w.prim_indices, &c.scene.triangles), &c.rays);
}
