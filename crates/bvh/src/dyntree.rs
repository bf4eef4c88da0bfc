//! A binary BVH that can be edited in place: nodes with explicit child links, and the parent array
//! kept beside them (thesis 3.4.2: "we store the indices in a separate array" so the 32-byte node
//! stays a power of two). The optimizers and the incremental builder work on this; the flat
//! [`Bvh`] (sibling pairs adjacent) is the exchange format with the rest of the pipeline.
//!
//! Invariants (checked by [`DynTree::check`]): `root` has parent [`NONE`]; every inner node's
//! children have it as parent; every leaf's primitives are `prims[first..first + count]`; inner
//! boxes are the union of their children's boxes after every public operation that promises a refit.
//! Node slots are never reused for a different role implicitly: a removed node is relinked by the
//! caller (Bittner 2013 reuses N and P to link the reinserted nodes), so the node count is constant.
use crate::{Aabb, Bvh, CostParams, Node};

/// "No node": the root's parent.
pub const NONE: u32 = u32::MAX;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DNode {
    pub bounds: Aabb,
    /// Inner node: the two children. Leaf: unused ([`NONE`]).
    pub left: u32,
    pub right: u32,
    /// Leaf: primitives `prims[first..first + count]`, `count > 0`. Inner node: `count == 0`.
    pub first: u32,
    pub count: u32,
}

