//! SAH compaction (subtree collapse), Bittner et al. 2013 section 3.6, Frantal 2019 section 3.4.4.
use crate::{Aabb, Bvh, CostParams, Node};

/// Post-order: replace a subtree by one leaf holding all its primitives when the leaf's cost
/// c_I * SA(N) * t(N) is lower than the subtree's cost (c_T * SA(N) + cost of both children; the
/// unnormalized form of thesis eq. 2-3, so the comparison needs no division). Collapsing can happen
/// repeatedly up a branch, as the thesis notes. Works on any BVH. Returns a compacted copy whose
/// nodes are renumbered depth-first with siblings adjacent and whose leaf ranges are contiguous in
/// traversal order.
///
/// A BVH with repeated references (SBVH, Stich et al. 2009: a triangle clipped into several
/// leaves) collapses too: a collapsed leaf holds each triangle once (its box, the subtree's, covers
/// every clipped part), and its cost counts distinct triangles (exactly for subtrees of up to
/// [`DISTINCT_CAP`] references, else their reference count, an upper bound: such subtrees collapse
/// slightly less eagerly, never wrongly).
pub fn collapse(bvh: &Bvh, cost: CostParams) -> Bvh {
    if bvh.nodes.is_empty() {
        return bvh.clone();
    }
    collapse_from(&mut Stored(bvh), has_repeats(&bvh.prim_indices), cost)
}

/// A binary tree as [`collapse_from`] reads it: node ids, boxes, children and leaf primitives. The
/// Morton builders give theirs as a cluster tree (`bvhlab_builders::bottomup`) without laying out a
/// [`Bvh`] of single-triangle leaves first: that layout (64 bytes per triangle) beside the compacted
/// copy was their memory peak (issue 19.4).
pub trait CollapseSource {
    /// Ids are `0..id_count()`.
    fn id_count(&self) -> usize;
    fn root(&self) -> u32;
    /// `Some([left, right])` for an inner node, `None` for a leaf.
    fn children(&self, id: u32) -> Option<[u32; 2]>;
    /// A leaf's primitives, left to right.
    fn prims(&self, id: u32) -> &[u32];
    /// The primitive references of all leaves.
    fn reference_count(&self) -> usize;
    /// A node's box; an inner node's only after its [`CollapseSource::refit`].
    fn bounds(&self, id: u32) -> Aabb;
    /// An inner node's box, given its children's: called once per inner node, after its
    /// children's, before any [`CollapseSource::bounds`] of it. A source with stored boxes returns
    /// its own; a cluster tree keeps the union.
    fn refit(&mut self, id: u32, left: &Aabb, right: &Aabb) -> Aabb;
}

/// A [`Bvh`] as a collapse source: its stored boxes.
struct Stored<'a>(&'a Bvh);

impl CollapseSource for Stored<'_> {
    fn id_count(&self) -> usize {
        self.0.nodes.len()
    }
    fn root(&self) -> u32 {
        0
    }
    fn children(&self, id: u32) -> Option<[u32; 2]> {
        let nd = &self.0.nodes[id as usize];
        (!nd.is_leaf()).then_some([nd.first, nd.first + 1])
    }
    fn prims(&self, id: u32) -> &[u32] {
        let nd = &self.0.nodes[id as usize];
        &self.0.prim_indices[nd.first as usize..(nd.first + nd.count) as usize]
    }
    fn reference_count(&self) -> usize {
        self.0.prim_indices.len()
    }
    fn bounds(&self, id: u32) -> Aabb {
        self.0.nodes[id as usize].bounds
    }
    fn refit(&mut self, id: u32, _: &Aabb, _: &Aabb) -> Aabb {
        self.0.nodes[id as usize].bounds
    }
}

