//! Branch-and-bound search for the node X that minimizes the cost of merging a subtree L with it
//! (Bittner 2013 section 3.3, algorithm 1; thesis 3.4.2): shared by the optimizer ([`crate::ibo`])
//! and the incremental builder (`bvhlab_builders::incremental`).
use bvhlab_bvh::dyntree::DynTree;
use bvhlab_bvh::Aabb;
use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// Reusable buffers of [`find_best`] (the priority queue and the zero-cost bucket), so a pass of
/// thousands of searches allocates once.
#[derive(Default)]
pub struct SearchScratch {
    /// Entries with a positive induced cost, lowest first. Key: `(induced.to_bits(), node)`:
    /// induced costs are never negative (SA(X ∪ L) >= SA(X) holds in floats too, min/max are exact
    /// and the area is monotone in the extents), so the bit pattern orders like the value, and equal
    /// costs pop by node index (deterministic, no float comparison in the heap).
    heap: BinaryHeap<Reverse<(u64, u32)>>,
    /// Entries with induced cost exactly 0 (the subtree of X already contains L's box up to the
    /// root): the thesis' zero-priority bucket (3.4.2), a plain stack popped before the heap.
    zero: Vec<u32>,
    /// Nodes popped by all searches with this scratch (for measurements).
    pub visited: u64,
}

impl SearchScratch {
    pub fn new() -> Self {
        Self::default()
    }
}

