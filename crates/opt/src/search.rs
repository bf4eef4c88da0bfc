//! Branch-and-bound search for the node X that minimizes the cost of merging a subtree L with it
//! (Bittner 2013 section 3.3, algorithm 1; thesis 3.4.2): shared by the optimizer ([`crate::ibo`])
//! and the incremental builder ([`crate::incremental`]).
use crate::tree::DynTree;
use bvhlab_bvh::Aabb;

/// Reusable buffers of [`find_best`] (the priority queue and the zero-cost bucket), so a pass of
/// thousands of searches allocates once.
#[derive(Default)]
pub struct SearchScratch {
    // owned by the ibo helper: priority queue, zero-priority bucket (thesis 3.4.2)
}

/// The node of `tree` (inner or leaf, reachable from the root) where inserting a subtree with box
/// `l` increases the total surface area of the tree least: direct cost SA(X ∪ L) plus the induced
/// cost (the area growth of every ancestor of X). Returns (X_best, its total cost C_best).
/// Ties go to the node found first in the search order, which is deterministic.
///
/// Skeleton: exhaustive evaluation over every reachable node (correct, O(n · depth)); the
/// branch-and-bound with the priority queue replaces it.
pub fn find_best(tree: &DynTree, l: &Aabb, _scratch: &mut SearchScratch) -> (u32, f32) {
    let mut best = (tree.root, f32::INFINITY);
    let mut stack = vec![(tree.root, 0.0f32)];
    while let Some((x, induced)) = stack.pop() {
        let d = &tree.nodes[x as usize];
        let merged = d.bounds.union(l).area();
        let c = induced + merged;
        if c < best.1 {
            best = (x, c);
        }
        if !d.is_leaf() {
            let ci = induced + merged - d.bounds.area();
            stack.push((d.right, ci));
            stack.push((d.left, ci));
        }
    }
    best
}
