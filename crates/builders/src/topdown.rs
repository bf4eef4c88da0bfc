//! The iterative top-down driver shared by the builders (thesis 3.1.1: iteration with an explicit
//! stack instead of recursion). It owns the node array; the split decision is a separate function.
use crate::simd_box::BoxA;
use crate::primref::Ref;
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
    /// `[0, n)` with its bounds and centroid bounds.
    pub fn root(n: usize, bounds: BoxA, cbounds: BoxA) -> Range {
        Range { begin: 0, end: n, bounds, cbounds }
    }
    #[inline]
    pub fn len(&self) -> usize {
        self.end - self.begin
    }
    /// The two children of a split at `mid` (`begin < mid < end`), with the (bounds, centroid
    /// bounds) of each side.
    #[inline]
    pub fn split(&self, mid: usize, left: (BoxA, BoxA), right: (BoxA, BoxA)) -> (Range, Range) {
        (
            Range { begin: self.begin, end: mid, bounds: left.0, cbounds: left.1 },
            Range { begin: mid, end: self.end, bounds: right.0, cbounds: right.1 },
        )
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

/// One node of the horizontal phase of [`build_nodes_parallel`]: an inner node (indices of its two
/// children in the skeleton), a leaf, or a subtree built by the vertical phase.
#[derive(Clone, Copy)]
enum Skel {
    Inner {
        bounds: BoxA,
        left: usize,
        right: usize,
    },
    Leaf {
        bounds: BoxA,
        begin: usize,
        count: usize,
    },
    Task(usize),
}

/// The skeleton of one subtree (root at index 0) and its vertical subtrees: `(first primitive,
/// nodes numbered locally)`, indexed by `Skel::Task`. Skeleton indices are only links; the final
/// layout comes from the replay in [`build_nodes_parallel`].
struct Piece {
    skel: Vec<Skel>,
    tasks: Vec<(usize, Vec<Node>)>,
}

impl Piece {
    /// Appends `other`'s skeleton and tasks; returns the index of its root here.
    fn append(&mut self, other: Piece) -> usize {
        let (s0, t0) = (self.skel.len(), self.tasks.len());
        self.skel.extend(other.skel.into_iter().map(|n| match n {
            Skel::Inner {
                bounds,
                left,
                right,
            } => Skel::Inner {
                bounds,
                left: left + s0,
                right: right + s0,
            },
            Skel::Task(t) => Skel::Task(t + t0),
            leaf => leaf,
        }));
        self.tasks.extend(other.tasks);
        s0
    }
}

/// The parallel driver, Wald's mixed scheme (thesis 3.1.2): nodes with at least `vertical_min`
/// primitives are split by `horizontal` (which lets all threads cooperate on that node); every
/// smaller node becomes an independent task that builds its whole subtree with `vertical`.
/// Sibling subtrees are processed concurrently (`rayon::join`), so a large node's binning, the
/// other large nodes of its level and the vertical tasks already released all share the threads,
/// with no barrier between the phases (the thesis' scheme does the levels one node at a time).
///
/// The result is exactly [`build_nodes`]' array when both closures make the same decisions as its
/// `decide` (same partitions, in place): the sequential driver expands a pending subtree completely
/// before popping its right sibling, so a subtree's descendants are one contiguous block of the
/// array. The horizontal phase records a small skeleton, the tasks return their subtrees numbered
/// locally (root 0, descendants from 1 in the same depth-first pair order), and a final replay of
/// the sequential allocation order gives each block its offset. Scheduling never affects the tree.
///
/// Both closures get the node's primitives (and for `horizontal` an equally long scratch slice) as
/// their own slices with a range rebased to 0; `horizontal` returns child ranges in that frame and
/// `vertical` returns the subtree's nodes with leaf `first` relative to its slice.
/// Recursion: one level per level of large nodes, at most about `2 log2 n`; deeper large nodes
/// (a degenerate, unbalanced top) fall back to an explicit stack, see [`horizontal_iterative`].
pub(crate) fn build_nodes_parallel<R: Ref, H, V>(
    refs: &mut [R],
    root: Range,
    vertical_min: usize,
    horizontal: H,
    vertical: V,
) -> Vec<Node>
where
    H: Fn(&mut [R], &mut [bool], &Range) -> Option<(Range, Range)> + Sync,
    V: Fn(&mut [R], &Range) -> Vec<Node> + Sync,
{
    use rayon::prelude::*;
    if refs.is_empty() {
        return Vec::new();
    }
    let n = refs.len();
    let mut flags = vec![false; n];
    let max_depth = 2 * (usize::BITS - n.leading_zeros()) as usize;
    let drv = Driver {
        vertical_min: vertical_min.max(1),
        max_depth,
        horizontal: &horizontal,
        vertical: &vertical,
        refs: std::marker::PhantomData,
    };
    let piece = drv.subtree(refs, &mut flags, root, 0, 0);
    let Piece { skel, tasks } = piece;

    // Replay the sequential allocation order: an inner node allocates its child pair when it is
    // popped, a task's subtree allocates its `len - 1` descendants as one block at that moment.
    let inner = skel
        .iter()
        .filter(|s| matches!(s, Skel::Inner { .. }))
        .count();
    let total = 1 + 2 * inner + tasks.iter().map(|s| s.1.len() - 1).sum::<usize>();
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
            Skel::Inner {
                bounds,
                left,
                right,
            } => {
                let li = next;
                next += 2;
                nodes[gi] = Node::inner(bounds.to_aabb(), li as u32);
                stack.push((li + 1, right));
                stack.push((li, left));
            }
            Skel::Leaf {
                bounds,
                begin,
                count,
            } => nodes[gi] = Node::leaf(bounds.to_aabb(), begin as u32, count as u32),
            Skel::Task(t) => {
                placed.push((gi, next, t));
                next += tasks[t].1.len() - 1;
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
        nodes[gi] = relocate(&tasks[t].1[0], block, tasks[t].0);
    }
    // Descendant blocks are disjoint and appear in increasing order: copy them in parallel.
    placed.sort_unstable_by_key(|p| p.1);
    let mut blocks: Vec<(&mut [Node], usize, usize)> = Vec::with_capacity(placed.len());
    let mut rest: &mut [Node] = &mut nodes;
    let mut pos = 0;
    for &(_, block, t) in &placed {
        let len = tasks[t].1.len() - 1;
        let (_, tail) = std::mem::take(&mut rest).split_at_mut(block - pos);
        let (mine, tail) = tail.split_at_mut(len);
        rest = tail;
        pos = block + len;
        blocks.push((mine, block, t));
    }
    blocks.into_par_iter().for_each(|(out, block, t)| {
        let prim0 = tasks[t].0;
        for (o, n) in out.iter_mut().zip(&tasks[t].1[1..]) {
            *o = relocate(n, block, prim0);
        }
    });
    nodes
}

/// The closures and limits of one [`build_nodes_parallel`] run.
struct Driver<'a, R, H, V> {
    vertical_min: usize,
    max_depth: usize,
    horizontal: &'a H,
    vertical: &'a V,
    refs: std::marker::PhantomData<fn(&mut [R])>,
}