/// The node of `tree` (inner or leaf, reachable from the root) where inserting a subtree with box
/// `l` increases the total surface area of the tree least: direct cost SA(X ∪ L) plus the induced
/// cost (the area growth of every ancestor of X). Returns (X_best, its total cost C_best).
/// Ties go to the node found first in the search order, which is deterministic.
///
/// Bittner 2013 algorithm 1, with the thesis' zero-priority bucket (3.4.2). One implementation
/// detail differs from the pseudocode, not the result: a node's two children are evaluated
/// (direct cost, C_best update) when their parent is expanded rather than when they are popped,
/// and a queue entry is (X, C_I of X's children) = C(L, X) - SA(X). So the two child boxes are
/// loaded together (two independent cache misses overlap, which is where the search spends its
/// time), leaves never enter the queue, and an entry carries the tighter bound of its subtree.
/// The pruning rules are the paper's: an entry whose bound C_I + SA(L) cannot beat C_best is not
/// queued, and the search ends when the lowest queued bound cannot (algorithm 1, line 6; every
/// queued entry has at least that bound). Areas in f64 (`Aabb::area`): in f32 they overflowed from
/// coordinates of 1e17 up and underflowed below 1e-19, so every candidate tied (issue 15).
pub fn find_best(tree: &DynTree, l: &Aabb, scratch: &mut SearchScratch) -> (u32, f64) {
    let SearchScratch { heap, zero, visited } = scratch;
    heap.clear();
    zero.clear();
    if tree.root == bvhlab_bvh::dyntree::NONE {
        return (bvhlab_bvh::dyntree::NONE, f64::INFINITY);
    }
    let sa_l = l.area();
    let nodes = &tree.nodes;
    let root = &nodes[tree.root as usize];
    let c_root = root.bounds.union(l).area();
    let mut best = (tree.root, c_root);
    if !root.is_leaf() {
        // Induced cost of the root's children: C(L, root) - SA(root) (algorithm 1, line 20),
        // clamped at 0 so a rounding artefact never gives a negative key.
        let ci = (c_root - root.bounds.area()).max(0.0);
        if ci + sa_l < best.1 {
            if ci == 0.0 {
                zero.push(tree.root);
            } else {
                heap.push(Reverse((ci.to_bits(), tree.root)));
            }
        }
    }
    loop {
        let (x, ci) = if let Some(x) = zero.pop() {
            (x, 0.0f64)
        } else if let Some(Reverse((bits, x))) = heap.pop() {
            (x, f64::from_bits(bits))
        } else {
            break;
        };
        // Early termination: no queued entry can beat C_best (algorithm 1, line 6).
        if ci + sa_l >= best.1 {
            break;
        }
        *visited += 1;
        let d = &nodes[x as usize];
        let (a, b) = (&nodes[d.left as usize], &nodes[d.right as usize]);
        let ca = ci + a.bounds.union(l).area();
        let cb = ci + b.bounds.union(l).area();
        if ca < best.1 {
            best = (d.left, ca);
        }
        if cb < best.1 {
            best = (d.right, cb);
        }
        for (child, cn, c) in [(d.left, a, ca), (d.right, b, cb)] {
            if cn.is_leaf() {
                continue;
            }
            let ci_child = (c - cn.bounds.area()).max(0.0);
            if ci_child + sa_l < best.1 {
                if ci_child == 0.0 {
                    zero.push(child);
                } else {
                    heap.push(Reverse((ci_child.to_bits(), child)));
                }
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use bvhlab_bvh::dyntree::DynTree;
    use bvhlab_bvh::{Bvh, Node, Vec3};
    use bvhlab_geom::rng::SplitMix64;

    /// Exhaustive reference: every reachable node, cost = induced + SA(X ∪ L).
    fn exhaustive(tree: &DynTree, l: &Aabb) -> f64 {
        let mut best = f64::INFINITY;
        let mut stack = vec![(tree.root, 0.0f64)];
        while let Some((x, induced)) = stack.pop() {
            let d = &tree.nodes[x as usize];
            let merged = d.bounds.union(l).area();
            best = best.min(induced + merged);
            if !d.is_leaf() {
                let ci = induced + merged - d.bounds.area();
                stack.push((d.right, ci));
                stack.push((d.left, ci));
            }
        }
        best
    }

    fn random_tree(n: usize, seed: u64) -> DynTree {
        // A chain-ish random tree built by repeated insertion at random leaves.
        let mut rng = SplitMix64::new(seed);
        let mut boxes = Vec::new();
        for _ in 0..n {
            let p = Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 10.0;
            let s = Vec3::new(rng.f32(), rng.f32(), rng.f32());
            boxes.push(Aabb::new(p, p + s));
        }
        let centers: Vec<Vec3> = boxes.iter().map(|b| b.center()).collect();
        let _ = &centers;
        // Spatial-median-like layout by sorting on x then pairing bottom-up.
        let mut nodes = vec![Node::leaf(boxes[0], 0, 1)];
        let prims: Vec<u32> = (0..n as u32).collect();
        // Build a left-deep chain: root = (((0,1),2),3)... in depth-first layout.
        fn build(nodes: &mut Vec<Node>, boxes: &[Aabb], lo: usize, hi: usize, slot: usize) -> Aabb {
            if hi - lo == 1 {
                nodes[slot] = Node::leaf(boxes[lo], lo as u32, 1);
                return boxes[lo];
            }
            let mid = lo + (hi - lo) / 3 + 1;
            let li = nodes.len();
            nodes.push(Node::leaf(Aabb::EMPTY, 0, 1));
            nodes.push(Node::leaf(Aabb::EMPTY, 0, 1));
            let a = build(nodes, boxes, lo, mid.min(hi - 1), li);
            let b = build(nodes, boxes, mid.min(hi - 1), hi, li + 1);
            let u = a.union(&b);
            nodes[slot] = Node::inner(u, li as u32);
            u
        }
        build(&mut nodes, &boxes, 0, n, 0);
        DynTree::from_bvh(&Bvh { nodes, prim_indices: prims })
    }

    #[test]
    fn branch_and_bound_matches_exhaustive() {
        let mut scratch = SearchScratch::new();
        for seed in 0..20 {
            let t = random_tree(200, seed);
            t.check().unwrap();
            let mut rng = SplitMix64::new(seed + 100);
            for _ in 0..50 {
                let p = Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 12.0 - 1.0;
                let s = Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 2.0;
                let l = Aabb::new(p, p + s);
                let (x, c) = find_best(&t, &l, &mut scratch);
                let want = exhaustive(&t, &l);
                assert!((c - want).abs() <= 1e-4 * want, "seed {seed}: {c} vs {want}");
                assert!(x != bvhlab_bvh::dyntree::NONE);
            }
        }
    }
}