impl DNode {
    #[inline]
    pub fn is_leaf(&self) -> bool {
        self.count > 0
    }
    #[inline]
    pub fn leaf(bounds: Aabb, first: u32, count: u32) -> DNode {
        DNode { bounds, left: NONE, right: NONE, first, count }
    }
    #[inline]
    pub fn inner(bounds: Aabb, left: u32, right: u32) -> DNode {
        DNode { bounds, left, right, first: 0, count: 0 }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct DynTree {
    pub nodes: Vec<DNode>,
    /// `parent[i]` of node `i`; [`NONE`] for the root.
    pub parent: Vec<u32>,
    /// Leaf primitive slots (scene triangle indices), as in `Bvh::prim_indices`.
    pub prims: Vec<u32>,
    pub root: u32,
}

impl DynTree {
    /// Takes over a flat BVH: node `i` keeps index `i`, so `from_bvh(b).to_bvh() == b` for a BVH in
    /// depth-first, left-first layout (what every builder emits).
    pub fn from_bvh(bvh: &Bvh) -> DynTree {
        let n = bvh.nodes.len();
        let mut nodes = Vec::with_capacity(n);
        let mut parent = vec![NONE; n];
        for (i, node) in bvh.nodes.iter().enumerate() {
            if node.is_leaf() {
                nodes.push(DNode::leaf(node.bounds, node.first, node.count));
            } else {
                let l = node.first;
                nodes.push(DNode::inner(node.bounds, l, l + 1));
                parent[l as usize] = i as u32;
                parent[l as usize + 1] = i as u32;
            }
        }
        DynTree { nodes, parent, prims: bvh.prim_indices.clone(), root: if n == 0 { NONE } else { 0 } }
    }

    /// Lays the tree out as a flat [`Bvh`]: root at 0, depth-first, left subtree first, sibling
    /// pairs adjacent, leaf primitives renumbered in visit order. Iterative (degenerate trees can be
    /// as deep as the primitive count). The output depends only on the tree's topology and boxes,
    /// never on which slots the nodes occupy, so equal trees give equal bytes.
    pub fn to_bvh(&self) -> Bvh {
        if self.root == NONE {
            return Bvh::default();
        }
        let reachable = self.nodes.len();
        let mut nodes: Vec<Node> = Vec::with_capacity(reachable);
        let mut prim_indices = Vec::with_capacity(self.prims.len());
        nodes.push(Node { bounds: Aabb::EMPTY, first: 0, count: 0 });
        // (tree node, output slot)
        let mut stack: Vec<(u32, usize)> = vec![(self.root, 0)];
        while let Some((id, slot)) = stack.pop() {
            let d = &self.nodes[id as usize];
            if d.is_leaf() {
                let first = prim_indices.len() as u32;
                prim_indices.extend_from_slice(&self.prims[d.first as usize..(d.first + d.count) as usize]);
                nodes[slot] = Node::leaf(d.bounds, first, d.count);
            } else {
                let li = nodes.len();
                nodes.push(Node { bounds: Aabb::EMPTY, first: 0, count: 0 });
                nodes.push(Node { bounds: Aabb::EMPTY, first: 0, count: 0 });
                nodes[slot] = Node::inner(d.bounds, li as u32);
                stack.push((d.right, li + 1));
                stack.push((d.left, li));
            }
        }
        Bvh { nodes, prim_indices }
    }

    #[inline]
    pub fn is_leaf(&self, n: u32) -> bool {
        self.nodes[n as usize].is_leaf()
    }

    #[inline]
    pub fn bounds(&self, n: u32) -> &Aabb {
        &self.nodes[n as usize].bounds
    }

    /// The other child of `n`'s parent; [`NONE`] for the root.
    #[inline]
    pub fn sibling(&self, n: u32) -> u32 {
        let p = self.parent[n as usize];
        if p == NONE {
            return NONE;
        }
        let pn = &self.nodes[p as usize];
        if pn.left == n {
            pn.right
        } else {
            pn.left
        }
    }

    /// Makes `new` the child of `parent` in place of `old` (and sets `new`'s parent link).
    /// `parent == NONE` makes `new` the root.
    #[inline]
    pub fn replace_child(&mut self, parent: u32, old: u32, new: u32) {
        if parent == NONE {
            self.root = new;
        } else {
            let p = &mut self.nodes[parent as usize];
            if p.left == old {
                p.left = new;
            } else {
                debug_assert_eq!(p.right, old, "replace_child: {old} is not a child of {parent}");
                p.right = new;
            }
        }
        self.parent[new as usize] = parent;
    }

    /// Makes `l` and `r` the children of inner node `n` (parent links set, box recomputed).
    #[inline]
    pub fn set_children(&mut self, n: u32, l: u32, r: u32) {
        let b = self.nodes[l as usize].bounds.union(&self.nodes[r as usize].bounds);
        self.nodes[n as usize] = DNode::inner(b, l, r);
        self.parent[l as usize] = n;
        self.parent[r as usize] = n;
    }

    /// Recomputes the boxes of `n` (if inner) and every ancestor up to the root.
    pub fn refit_up(&mut self, mut n: u32) {
        while n != NONE {
            let d = self.nodes[n as usize];
            if !d.is_leaf() {
                let b = self.nodes[d.left as usize].bounds.union(&self.nodes[d.right as usize].bounds);
                self.nodes[n as usize].bounds = b;
            }
            n = self.parent[n as usize];
        }
    }

    /// Like [`DynTree::refit_up`], but stops at the first ancestor whose box does not change: its
    /// own ancestors were consistent with that box before, so they still are. Exact (boxes are
    /// unions, min/max have no rounding), and what makes one reinsertion cheaper than a walk to
    /// the root on deep trees.
    pub fn refit_up_until_stable(&mut self, mut n: u32) {
        while n != NONE {
            let d = self.nodes[n as usize];
            if !d.is_leaf() {
                let b = self.nodes[d.left as usize].bounds.union(&self.nodes[d.right as usize].bounds);
                if b == d.bounds {
                    return;
                }
                self.nodes[n as usize].bounds = b;
            }
            n = self.parent[n as usize];
        }
    }

    /// Indices of the inner nodes reachable from the root, in index order.
    pub fn inner_nodes(&self) -> Vec<u32> {
        let mut reach = vec![false; self.nodes.len()];
        if self.root != NONE {
            let mut stack = vec![self.root];
            while let Some(n) = stack.pop() {
                reach[n as usize] = true;
                let d = &self.nodes[n as usize];
                if !d.is_leaf() {
                    stack.push(d.left);
                    stack.push(d.right);
                }
            }
        }
        (0..self.nodes.len() as u32).filter(|&i| reach[i as usize] && !self.is_leaf(i)).collect()
    }

    /// SAH cost, thesis eq. 4, exactly as `bvhlab_bvh::metrics` computes it (f64 sums, the same
    /// convention for a zero-area root), without laying the tree out.
    pub fn sah_cost(&self, cost: CostParams) -> f64 {
        if self.root == NONE {
            return 0.0;
        }
        let root_sa = self.nodes[self.root as usize].bounds.area_f64();
        let degenerate = !(root_sa > 0.0);
        let ratio = |sa: f64| if degenerate { 1.0 } else { sa / root_sa };
        let (mut inner, mut leaf) = (0.0f64, 0.0f64);
        let mut stack = vec![self.root];
        while let Some(n) = stack.pop() {
            let d = &self.nodes[n as usize];
            if d.is_leaf() {
                leaf += ratio(d.bounds.area_f64()) * d.count as f64;
            } else {
                inner += ratio(d.bounds.area_f64());
                stack.push(d.left);
                stack.push(d.right);
            }
        }
        cost.c_t as f64 * inner + cost.c_i as f64 * leaf
    }

    /// Structural check (for tests and debug assertions): parent links, reachability of every node
    /// exactly once, children inside parents. `Err` names the first violation.
    pub fn check(&self) -> Result<(), String> {
        if self.root == NONE {
            return if self.nodes.is_empty() { Ok(()) } else { Err("no root".into()) };
        }
        if self.parent[self.root as usize] != NONE {
            return Err(format!("root {} has parent {}", self.root, self.parent[self.root as usize]));
        }
        let mut seen = vec![false; self.nodes.len()];
        let mut stack = vec![self.root];
        while let Some(n) = stack.pop() {
            if std::mem::replace(&mut seen[n as usize], true) {
                return Err(format!("node {n} reached twice"));
            }
            let d = &self.nodes[n as usize];
            if d.is_leaf() {
                if (d.first + d.count) as usize > self.prims.len() {
                    return Err(format!("leaf {n} primitive range out of bounds"));
                }
                continue;
            }
            for c in [d.left, d.right] {
                if c as usize >= self.nodes.len() {
                    return Err(format!("node {n} has child {c} out of range"));
                }
                if self.parent[c as usize] != n {
                    return Err(format!("child {c} of {n} has parent {}", self.parent[c as usize]));
                }
                if !d.bounds.contains(&self.nodes[c as usize].bounds) {
                    return Err(format!("child {c} not inside its parent {n}"));
                }
            }
            stack.push(d.left);
            stack.push(d.right);
        }
        if let Some(i) = seen.iter().position(|s| !s) {
            return Err(format!("node {i} unreachable"));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Vec3;

    fn four() -> Bvh {
        // ((p0, p1), (p2, p3)) in depth-first layout.
        let b = |i: f32| Aabb::new(Vec3::splat(i), Vec3::splat(i + 0.5));
        let u = |a: Aabb, c: Aabb| a.union(&c);
        let nodes = vec![
            Node::inner(u(b(0.0), b(3.0)), 1),
            Node::inner(u(b(0.0), b(1.0)), 3),
            Node::inner(u(b(2.0), b(3.0)), 5),
            Node::leaf(b(0.0), 0, 1),
            Node::leaf(b(1.0), 1, 1),
            Node::leaf(b(2.0), 2, 1),
            Node::leaf(b(3.0), 3, 1),
        ];
        Bvh { nodes, prim_indices: vec![0, 1, 2, 3] }
    }

    #[test]
    fn round_trip_and_cost() {
        let bvh = four();
        let t = DynTree::from_bvh(&bvh);
        t.check().unwrap();
        // Layout differs from the builder's (breadth-first pairs) but the tree is the same.
        let back = t.to_bvh();
        let c = CostParams::default();
        assert!((t.sah_cost(c) - crate::metrics(&bvh, c).sah_cost).abs() < 1e-9);
        assert!((crate::metrics(&back, c).sah_cost - crate::metrics(&bvh, c).sah_cost).abs() < 1e-9);
        assert_eq!(DynTree::from_bvh(&back).to_bvh(), back);
        assert_eq!(t.inner_nodes(), vec![0, 1, 2]);
        assert_eq!(t.sibling(3), 4);
        assert_eq!(t.sibling(0), NONE);
    }

    #[test]
    fn relink_and_refit() {
        let mut t = DynTree::from_bvh(&four());
        // Move leaf 6 (p3) next to leaf 3 (p0): detach 6 (its parent 2 is freed, sibling 5 takes
        // 2's place), then reuse 2 to link 3 and 6.
        let (p, s, g) = (2u32, 5u32, 0u32);
        t.replace_child(g, p, s);
        t.refit_up(g);
        let gp = t.parent[3];
        t.replace_child(gp, 3, p);
        t.set_children(p, 3, 6);
        t.refit_up(p);
        t.check().unwrap();
        let b = t.to_bvh();
        crate::validate(&b, &(0..4).map(|i| Aabb::new(Vec3::splat(i as f32), Vec3::splat(i as f32 + 0.5))).collect::<Vec<_>>()).unwrap();
    }
}
