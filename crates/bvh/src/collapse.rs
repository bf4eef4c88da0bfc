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
    // Children always have larger indices than parents in every layout we produce? Not guaranteed
    // for all layouts, so compute a post-order explicitly.
    let mut order = Vec::with_capacity(n);
    let mut stack = vec![0u32];
    while let Some(i) = stack.pop() {
        order.push(i);
        let nd = &bvh.nodes[i as usize];
        if !nd.is_leaf() {
            stack.push(nd.first);
            stack.push(nd.first + 1);
        }
    }
    let mut sub_cost = vec![0f64; n];
    let mut count = vec![0u32; n];
    let mut make_leaf = vec![false; n];
    // Repeated references: the sorted distinct triangles of each subtree (small subtrees only),
    // dropped once the parent has merged them.
    let mut distinct: Vec<Option<Vec<u32>>> = if repeats { vec![None; n] } else { Vec::new() };
    for &i in order.iter().rev() {
        let nd = &bvh.nodes[i as usize];
        let sa = nd.bounds.area_f64();
        let i = i as usize;
        if nd.is_leaf() {
            count[i] = nd.count;
            sub_cost[i] = c_i * sa * nd.count as f64;
            make_leaf[i] = true;
            if repeats {
                let mut v = bvh.prim_indices[nd.first as usize..(nd.first + nd.count) as usize].to_vec();
                v.sort_unstable();
                distinct[i] = Some(v);
            }
        } else {
            let (l, r) = (nd.first as usize, nd.first as usize + 1);
            count[i] = count[l] + count[r];
            if repeats {
                if let (Some(a), Some(b)) = (distinct[l].take(), distinct[r].take()) {
                    let m = merge_distinct(&a, &b);
                    count[i] = m.len() as u32;
                    if m.len() <= DISTINCT_CAP {
                        distinct[i] = Some(m);
                    }
                }
            }
            let as_inner = c_t * sa + sub_cost[l] + sub_cost[r];
            let as_leaf = c_i * sa * count[i] as f64;
            if as_leaf < as_inner {
                make_leaf[i] = true;
                sub_cost[i] = as_leaf;
            } else {
                sub_cost[i] = as_inner;
            }
        }
    }

    let mut out = Bvh { nodes: Vec::with_capacity(n), prim_indices: Vec::with_capacity(bvh.prim_indices.len()) };
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
