use bvhlab_bvh::{collapse::collapse, metrics, validate, Aabb, Bvh, CostParams, Node, Vec3};
use proptest::prelude::*;

fn unit_box(x: f32) -> Aabb {
    Aabb::new(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 1.0))
}

/// Builds a single-primitive-leaf tree over boxes by recursive median split along x (a test helper,
/// deliberately independent of the real builders).
fn median_tree(boxes: &[Aabb]) -> Bvh {
    let mut bvh = Bvh { nodes: vec![Node::leaf(Aabb::EMPTY, 0, 1)], prim_indices: (0..boxes.len() as u32).collect() };
    let mut stack = vec![(0usize, 0usize, boxes.len())];
    while let Some((slot, a, b)) = stack.pop() {
        let mut bb = Aabb::EMPTY;
        for &p in &bvh.prim_indices[a..b] {
            bb.grow(&boxes[p as usize]);
        }
        if b - a == 1 {
            bvh.nodes[slot] = Node::leaf(bb, a as u32, 1);
        } else {
            let left = bvh.nodes.len();
            bvh.nodes.push(Node::leaf(Aabb::EMPTY, 0, 1));
            bvh.nodes.push(Node::leaf(Aabb::EMPTY, 0, 1));
            bvh.nodes[slot] = Node::inner(bb, left as u32);
            let m = (a + b) / 2;
            stack.push((left, a, m));
            stack.push((left + 1, m, b));
        }
    }
    bvh
}

#[test]
fn metrics_of_two_leaf_tree_follow_eq4() {
    let boxes = [unit_box(0.0), unit_box(2.0)];
    let bvh = median_tree(&boxes);
    let m = metrics(&bvh, CostParams { c_t: 3.0, c_i: 2.0 });
    // Root box 3x1x1: SA = 2*(3+1+3) = 14; each leaf SA 6.
    let expect = (3.0 * 14.0 + 2.0 * (6.0 + 6.0)) / 14.0;
    assert!((m.sah_cost - expect).abs() < 1e-9, "{} vs {expect}", m.sah_cost);
    assert_eq!((m.inner_nodes, m.leaves, m.depth), (1, 2, 1));
    assert!((m.inner_sa_ratio - 1.0).abs() < 1e-12);
    assert!((m.leaf_sa_ratio - 12.0 / 14.0).abs() < 1e-12);
    assert_eq!(m.refs_per_leaf, 1.0);
    assert_eq!(m.bytes, 3 * 32 + 2 * 4);
}

#[test]
fn validate_catches_each_violation() {
    let boxes: Vec<Aabb> = (0..8).map(|i| unit_box(i as f32 * 1.5)).collect();
    let good = median_tree(&boxes);
    validate(&good, &boxes).unwrap();

    // Same-box primitives so only the duplicate reference (not a box test) can fail.
    let same: Vec<Aabb> = (0..8).map(|_| unit_box(0.0)).collect();
    let mut dup = median_tree(&same);
    validate(&dup, &same).unwrap();
    dup.prim_indices[1] = dup.prim_indices[0];
    assert!(validate(&dup, &same).unwrap_err().contains("twice"));

    let mut shrunk = good.clone();
    let leaf = shrunk.nodes.iter().position(|n| n.is_leaf()).unwrap();
    shrunk.nodes[leaf].bounds.max.x -= 0.5;
    assert!(validate(&shrunk, &boxes).is_err());

    let mut cyc = good.clone();
    let inner = cyc.nodes.iter().rposition(|n| !n.is_leaf()).unwrap();
    cyc.nodes[inner].first = 1; // points at the root's children again
    assert!(validate(&cyc, &boxes).is_err());

    let mut orphan = good.clone();
    orphan.nodes.push(Node::leaf(boxes[0], 0, 1));
    assert!(validate(&orphan, &boxes).unwrap_err().contains("unreachable"));

    let missing = Bvh { nodes: good.nodes.clone(), prim_indices: good.prim_indices[..7].to_vec() };
    assert!(validate(&missing, &boxes).is_err());
}

