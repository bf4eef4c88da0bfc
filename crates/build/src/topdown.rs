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

/// One node of the horizontal phase of [`build_nodes_parallel`]: its children (an adjacent pair,
/// like the final layout), a leaf, or a subtree handed to the vertical phase.
#[derive(Clone, Copy)]
enum Skel {
    Inner {
        bounds: BoxA,
        left: usize,
    },
    Leaf {
        bounds: BoxA,
        begin: usize,
        count: usize,
    },
    Task(usize),
}

/// The parallel driver, Wald's mixed scheme (thesis 3.1.2): a horizontal phase in which nodes with
/// at least `vertical_min` primitives are split one at a time by `horizontal` (which lets all threads
/// cooperate on that one node), then a vertical phase in which every smaller node becomes an
/// independent rayon task that builds its whole subtree with `vertical`.
///
/// The result is exactly [`build_nodes`]' array when both closures make the same decisions as its
/// `decide` (same partitions, in place): the sequential driver expands a pending subtree completely
/// before popping its right sibling, so a subtree's descendants are one contiguous block of the
/// array. The horizontal phase records a small skeleton, the tasks return their subtrees numbered
/// locally (root 0, descendants from 1 in the same depth-first pair order), and a final replay of
/// the sequential allocation order gives each block its offset.
///
/// `vertical` gets the task's primitives as their own slice and a range rebased to 0; it returns
/// the subtree's nodes with leaf `first` relative to that slice.
pub(crate) fn build_nodes_parallel<H, V>(
    refs: &mut [crate::primref::PrimRef],
    root: Range,
    vertical_min: usize,
    mut horizontal: H,
    vertical: V,
) -> Vec<Node>
where
    H: FnMut(&mut [crate::primref::PrimRef], &Range) -> Option<(Range, Range)>,
    V: Fn(&mut [crate::primref::PrimRef], &Range) -> Vec<Node> + Sync,
{
    use rayon::prelude::*;
    if refs.is_empty() {
        return Vec::new();
    }
    // Horizontal phase: the sequential driver's loop over the large nodes only.
    let mut skel: Vec<Skel> = vec![Skel::Task(usize::MAX)];
    let mut tasks: Vec<Range> = Vec::new();
    let mut stack: Vec<(usize, Range)> = vec![(0, root)];
    while let Some((si, r)) = stack.pop() {
        if r.len() < vertical_min.max(1) {
            skel[si] = Skel::Task(tasks.len());
            tasks.push(r);
            continue;
        }
        match horizontal(refs, &r) {
            Some((left, right)) => {
                debug_assert!(
                    left.begin == r.begin && left.end == right.begin && right.end == r.end
                );
                debug_assert!(left.len() > 0 && right.len() > 0);
                let li = skel.len();
                skel.push(Skel::Task(usize::MAX));
                skel.push(Skel::Task(usize::MAX));
                skel[si] = Skel::Inner {
                    bounds: r.bounds,
                    left: li,
                };
                stack.push((li + 1, right));
                stack.push((li, left));
            }
            None => {
                skel[si] = Skel::Leaf {
                    bounds: r.bounds,
                    begin: r.begin,
                    count: r.len(),
                };
            }
        }
    }

    // Vertical phase. Left subtrees are expanded first, so tasks come in increasing `begin` order
    // and their ranges are disjoint: carve `refs` into one slice per task.
    let mut jobs: Vec<(&mut [crate::primref::PrimRef], Range)> = Vec::with_capacity(tasks.len());
    let mut rest = refs;
    let mut pos = 0;
    for t in &tasks {
        debug_assert!(t.begin >= pos);
        let (_, tail) = std::mem::take(&mut rest).split_at_mut(t.begin - pos);
        let (mine, tail) = tail.split_at_mut(t.len());
        rest = tail;
        pos = t.end;
        let local = Range {
            begin: 0,
            end: t.len(),
            ..*t
        };
        jobs.push((mine, local));
    }
    let subtrees: Vec<Vec<Node>> = jobs.into_par_iter().map(|(s, r)| vertical(s, &r)).collect();

    // Replay the sequential allocation order: an inner node allocates its child pair when it is
    // popped, a task's subtree allocates its `len - 1` descendants as one block at that moment.
    let total = skel.len() + subtrees.iter().map(|s| s.len() - 1).sum::<usize>();
    let placeholder = Node {
        bounds: root.bounds.to_aabb(),
        first: 0,
        count: 0,
    };
    // Filled in parallel: the first touch of a large array (page faults) costs as much as a copy.
    let mut nodes: Vec<Node> = (0..total).into_par_iter().map(|_| placeholder).collect();
    // (global index of the task's root, first index of its descendant block, task id)
    let mut placed: Vec<(usize, usize, usize)> = Vec::with_capacity(tasks.len());
    let mut next = 1;
    let mut stack: Vec<(usize, usize)> = vec![(0, 0)];
    while let Some((gi, si)) = stack.pop() {
        match skel[si] {
            Skel::Inner { bounds, left } => {
                let li = next;
                next += 2;
                nodes[gi] = Node::inner(bounds.to_aabb(), li as u32);
                stack.push((li + 1, left + 1));
                stack.push((li, left));
            }
            Skel::Leaf {
                bounds,
                begin,
                count,
            } => nodes[gi] = Node::leaf(bounds.to_aabb(), begin as u32, count as u32),
            Skel::Task(t) => {
                placed.push((gi, next, t));
                next += subtrees[t].len() - 1;
            }
        }
    }
    debug_assert_eq!(next, total);
    // Local index i >= 1 goes to block + i - 1; leaves shift by the task's first primitive.
    let relocate = |n: &Node, block: usize, prim0: usize| {
        if n.is_leaf() {
            Node::leaf(n.bounds, n.first + prim0 as u32, n.count)
        } else {
            Node::inner(n.bounds, (block + n.first as usize - 1) as u32)
        }
    };
    for &(gi, block, t) in &placed {
        nodes[gi] = relocate(&subtrees[t][0], block, tasks[t].begin);
    }
    // Descendant blocks are disjoint and appear in increasing order: copy them in parallel.
    placed.sort_unstable_by_key(|p| p.1);
    let mut blocks: Vec<(&mut [Node], usize, usize)> = Vec::with_capacity(placed.len());
    let mut rest: &mut [Node] = &mut nodes;
    let mut pos = 0;
    for &(_, block, t) in &placed {
        let len = subtrees[t].len() - 1;
        let (_, tail) = std::mem::take(&mut rest).split_at_mut(block - pos);
        let (mine, tail) = tail.split_at_mut(len);
        rest = tail;
        pos = block + len;
        blocks.push((mine, block, t));
    }
    blocks.into_par_iter().for_each(|(out, block, t)| {
        let prim0 = tasks[t].begin;
        for (o, n) in out.iter_mut().zip(&subtrees[t][1..]) {
            *o = relocate(n, block, prim0);
        }
    });
    nodes
}
