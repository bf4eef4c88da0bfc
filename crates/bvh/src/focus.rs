//! Focus metrics: how good is the BVH around one object of interest?
//!
//! In scenes where a small object sits beside a far outlier or on a huge ground plane (Riemersma
//! 2024), the whole-tree SAH cost (thesis eq. 4) is dominated by the large structure and hides what
//! happened to the object. The focus cost looks only at the smallest subtree that holds every focus
//! primitive (the lowest common ancestor of their leaves) and normalizes eq. 4 by the surface area
//! of the focus primitives' own bounds: the expected cost of a ray that hits the object's box and
//! starts its traversal at that subtree.
use crate::{Aabb, Bvh, CostParams};

/// `Some((focus primitives, cost))`, or `None` when no primitive is in focus (or the BVH is empty).
///
/// `prim_in_focus[i]` says whether scene primitive `i` belongs to the object; `prim_boxes[i]` is its
/// box. The cost is `(c_T * sum_inner SA + c_I * sum_leaves SA * n) / SA(focus)` over the subtree
/// rooted at the lowest common ancestor of the focus primitives' leaves, where `SA(focus)` is the
/// surface area of the union of the focus primitives' boxes. When that area is zero (a single
/// point-like or line-like object), the subtree root's area is used instead (plain eq. 4 of the
/// subtree); when that is zero too, every node counts as equally likely (ratio 1), the rule
/// `metrics` uses for a zero-area root.
///
/// Iterative (explicit stacks): deep trees from degenerate input cannot overflow the call stack.
/// Malformed trees (child indices out of range, primitive indices outside `prim_in_focus`) are not
/// followed / not counted rather than panicking; `validate` reports them.
pub fn focus_cost(bvh: &Bvh, prim_in_focus: &[bool], prim_boxes: &[Aabb], cost: CostParams) -> Option<(u64, f64)> {
    if bvh.nodes.is_empty() {
        return None;
    }
    let n_nodes = bvh.nodes.len();
    let in_focus = |p: u32| prim_in_focus.get(p as usize).copied().unwrap_or(false);

    // Pre-order from the root; children come after their parent, so a reversed pass sees children
    // first and can sum subtree counts.
    let mut order: Vec<u32> = Vec::with_capacity(n_nodes);
    let mut stack: Vec<u32> = vec![0];
    let mut seen = vec![false; n_nodes];
    while let Some(i) = stack.pop() {
        if seen[i as usize] {
            continue; // malformed (shared child): count each node once
        }
        seen[i as usize] = true;
        order.push(i);
        let n = &bvh.nodes[i as usize];
        if !n.is_leaf() && (n.first as usize) + 1 < n_nodes {
            stack.push(n.first + 1);
            stack.push(n.first);
        }
    }
    let mut count = vec![0u64; n_nodes];
    for &i in order.iter().rev() {
        let n = &bvh.nodes[i as usize];
        count[i as usize] = if n.is_leaf() {
            let lo = (n.first as usize).min(bvh.prim_indices.len());
            let hi = (n.first as usize + n.count as usize).min(bvh.prim_indices.len());
            bvh.prim_indices[lo..hi].iter().filter(|&&p| in_focus(p)).count() as u64
        } else if (n.first as usize) + 1 < n_nodes {
            count[n.first as usize] + count[n.first as usize + 1]
        } else {
            0
        };
    }
    let total = count[0];
    if total == 0 {
        return None;
    }

    // Lowest common ancestor: descend while one child still holds every focus primitive.
    let mut lca = 0u32;
    loop {
        let n = &bvh.nodes[lca as usize];
        if n.is_leaf() || (n.first as usize) + 1 >= n_nodes {
            break;
        }
        if count[n.first as usize] == total {
            lca = n.first;
        } else if count[n.first as usize + 1] == total {
            lca = n.first + 1;
        } else {
            break;
        }
    }

    let mut focus_box = Aabb::EMPTY;
    let mut focus_prims = 0u64;
    for (i, &f) in prim_in_focus.iter().enumerate() {
        if f {
            focus_prims += 1;
            if let Some(b) = prim_boxes.get(i) {
                focus_box.grow(b);
            }
        }
    }
    let focus_sa = focus_box.area_f64();
    let root_sa = bvh.nodes[lca as usize].bounds.area_f64();
    let norm = if focus_sa > 0.0 { focus_sa } else { root_sa };
    let ratio = |sa: f64| if norm > 0.0 { sa / norm } else { 1.0 };

    let (mut inner, mut leaf) = (0.0f64, 0.0f64);
    let mut stack: Vec<u32> = vec![lca];
    let mut visited = vec![false; n_nodes];
    while let Some(i) = stack.pop() {
        if std::mem::replace(&mut visited[i as usize], true) {
            continue;
        }
        let n = &bvh.nodes[i as usize];
        if n.is_leaf() {
            leaf += ratio(n.bounds.area_f64()) * n.count as f64;
        } else {
            inner += ratio(n.bounds.area_f64());
            if (n.first as usize) + 1 < n_nodes {
                stack.push(n.first + 1);
                stack.push(n.first);
            }
        }
    }
    Some((focus_prims, cost.c_t as f64 * inner + cost.c_i as f64 * leaf))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{metrics, Node, Vec3};

    fn bx(x: f32) -> Aabb {
        Aabb::new(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 1.0))
    }

    /// ((p0 p1) (p2 p3)) with unit boxes at x = 0, 1, 10, 11 (area 6 each).
    fn tree() -> (Bvh, Vec<Aabb>) {
        let boxes: Vec<Aabb> = [0.0, 1.0, 10.0, 11.0].iter().map(|&x| bx(x)).collect();
        let u = |a: usize, b: usize| boxes[a].union(&boxes[b]);
        let nodes = vec![
            Node::inner(u(0, 3), 1),
            Node::inner(u(0, 1), 3),
            Node::inner(u(2, 3), 5),
            Node::leaf(boxes[0], 0, 1),
            Node::leaf(boxes[1], 1, 1),
            Node::leaf(boxes[2], 2, 1),
            Node::leaf(boxes[3], 3, 1),
        ];
        (Bvh { nodes, prim_indices: vec![0, 1, 2, 3] }, boxes)
    }

    /// `focus_cost` of `tree()` with the default constants, for the primitives in focus.
    fn focus_of(in_focus: &[bool]) -> (u64, f64) {
        let (bvh, boxes) = tree();
        focus_cost(&bvh, in_focus, &boxes, CostParams::default()).unwrap()
    }

    #[test]
    fn subtree_of_two_leaves() {
        // Focus p2, p3: LCA is node 2 (box 2x1x1, area 10), focus box is the same box.
        let (n, cost) = focus_of(&[false, false, true, true]);
        assert_eq!(n, 2);
        let want = 3.0 * 10.0 / 10.0 + 2.0 * (6.0 + 6.0) / 10.0;
        assert!((cost - want).abs() < 1e-12, "{cost} vs {want}");
        // Focus p3 alone: LCA is its leaf; normalized by its own box: c_I * 1.
        let (n, cost) = focus_of(&[false, false, false, true]);
        assert_eq!((n, cost), (1, 2.0));
    }

    #[test]
    fn split_focus_uses_root_and_focus_area() {
        // p1 and p2 live in different subtrees: LCA is the root; normalized by the union of their
        // boxes (x 1..11: area 2*(10+1+10) = 42), not by the root's (x 0..12: area 50).
        let (n, cost) = focus_of(&[false, true, true, false]);
        assert_eq!(n, 2);
        let inner = 50.0 + 10.0 + 10.0;
        let want = (3.0 * inner + 2.0 * 24.0) / 42.0;
        assert!((cost - want).abs() < 1e-12, "{cost} vs {want}");
        // Every primitive in focus: the focus box is the root box, so this is eq. 4 itself.
        let (_, all) = focus_of(&[true; 4]);
        assert!((all - metrics(&tree().0, CostParams::default()).sah_cost).abs() < 1e-12);
    }

    #[test]
    fn nothing_in_focus_and_empty_tree() {
        let (bvh, boxes) = tree();
        assert_eq!(focus_cost(&bvh, &[false; 4], &boxes, CostParams::default()), None);
        assert_eq!(focus_cost(&bvh, &[], &boxes, CostParams::default()), None);
        assert_eq!(focus_cost(&Bvh::default(), &[true], &boxes, CostParams::default()), None);
    }

    #[test]
    fn zero_area_focus_falls_back_without_dividing_by_zero() {
        // Two point primitives at the same place in one leaf beside a normal box.
        let p = Aabb::from_point(Vec3::new(5.0, 5.0, 5.0));
        let boxes = vec![p, p, bx(0.0)];
        let nodes = vec![Node::inner(p.union(&boxes[2]), 1), Node::leaf(p, 0, 2), Node::leaf(boxes[2], 2, 1)];
        let bvh = Bvh { nodes, prim_indices: vec![0, 1, 2] };
        let (n, cost) = focus_cost(&bvh, &[true, true, false], &boxes, CostParams::default()).unwrap();
        // Focus and LCA both have zero area: ratio 1, so c_I * 2.
        assert_eq!((n, cost), (2, 4.0));
        // A point-like focus in a leaf with area: normalized by that leaf's area (ratio 1 for it).
        let q = Aabb::from_point(Vec3::new(-5.0, 0.0, 0.0));
        let boxes = vec![p, q, bx(0.0)];
        let l0 = p.union(&boxes[2]);
        let nodes = vec![Node::inner(l0.union(&q), 1), Node::leaf(l0, 0, 2), Node::leaf(q, 2, 1)];
        let bvh = Bvh { nodes, prim_indices: vec![0, 2, 1] };
        let (n, cost) = focus_cost(&bvh, &[true, false, false], &boxes, CostParams::default()).unwrap();
        assert_eq!((n, cost), (1, 4.0));
    }

    #[test]
    fn deep_chain_does_not_overflow() {
        // A caterpillar of 200k leaves (depth 200k), focus on the deepest one.
        let n = 200_000usize;
        let boxes: Vec<Aabb> = (0..n).map(|i| bx(i as f32)).collect();
        let mut nodes = Vec::with_capacity(2 * n);
        nodes.push(Node::inner(Aabb::EMPTY, 1));
        for i in 0..n - 1 {
            // children of the current inner node: leaf i, then the next inner node (or the last leaf)
            let leaf = Node::leaf(boxes[i], i as u32, 1);
            let next = if i + 1 == n - 1 {
                Node::leaf(boxes[n - 1], (n - 1) as u32, 1)
            } else {
                Node::inner(Aabb::EMPTY, nodes.len() as u32 + 2)
            };
            nodes.push(leaf);
            nodes.push(next);
        }
        let bvh = Bvh { nodes, prim_indices: (0..n as u32).collect() };
        let mut focus = vec![false; n];
        focus[n - 1] = true;
        let (k, cost) = focus_cost(&bvh, &focus, &boxes, CostParams::default()).unwrap();
        assert_eq!((k, cost), (1, 2.0));
    }
}