/// Rebases a range by `-by` (child ranges into their own slice's frame).
fn shift(r: Range, by: usize) -> Range {
    Range {
        begin: r.begin - by,
        end: r.end - by,
        ..r
    }
}

impl<R: Ref, H, V> Driver<'_, R, H, V>
where
    H: Fn(&mut [R], &mut [bool], &Range) -> Option<(Range, Range)> + Sync,
    V: Fn(&mut [R], &Range) -> Vec<Node> + Sync,
{
    /// The subtree of `r` (rebased to `refs`, whose first primitive is `offset` globally).
    fn subtree(
        &self,
        refs: &mut [R],
        flags: &mut [bool],
        r: Range,
        offset: usize,
        depth: usize,
    ) -> Piece {
        debug_assert!(r.begin == 0 && r.end == refs.len());
        if r.len() < self.vertical_min {
            return Piece {
                skel: vec![Skel::Task(0)],
                tasks: vec![(offset, (self.vertical)(refs, &r))],
            };
        }
        if depth >= self.max_depth {
            return self.horizontal_iterative(refs, flags, r, offset);
        }
        match (self.horizontal)(refs, flags, &r) {
            None => Piece {
                skel: vec![Skel::Leaf {
                    bounds: r.bounds,
                    begin: offset,
                    count: r.len(),
                }],
                tasks: Vec::new(),
            },
            Some((left, right)) => {
                debug_assert!(left.begin == 0 && left.end == right.begin && right.end == r.end);
                let m = left.len();
                let (lr, rr) = refs.split_at_mut(m);
                let (lf, rf) = flags.split_at_mut(m);
                let (pl, pr) = rayon::join(
                    || self.subtree(lr, lf, left, offset, depth + 1),
                    || self.subtree(rr, rf, shift(right, m), offset + m, depth + 1),
                );
                let mut p = Piece {
                    skel: vec![Skel::Task(usize::MAX)],
                    tasks: Vec::new(),
                };
                let left = p.append(pl);
                let right = p.append(pr);
                p.skel[0] = Skel::Inner {
                    bounds: r.bounds,
                    left,
                    right,
                };
                p
            }
        }
    }

    /// The depth-limit fallback: the sequential driver's loop over the large nodes with an explicit
    /// stack (one node at a time, each split by all threads), then the vertical tasks in parallel.
    fn horizontal_iterative(
        &self,
        refs: &mut [R],
        flags: &mut [bool],
        root: Range,
        offset: usize,
    ) -> Piece {
        use rayon::prelude::*;
        let mut skel: Vec<Skel> = vec![Skel::Task(usize::MAX)];
        let mut tasks: Vec<Range> = Vec::new();
        let mut stack: Vec<(usize, Range)> = vec![(0, root)];
        while let Some((si, r)) = stack.pop() {
            if r.len() < self.vertical_min {
                skel[si] = Skel::Task(tasks.len());
                tasks.push(r);
                continue;
            }
            match (self.horizontal)(refs, flags, &r) {
                Some((left, right)) => {
                    let li = skel.len();
                    skel.push(Skel::Task(usize::MAX));
                    skel.push(Skel::Task(usize::MAX));
                    skel[si] = Skel::Inner {
                        bounds: r.bounds,
                        left: li,
                        right: li + 1,
                    };
                    stack.push((li + 1, right));
                    stack.push((li, left));
                }
                None => {
                    skel[si] = Skel::Leaf {
                        bounds: r.bounds,
                        begin: offset + r.begin,
                        count: r.len(),
                    };
                }
            }
        }
        // Left subtrees are expanded first, so tasks come in increasing `begin` order and their
        // ranges are disjoint: carve `refs` into one slice per task.
        let mut jobs: Vec<(&mut [R], Range, usize)> = Vec::with_capacity(tasks.len());
        let mut rest = refs;
        let mut pos = 0;
        for t in &tasks {
            debug_assert!(t.begin >= pos);
            let (_, tail) = std::mem::take(&mut rest).split_at_mut(t.begin - pos);
            let (mine, tail) = tail.split_at_mut(t.len());
            rest = tail;
            pos = t.end;
            jobs.push((mine, shift(*t, t.begin), t.begin));
        }
        let tasks = jobs
            .into_par_iter()
            .map(|(s, r, begin)| (offset + begin, (self.vertical)(s, &r)))
            .collect();
        Piece { skel, tasks }
    }
}
