//! SAH compaction (subtree collapse), Bittner et al. 2013 section 3.6, Frantal 2019 section 3.4.4.
use crate::{Bvh, CostParams, Node};

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
    let n = bvh.nodes.len();
    if n == 0 {
        return bvh.clone();
    }
    let repeats = has_repeats(&bvh.prim_indices);
    let (c_t, c_i) = (cost.c_t as f64, cost.c_i as f64);
    // Post-order over an explicit stack (children's indices need not exceed their parent's); a
    // finished subtree's cost, primitive count and (repeated references) distinct triangles wait
    // on a value stack for its parent, so the only per-node array is the decision: the work memory
    // is a byte per node plus two stacks as deep as the tree, not the 17 bytes per node of
    // per-node costs, counts and order (the peak of the Morton builders, which collapse a tree of
    // single-triangle leaves: issue 19.4).
    let mut make_leaf = vec![false; n];
    let mut todo = vec![(0u32, false)];
    let mut vals: Vec<(f64, u32, Option<Vec<u32>>)> = Vec::new();
    while let Some((i, expanded)) = todo.pop() {
        let nd = &bvh.nodes[i as usize];
        let sa = nd.bounds.area_f64();
        let i = i as usize;
        if nd.is_leaf() {
            make_leaf[i] = true;
            let distinct = repeats.then(|| {
                let mut v = bvh.prim_indices[nd.first as usize..(nd.first + nd.count) as usize].to_vec();
                v.sort_unstable();
                v
            });
            vals.push((c_i * sa * nd.count as f64, nd.count, distinct));
        } else if !expanded {
            // The left child's value ends up below the right one's.
            todo.push((i as u32, true));
            todo.push((nd.first + 1, false));
            todo.push((nd.first, false));
        } else {
            let (Some((cost_r, count_r, dist_r)), Some((cost_l, count_l, dist_l))) = (vals.pop(), vals.pop()) else {
                unreachable!("an expanded node's two children were finished before it")
            };
            let mut count = count_l + count_r;
            let mut distinct = None;
            if let (Some(a), Some(b)) = (dist_l, dist_r) {
                let m = merge_distinct(&a, &b);
                count = m.len() as u32;
                if m.len() <= DISTINCT_CAP {
                    distinct = Some(m);
                }
            }
            let as_inner = c_t * sa + cost_l + cost_r;
            let as_leaf = c_i * sa * count as f64;
            let sub_cost = if as_leaf < as_inner {
                make_leaf[i] = true;
                as_leaf
            } else {
                as_inner
            };
            vals.push((sub_cost, count, distinct));
        }
    }

    // The output's size, so its arrays are allocated once and exactly: the root and both children
    // of every inner node kept (an inner node none of whose ancestors became a leaf).
    let mut out_nodes = 1usize;
    let mut walk = vec![0u32];
    while let Some(i) = walk.pop() {
        let nd = &bvh.nodes[i as usize];
        if !make_leaf[i as usize] {
            out_nodes += 2;
            walk.push(nd.first);
            walk.push(nd.first + 1);
        }
    }
    let mut out = Bvh { nodes: Vec::with_capacity(out_nodes), prim_indices: Vec::with_capacity(bvh.prim_indices.len()) };
    out.nodes.push(bvh.nodes[0]);
    // (old node, new slot)
    let mut work = vec![(0u32, 0u32)];
    let mut gather = Vec::new();
    while let Some((old, slot)) = work.pop() {
        let nd = bvh.nodes[old as usize];
        if make_leaf[old as usize] {
            let first = out.prim_indices.len() as u32;
            // Gather the subtree's primitives left to right.
            gather.clear();
            gather.push(old);
            while let Some(g) = gather.pop() {
                let gn = &bvh.nodes[g as usize];
                if gn.is_leaf() {
                    let (a, b) = (gn.first as usize, (gn.first + gn.count) as usize);
                    out.prim_indices.extend_from_slice(&bvh.prim_indices[a..b]);
                } else {
                    gather.push(gn.first + 1);
                    gather.push(gn.first);
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
            out.nodes[slot as usize] = Node::leaf(nd.bounds, first, count);
        } else {
            let left = out.nodes.len() as u32;
            out.nodes.push(bvh.nodes[nd.first as usize]);
            out.nodes.push(bvh.nodes[nd.first as usize + 1]);
            out.nodes[slot as usize] = Node::inner(nd.bounds, left);
            // Right pushed first so the left subtree is emitted first (depth-first order).
            work.push((nd.first + 1, left + 1));
            work.push((nd.first, left));
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
