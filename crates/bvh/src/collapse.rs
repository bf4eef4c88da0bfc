//! SAH compaction (subtree collapse), Bittner et al. 2013 section 3.6, Frantal 2019 section 3.4.4.
use crate::{Bvh, CostParams, Node};

/// Post-order: replace a subtree by one leaf holding all its primitives when the leaf's cost
/// c_I * SA(N) * t(N) is lower than the subtree's cost (c_T * SA(N) + cost of both children; the
/// unnormalized form of thesis eq. 2-3, so the comparison needs no division). Collapsing can happen
/// repeatedly up a branch, as the thesis notes. Works on any BVH. Returns a compacted copy whose
/// nodes are renumbered depth-first with siblings adjacent and whose leaf ranges are contiguous in
/// traversal order.
pub fn collapse(bvh: &Bvh, cost: CostParams) -> Bvh {
    let n = bvh.nodes.len();
    if n == 0 {
        return bvh.clone();
    }
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
    for &i in order.iter().rev() {
        let nd = &bvh.nodes[i as usize];
        let sa = nd.bounds.area_f64();
        let i = i as usize;
        if nd.is_leaf() {
            count[i] = nd.count;
            sub_cost[i] = c_i * sa * nd.count as f64;
            make_leaf[i] = true;
        } else {
            let (l, r) = (nd.first as usize, nd.first as usize + 1);
            count[i] = count[l] + count[r];
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
            out.nodes[slot as usize] = Node::leaf(nd.bounds, first, count[old as usize]);
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
