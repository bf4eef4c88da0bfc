//! cwbvh (issue 19 item 2, Ylitie et al. 2017) against brute force and against bvh8, whose tree it
//! compresses: the counting traversal (exact test) equals brute force; the timed path with every box
//! test equals it with the exact test and agrees within `bvhlab_trace::agrees`' tolerance with the
//! watertight test; memory is 80 bytes per node; quantization costs little SAH, also at the edges
//! of the f32 range; validation rejects a box shrunk by one grid step.
mod common;
use bvhlab_bvh::CostParams;
use bvhlab_layout::cwbvh::CwBvh;
use bvhlab_layout::wide::{Collapse, Simd, WideBvh};
use bvhlab_layout::Layout;
use bvhlab_trace::fast::{Exact, Watertight};
use bvhlab_trace::check_agreement;
use common::*;

fn cw_of(l: &Layout) -> &CwBvh {
    match l {
        Layout::Cw(c) => c,
        _ => panic!("not cwbvh"),
    }
}

/// Oracle, timed paths, memory and the SAH against bvh8; returns SAH(cwbvh) / SAH(bvh8).
fn check_cw(c: &Case) -> f64 {
    check_cw_with(c, "sah")
}

/// [`check_cw`] with the `collapse` parameter given (bvh8 built with the same collapse).
fn check_cw_with(c: &Case, collapse: &str) -> f64 {
    let l = check(c, &spec("cwbvh", &[("collapse", collapse)]));
    let cw = cw_of(&l);
    let tris = &c.scene.triangles;
    let store = cw.store(tris);
    for simd in [Simd::Best, Simd::Avx2, Simd::Scalar] {
        assert_eq!(cw.hits_with::<Exact>(&store, &c.rays, simd), c.want, "{} {simd:?} exact", c.spec);
        let fast = cw.hits_with::<Watertight>(&store, &c.rays, simd);
        check_agreement(tris, &c.rays, &fast, &c.want, 8).unwrap_or_else(|e| panic!("{} {simd:?}: {e}", c.spec));
    }
    let w8 = WideBvh::build_with(&c.bvh, 8, cw.collapse).unwrap();
    assert_eq!(cw.collapse, if collapse == "greedy" { Collapse::Greedy } else { Collapse::default() });
    assert_eq!(cw.nodes.len(), w8.nodes());
    assert_eq!(cw.leaves.len(), w8.leaves.len());
    let m = l.memory();
    assert_eq!(m.topology_bytes, (cw.nodes.len() * 80 + cw.leaves.len() * 8) as u64);
    // Nodes under half of bvh8's; cwbvh keeps a leaf table (8 bytes per leaf) that bvh8 no longer
    // needs (its leaf codes name the first triangle pack), so the whole is compared as smaller only.
    assert!(cw.nodes.len() * 80 * 2 < w8.nodes() * 224, "{}: nodes not compressed", c.spec);
    assert!(m.topology_bytes < w8.memory().topology_bytes, "{}: not compressed", c.spec);
    let cost = CostParams::default();
    let (q, exact) = (cw.sah_cost(cost), w8.sah_cost(cost));
    assert!(q >= exact * (1.0 - 1e-9), "{}: quantized boxes are larger: {q} < {exact}", c.spec);
    q / exact
}

#[test]
fn cwbvh_matches_brute_force_and_costs_little_sah() {
    for s in SCENES {
        for leaf in [1, 2, 8] {
            let c = case(s, leaf, 2000, 7);
            for collapse in ["sah", "greedy"] {
                let ratio = check_cw_with(&c, collapse);
                // 8-bit boxes on a per-node grid: a few percent at most (measured 1.00-1.04 here).
                assert!(ratio < 1.10, "{s} leaf {leaf} {collapse}: SAH {ratio} x bvh8's");
            }
        }
    }
}

#[test]
fn quantization_is_as_good_at_the_edges_of_the_f32_range() {
    let base = check_cw(&case("gen:scale:n=2000", 2, 2000, 3));
    for s in ["1e-30", "1e30", "1e-37", "1e36"] {
        let ratio = check_cw(&case(&format!("gen:scale:n=2000,s={s}"), 2, 2000, 3));
        assert!((ratio - base).abs() < 0.01, "s={s}: SAH {ratio} x bvh8's, {base} at s=1");
    }
}

#[test]
fn validation_rejects_a_shrunk_box_and_a_repeated_triangle() {
    let c = case("gen:terrain:n=2000", 2, 10, 1);
    let tris = &c.scene.triangles;
    let cw = CwBvh::build(&c.bvh).unwrap();
    cw.validate_refs(tris, Default::default()).unwrap();
    // Every slot's upper x bound one grid step lower: some box no longer holds its triangles.
    let mut b = cw.clone();
    for n in &mut b.nodes {
        for q in &mut n.qhi[0] {
            *q = q.saturating_sub(1);
        }
    }
    assert!(b.validate_refs(tris, Default::default()).is_err());
    let mut b = cw.clone();
    b.prim_indices[0] = b.prim_indices[1];
    assert!(b.validate_refs(tris, Default::default()).is_err());
}

#[test]
fn identical_at_any_thread_count() {
    let c = case("gen:hairball:n=500", 2, 5000, 9);
    let cw = CwBvh::build(&c.bvh).unwrap();
    let store = cw.store(&c.scene.triangles);
    let run = |n| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
        pool.install(|| (cw.hits(&store, &c.rays), cw.trace(&c.scene.triangles, &c.rays)))
    };
    let (a, b) = (run(1), run(3));
    assert_eq!(a.0, b.0);
    assert_eq!(a.1.steps, b.1.steps);
}
