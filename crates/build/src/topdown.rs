//! The iterative top-down driver shared by the builders (thesis 3.1.1: iteration with an explicit
//! stack instead of recursion). It owns the node array; the split decision is a separate function.
use crate::boxa::BoxA;
use bvhlab_bvh::Node;

/// A node's primitive range `[begin, end)` with its bounds and its centroid bounds.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Range {
    pub begin: usize,
    pub end: usize,
    pub bounds: BoxA,
    pub cbounds: BoxA,
}

impl Range {
    #[inline]
    pub fn len(&self) -> usize {
        self.end - self.begin
    }
}

/// Builds the node array. `decide` returns `None` for a leaf, or the two non-empty child ranges
/// `[begin, mid)` and `[mid, end)` after it has partitioned its primitive arrays accordingly.
/// Layout (bvhlab_bvh::Node docs): root at 0, the two children of a node are allocated together as
/// an adjacent pair (left, right); left subtrees are expanded first (depth-first pair order).
pub(crate) fn build_nodes(
    n: usize,
    root: Range,
    mut decide: impl FnMut(&Range) -> Option<(Range, Range)>,
) -> Vec<Node> {
    let mut nodes = Vec::with_capacity(2 * n.max(1) - 1);
    if n == 0 {
        return nodes;
    }
    let placeholder = Node {
        bounds: root.bounds.to_aabb(),
        first: 0,
        count: 0,
    };
    nodes.push(placeholder);
    let mut stack: Vec<(usize, Range)> = Vec::with_capacity(128);
    stack.push((0, root));
    while let Some((ni, r)) = stack.pop() {
        match decide(&r) {
            Some((left, right)) => {
                debug_assert!(
                    left.begin == r.begin && left.end == right.begin && right.end == r.end
                );
                debug_assert!(left.len() > 0 && right.len() > 0);
                let li = nodes.len();
                nodes.push(placeholder);
                nodes.push(placeholder);
                nodes[ni] = Node::inner(r.bounds.to_aabb(), li as u32);
                stack.push((li + 1, right));
                stack.push((li, left));
            }
            None => {
                nodes[ni] = Node::leaf(r.bounds.to_aabb(), r.begin as u32, r.len() as u32);
            }
        }
    }
    nodes
}