/// [`collapse`] of any non-empty tree: the output depends only on the tree (shape, left/right
/// order, boxes, primitives), not on its ids, so a source gives the same bytes as its [`Bvh`]
/// layout. `repeats`: some triangle is referenced twice ([`has_repeats`]).
pub fn collapse_from<S: CollapseSource + ?Sized>(src: &mut S, repeats: bool, cost: CostParams) -> Bvh {
    let n = src.id_count();
    let (c_t, c_i) = (cost.c_t as f64, cost.c_i as f64);
    // Post-order over an explicit stack (children's indices need not exceed their parent's); a
    // finished subtree's box, cost, primitive count, output node count and (repeated references)
    // distinct triangles wait on a value stack for its parent, so the only per-node array is the
    // decision: the work memory is a byte per node plus two stacks as deep as the tree, not the 17
    // bytes per node of per-node costs, counts and order (the peak of the Morton builders, which
    // collapse a tree of single-triangle leaves: issue 19.4).
    struct Val {
        bounds: Aabb,
        cost: f64,
        count: u32,
        /// Nodes of the subtree's output (1 when it becomes a leaf).
        out: usize,
        distinct: Option<Vec<u32>>,
    }
    let mut make_leaf = vec![false; n];
    let mut todo = vec![(src.root(), false)];
    let mut vals: Vec<Val> = Vec::new();
    while let Some((i, expanded)) = todo.pop() {
        match src.children(i) {
            None => {
                make_leaf[i as usize] = true;
                let bounds = src.bounds(i);
                let prims = src.prims(i);
                let distinct = repeats.then(|| {
                    let mut v = prims.to_vec();
                    v.sort_unstable();
                    v
                });
                let count = prims.len() as u32;
                vals.push(Val { bounds, cost: c_i * bounds.area_f64() * count as f64, count, out: 1, distinct });
            }
            Some([l, r]) if !expanded => {
                // The left child's value ends up below the right one's.
                todo.push((i, true));
                todo.push((r, false));
                todo.push((l, false));
            }
            Some(_) => {
                let (Some(vr), Some(vl)) = (vals.pop(), vals.pop()) else {
                    unreachable!("an expanded node's two children were finished before it")
                };
                let bounds = src.refit(i, &vl.bounds, &vr.bounds);
                let sa = bounds.area_f64();
                let mut count = vl.count + vr.count;
                let mut distinct = None;
                if let (Some(a), Some(b)) = (vl.distinct, vr.distinct) {
                    let m = merge_distinct(&a, &b);
                    count = m.len() as u32;
                    if m.len() <= DISTINCT_CAP {
                        distinct = Some(m);
                    }
                }
                let as_inner = c_t * sa + vl.cost + vr.cost;
                let as_leaf = c_i * sa * count as f64;
                let (cost, out) = if as_leaf < as_inner {
                    make_leaf[i as usize] = true;
                    (as_leaf, 1)
                } else {
                    (as_inner, 1 + vl.out + vr.out)
                };
                vals.push(Val { bounds, cost, count, out, distinct });
            }
        }
    }
    // The output's size, so its arrays are allocated once and exactly.
    let out_nodes = vals.pop().map_or(1, |v| v.out);
    let placeholder = Node { bounds: Aabb::EMPTY, first: 0, count: 0 };
    let mut out = Bvh { nodes: Vec::with_capacity(out_nodes), prim_indices: Vec::with_capacity(src.reference_count()) };
    out.nodes.push(placeholder);
    // (source id, output slot); every slot pushed is assigned when its entry is popped.
    let mut work = vec![(src.root(), 0u32)];
    let mut gather = Vec::new();
    while let Some((id, slot)) = work.pop() {
        let bounds = src.bounds(id);
        if make_leaf[id as usize] {
            let first = out.prim_indices.len() as u32;
            // Gather the subtree's primitives left to right.
            gather.clear();
            gather.push(id);
            while let Some(g) = gather.pop() {
                match src.children(g) {
                    None => out.prim_indices.extend_from_slice(src.prims(g)),
                    Some([l, r]) => {
                        gather.push(r);
                        gather.push(l);
                    }
                }
            }
            if repeats {
                // Keep each triangle's first reference (left to right).
                let mut seen = std::collections::HashSet::new();
                let mut k = first as usize;
                for j in first as usize..out.prim_indices.len() {
                    let p = out.prim_indices[j];
                    if seen.insert(p) {
                        out.prim_indices[k] = p;
                        k += 1;
                    }
                }
                out.prim_indices.truncate(k);
            }
            let count = out.prim_indices.len() as u32 - first;
            out.nodes[slot as usize] = Node::leaf(bounds, first, count);
        } else {
            let Some([l, r]) = src.children(id) else {
                unreachable!("a leaf is always kept as a leaf")
            };
            let left = out.nodes.len() as u32;
            out.nodes.push(placeholder);
            out.nodes.push(placeholder);
            out.nodes[slot as usize] = Node::inner(bounds, left);
            // Right pushed first so the left subtree is emitted first (depth-first order).
            work.push((r, left + 1));
            work.push((l, left));
        }
    }
    debug_assert_eq!(out.nodes.len(), out_nodes);
    if repeats {
        // Collapsed leaves keep each triangle once: fewer references than the input's.
        out.prim_indices.shrink_to_fit();
    }
    out
}

/// Subtrees with more references than this keep their reference count as the collapse count
/// (see [`collapse`]); sets up to it are merged exactly.
pub const DISTINCT_CAP: usize = 4096;

/// Whether some triangle index occurs twice (only the SBVH builds such trees).
pub fn has_repeats(prims: &[u32]) -> bool {
    let max = prims.iter().copied().max().map_or(0, |m| m as usize + 1);
    let mut seen = vec![false; max];
    prims.iter().any(|&p| std::mem::replace(&mut seen[p as usize], true))
}

/// The sorted union of two sorted sets.
fn merge_distinct(a: &[u32], b: &[u32]) -> Vec<u32> {
    let mut out = Vec::with_capacity(a.len() + b.len());
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        match a[i].cmp(&b[j]) {
            std::cmp::Ordering::Less => {
                out.push(a[i]);
                i += 1;
            }
            std::cmp::Ordering::Greater => {
                out.push(b[j]);
                j += 1;
            }
            std::cmp::Ordering::Equal => {
                out.push(a[i]);
                i += 1;
                j += 1;
            }
        }
    }
    out.extend_from_slice(&a[i..]);
    out.extend_from_slice(&b[j..]);
    out
}