#[test]
fn collapse_merges_when_leaf_is_cheaper_and_keeps_when_not() {
    // Two overlapping identical boxes: splitting only adds traversal cost -> one leaf.
    let same = [unit_box(0.0), unit_box(0.0)];
    let c = collapse(&median_tree(&same), CostParams::default());
    validate(&c, &same).unwrap();
    assert_eq!(c.nodes.len(), 1);
    assert_eq!(c.nodes[0].count, 2);
    // Far apart boxes: the split is much cheaper than one big leaf -> unchanged shape.
    let far = [unit_box(0.0), unit_box(100.0)];
    let c = collapse(&median_tree(&far), CostParams::default());
    validate(&c, &far).unwrap();
    assert_eq!(c.nodes.len(), 3);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    #[test]
    fn collapse_never_raises_cost_and_stays_valid(xs in prop::collection::vec((0.0f32..50.0, 0.0f32..50.0, 0.01f32..5.0), 1..120)) {
        let boxes: Vec<Aabb> = xs.iter().map(|&(x, y, s)| Aabb::new(Vec3::new(x, y, 0.0), Vec3::new(x + s, y + s, s))).collect();
        let t = median_tree(&boxes);
        validate(&t, &boxes).unwrap();
        let cost = CostParams::default();
        let c = collapse(&t, cost);
        prop_assert!(validate(&c, &boxes).is_ok());
        let (before, after) = (metrics(&t, cost).sah_cost, metrics(&c, cost).sah_cost);
        prop_assert!(after <= before * (1.0 + 1e-9), "{after} > {before}");
        // Collapsing an already collapsed tree changes nothing.
        prop_assert_eq!(collapse(&c, cost), c);
    }
}

/// A long box [0, 2] split at x = 1 into two leaves (SBVH), plus a small box in the right leaf.
fn split_tree() -> (Bvh, Vec<Aabb>) {
    let long = Aabb::new(Vec3::new(0.0, 0.0, 0.0), Vec3::new(2.0, 1.0, 1.0));
    let small = Aabb::new(Vec3::new(1.5, 0.0, 0.0), Vec3::new(1.6, 0.1, 0.1));
    let left = Aabb::new(Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 1.0));
    let right = Aabb::new(Vec3::new(1.0, 0.0, 0.0), Vec3::new(2.0, 1.0, 1.0));
    let bvh = Bvh {
        nodes: vec![Node::inner(long, 1), Node::leaf(left, 0, 1), Node::leaf(right, 1, 2)],
        prim_indices: vec![0, 0, 1],
    };
    (bvh, vec![long, small])
}

#[test]
fn validate_split_allows_clipped_repeats_and_catches_gaps() {
    use bvhlab_bvh::validate_split;
    let (bvh, boxes) = split_tree();
    assert!(validate(&bvh, &boxes).is_err(), "exactly-once validation rejects repeats");
    validate_split(&bvh, &boxes).unwrap();
    // A gap: the right leaf ends at 1.9, so x in (1.9, 2] of triangle 0 is in no leaf box. (The
    // check is on the union of the parts' boxes: a gap between two parts is the oracle's to find.)
    let mut gap = bvh.clone();
    gap.nodes[2].bounds.max.x = 1.9;
    assert!(validate_split(&gap, &boxes).unwrap_err().contains("do not cover"));
    // Twice in one leaf.
    let mut twice = bvh.clone();
    twice.prim_indices = vec![0, 0, 0];
    assert!(validate_split(&twice, &boxes).is_err());
    // Triangle 1 never referenced.
    let mut missing = bvh.clone();
    missing.prim_indices = vec![0, 0, 0];
    missing.nodes[2].count = 1;
    missing.prim_indices.truncate(2);
    assert!(validate_split(&missing, &boxes).unwrap_err().contains("not referenced"));
}

#[test]
fn collapse_keeps_each_triangle_once_per_leaf() {
    let (bvh, boxes) = split_tree();
    // Costs make the root a leaf: traversal is expensive, intersection cheap.
    let c = CostParams { c_t: 100.0, c_i: 0.01 };
    let out = collapse(&bvh, c);
    assert_eq!(out.nodes.len(), 1);
    assert_eq!(out.prim_indices, vec![0, 1]);
    validate(&out, &boxes).unwrap();
    // Cheap traversal keeps the split.
    assert_eq!(collapse(&bvh, CostParams { c_t: 0.01, c_i: 100.0 }), bvh);
}
