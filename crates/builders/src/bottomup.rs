//! Shared output step of the bottom-up builders (lbvh, aac, ploc): a cluster tree given as merges
//! becomes the flat [`Bvh`] layout every stage uses (root at 0, sibling pairs adjacent, depth-first
//! with left subtrees first, one primitive per leaf), or directly its SAH compaction, which the
//! thesis runs after every bottom-up build (3.2.2, 3.6.1): [`collapse_tree`].
use bvhlab_bvh::collapse::{collapse_from, CollapseSource};
use bvhlab_bvh::{Aabb, Bvh, CostParams, Node};

/// The result of agglomerative clustering. Node ids `0..leaf_prims.len()` are leaves (leaf `i`
/// holds primitive `leaf_prims[i]`); id `leaf_prims.len() + j` is the inner node whose children are
/// `children[j]` (left, right). `root` is the id of the root (leaf 0 when there is one primitive).
pub struct ClusterTree<'a> {
    pub leaf_prims: &'a [u32],
    pub children: &'a [[u32; 2]],
    pub root: u32,
}

/// Lays a cluster tree out as a [`Bvh`]; node boxes are recomputed bottom-up from the primitive boxes
/// (min/max unions are exact, so the result does not depend on the order clusters were merged in).
/// Iterative: trees from degenerate input can be as deep as the primitive count.
pub fn to_bvh(boxes: &[Aabb], tree: &ClusterTree) -> Bvh {
    let n = tree.leaf_prims.len();
    if n == 0 {
        return Bvh::default();
    }
    debug_assert_eq!(tree.children.len(), n - 1);
    let placeholder = Node { bounds: Aabb::EMPTY, first: 0, count: 0 };
    let mut nodes = vec![placeholder; 2 * n - 1];
    let mut prim_indices = Vec::with_capacity(n);
    let mut next = 1usize;
    // (cluster id, output slot); pop order = left subtree first, as in the top-down driver.
    let mut stack: Vec<(u32, usize)> = Vec::with_capacity(64);
    stack.push((tree.root, 0));
    while let Some((id, slot)) = stack.pop() {
        let id = id as usize;
        if id < n {
            let p = tree.leaf_prims[id];
            nodes[slot] = Node::leaf(boxes[p as usize], prim_indices.len() as u32, 1);
            prim_indices.push(p);
        } else {
            let [l, r] = tree.children[id - n];
            let li = next;
            next += 2;
            nodes[slot] = Node::inner(Aabb::EMPTY, li as u32);
            stack.push((r, li + 1));
            stack.push((l, li));
        }
    }
    debug_assert_eq!(next, 2 * n - 1);
    // Children always come after their parent in this layout: one reverse sweep refits every box.
    for i in (0..nodes.len()).rev() {
        if !nodes[i].is_leaf() {
            let c = nodes[i].first as usize;
            let mut b = nodes[c].bounds;
            b.grow(&nodes[c + 1].bounds);
            nodes[i].bounds = b;
        }
    }
    Bvh { nodes, prim_indices }
}

/// A builder's output from its cluster tree: the layout of single-triangle leaves ([`to_bvh`]), or
/// with `cost` its SAH compaction ([`collapse_tree`]).
pub(crate) fn finish(boxes: &[Aabb], tree: &ClusterTree, cost: Option<CostParams>) -> Bvh {
    match cost {
        Some(c) => collapse_tree(boxes, tree, c),
        None => to_bvh(boxes, tree),
    }
}

/// `collapse(&to_bvh(boxes, tree), cost)`, the same bytes, without the single-triangle layout in
/// between: the compaction reads the cluster tree and its inner boxes (24 bytes per triangle, where
/// the layout took 64 and lived beside the compacted copy: the Morton builders' memory peak,
/// issue 19.4).
pub fn collapse_tree(boxes: &[Aabb], tree: &ClusterTree, cost: CostParams) -> Bvh {
    let n = tree.leaf_prims.len();
    if n == 0 {
        return Bvh::default();
    }
    debug_assert_eq!(tree.children.len(), n - 1);
    let mut src = WithBounds { boxes, tree, inner: vec![Aabb::EMPTY; n - 1] };
    // Every primitive is in exactly one leaf (the codes' order is a permutation).
    collapse_from(&mut src, false, cost)
}

/// A cluster tree with its inner boxes (filled by [`CollapseSource::refit`] as the compaction's
/// post-order reaches them), as [`collapse_from`] reads trees.
struct WithBounds<'a> {
    boxes: &'a [Aabb],
    tree: &'a ClusterTree<'a>,
    inner: Vec<Aabb>,
}

impl CollapseSource for WithBounds<'_> {
    fn id_count(&self) -> usize {
        2 * self.tree.leaf_prims.len() - 1
    }
    fn root(&self) -> u32 {
        self.tree.root
    }
    #[inline]
    fn bounds(&self, id: u32) -> Aabb {
        let (id, n) = (id as usize, self.tree.leaf_prims.len());
        if id < n { self.boxes[self.tree.leaf_prims[id] as usize] } else { self.inner[id - n] }
    }
    #[inline]
    fn children(&self, id: u32) -> Option<[u32; 2]> {
        (id as usize).checked_sub(self.tree.leaf_prims.len()).map(|k| self.tree.children[k])
    }
    #[inline]
    fn prims(&self, id: u32) -> &[u32] {
        std::slice::from_ref(&self.tree.leaf_prims[id as usize])
    }
    fn reference_count(&self) -> usize {
        self.tree.leaf_prims.len()
    }
    /// The left child's box grown by the right one's, as [`to_bvh`] refits.
    fn refit(&mut self, id: u32, left: &Aabb, right: &Aabb) -> Aabb {
        let mut b = *left;
        b.grow(right);
        self.inner[id as usize - self.tree.leaf_prims.len()] = b;
        b
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bvhlab_bvh::Vec3;

    #[test]
    fn layout_and_bounds() {
        let boxes: Vec<Aabb> = (0..4).map(|i| Aabb::from_point(Vec3::splat(i as f32))).collect();
        // ((p2, p0), (p1, p3)) with leaves listed as [2, 0, 1, 3].
        let leaf_prims = [2u32, 0, 1, 3];
        let children = [[0u32, 1], [2, 3], [4, 5]];
        let bvh = to_bvh(&boxes, &ClusterTree { leaf_prims: &leaf_prims, children: &children, root: 6 });
        assert_eq!(bvh.nodes.len(), 7);
        assert_eq!(bvh.prim_indices, vec![2, 0, 1, 3]);
        assert_eq!(bvh.nodes[0].bounds, Aabb::new(Vec3::ZERO, Vec3::splat(3.0)));
        assert!(bvhlab_bvh::validate(&bvh, &boxes).is_ok());
        let one = to_bvh(&boxes[..1], &ClusterTree { leaf_prims: &[0], children: &[], root: 0 });
        assert_eq!(one.nodes.len(), 1);
        assert!(one.nodes[0].is_leaf());
    }
}
