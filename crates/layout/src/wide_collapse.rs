//! SAH-optimal collapse of a binary BVH into a `W`-wide one: the dynamic programme of Ylitie,
//! Karras and Laine 2017 ("Efficient incoherent ray traversal on GPUs through compressed wide
//! BVHs", section 3.1), with bvhlab's leaves (a binary leaf, or a binary subtree of at most
//! [`LEAF_BLOCK`](crate::wide::LEAF_BLOCK) references combined into one leaf, tested four triangles at a time).
//!
//! For every binary node `n` and `i` in `1..=W`, `cost(n, i)` is the least SAH cost of the part of
//! the tree below `n` represented as at most `i` subtrees that become children of one wide node:
//! - `cost(n, 1) = min(leaf(n), c_node SA(n) + dist(n, W))`: `n` is one child, a leaf or a wide
//!   node whose `W` slots are shared out among `n`'s two children;
//! - `cost(n, i) = min(cost(n, i - 1), dist(n, i))` for `i >= 2`;
//! - `dist(n, j) = min over k in 1..j of cost(l, k) + cost(r, j - k)`.
//!
//! `leaf(n) = c_leaf SA(n) ceil(refs / 4)` (one four-wide triangle test per four references) where
//! a leaf is allowed, else infinite; a binary leaf cannot be opened, so all its costs are its leaf
//! cost. Ylitie et al. also let the programme form leaves of any subtree up to its triangle limit;
//! here the limit is `max_leaf` (the combined leaf's `LEAF_BLOCK`, 4, by default, as in the greedy
//! collapse). The root is always a wide node (its box is tested before the traversal's first
//! step): its cost is `c_node SA(root)` plus the cheaper of its one leaf child and `dist(root, W)`.
//! An SBVH subtree may hold two fragments of one triangle; a combined leaf keeps it once, so the
//! programme's leaf cost (per reference) may overstate such a leaf: its choice is then optimal
//! for the reference counts, not exactly for the stored leaves.
use bvhlab_bvh::{Bvh, Node};

/// The decisions of the programme: per binary node and `i`, `choice[n * W + i - 1]`:
/// - `i = 1`: 0 = leaf, `k >= 1` = wide node whose slots go `k` to the left child, `W - k` right;
/// - `i >= 2`: 0 = as `i - 1`, `k >= 1` = `k` subtrees from the left child, `i - k` from the right.
pub(crate) struct Optimal {
    width: usize,
    choice: Vec<u8>,
    /// Least cost of the whole tree (`cost(root, 1)`), in the units of the weights given.
    cost: f64,
}

/// 1 / the root's area (areas relative to the root's are scale-free: in f32, a scene at 1e-30 or
/// 1e30 would underflow or overflow its raw areas and tie or break every comparison), or 1 when the
/// root has no finite positive area.
pub(crate) fn area_norm(nodes: &[Node]) -> f64 {
    let a = nodes.first().map_or(0.0, |r| r.bounds.area());
    if a > 0.0 && a.is_finite() {
        1.0 / a
    } else {
        1.0
    }
}

/// Weights of the programme's cost: a wide node entered, a four-triangle leaf test.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CollapseCost {
    pub c_node: f32,
    pub c_leaf: f32,
    /// Largest binary subtree (references) that may become one leaf.
    pub max_leaf: u32,
    /// Triangles per leaf test: `c_leaf` is paid per started `block` (4: the four-wide test; 1:
    /// per triangle, as the SAH cost of eq. 4).
    pub block: u32,
}

impl Optimal {
    /// Runs the programme bottom-up over `nodes` (children after their parent in `order`, a
    /// pre-order of the tree; `refs` the references below each node).
    pub(crate) fn plan(nodes: &[Node], order: &[usize], refs: &[u32], width: usize, w: CollapseCost) -> Optimal {
        assert!((2..=8).contains(&width));
        let n = nodes.len();
        let mut cost = vec![f32::INFINITY; n * width];
        let mut choice = vec![0u8; n * width];
        let norm = area_norm(nodes);
        for &b in order.iter().rev() {
            let nd = &nodes[b];
            let sa = (nd.bounds.area() * norm) as f32;
            let leaf_ok = nd.is_leaf() || refs[b] <= w.max_leaf;
            let leaf = if leaf_ok { w.c_leaf * sa * refs[b].div_ceil(w.block).max(1) as f32 } else { f32::INFINITY };
            let at = b * width;
            if nd.is_leaf() {
                cost[at..at + width].fill(leaf);
                if b == 0 {
                    cost[at] = w.c_node * sa + leaf;
                }
                continue;
            }
            let (l, r) = (nd.first as usize * width, (nd.first as usize + 1) * width);
            let (mut cl, mut cr) = ([0f32; 8], [0f32; 8]);
            cl[..width].copy_from_slice(&cost[l..l + width]);
            cr[..width].copy_from_slice(&cost[r..r + width]);
            // dist(b, j) for j = 2..=W and its best split.
            let dist = |j: usize| -> (f32, u8) {
                let mut best = (f32::INFINITY, 0u8);
                for k in 1..j {
                    let c = cl[k - 1] + cr[j - k - 1];
                    if c < best.0 {
                        best = (c, k as u8);
                    }
                }
                best
            };
            let (dw, kw) = dist(width);
            // Ties go to the leaf (fewer nodes for the same cost). The root pays for its wide node
            // either way, so there the leaf competes with the shared-out slots alone.
            let (c1, k1) = if b == 0 {
                if leaf_ok && leaf <= dw {
                    (w.c_node * sa + leaf, 0)
                } else {
                    (w.c_node * sa + dw, kw)
                }
            } else {
                let inner = w.c_node * sa + dw;
                if leaf_ok && leaf <= inner {
                    (leaf, 0)
                } else {
                    (inner, kw)
                }
            };
            cost[at] = c1;
            choice[at] = k1;
            for i in 2..=width {
                let (d, k) = dist(i);
                let prev = cost[at + i - 2];
                let (c, ch) = if d < prev { (d, k) } else { (prev, 0) };
                cost[at + i - 1] = c;
                choice[at + i - 1] = ch;
            }
        }
        let total = if n == 0 { 0.0 } else { cost[0] as f64 };
        Optimal { width, choice, cost: total }
    }

    /// Whether binary node `b` becomes a leaf of the wide tree (when it is a child at all).
    pub(crate) fn is_leaf(&self, b: u32) -> bool {
        self.choice[b as usize * self.width] == 0
    }

    /// The children of the wide node made from binary node `b` (not a leaf), left to right.
    pub(crate) fn children(&self, nodes: &[Node], b: u32, out: &mut Vec<u32>) {
        out.clear();
        let k = self.choice[b as usize * self.width] as usize;
        debug_assert!(k >= 1, "node {b} is a leaf");
        let first = nodes[b as usize].first;
        self.collect(nodes, first, k, out);
        self.collect(nodes, first + 1, self.width - k, out);
    }

    /// The at most `i` subtrees node `b` is split into (its `cost(b, i)` decisions).
    fn collect(&self, nodes: &[Node], b: u32, i: usize, out: &mut Vec<u32>) {
        let mut i = i;
        loop {
            if i == 1 {
                out.push(b);
                return;
            }
            let k = self.choice[b as usize * self.width + i - 1] as usize;
            if k == 0 {
                i -= 1;
                continue;
            }
            let first = nodes[b as usize].first;
            self.collect(nodes, first, k, out);
            self.collect(nodes, first + 1, i - k, out);
            return;
        }
    }
}

/// The least cost the programme finds for collapsing `bvh` into `width`-wide nodes (`cost(root, 1)`,
/// areas relative to the root's): what [`crate::wide::WideBvh::collapse_cost`] of the tree built with these
/// weights must equal, and what no other collapse of the same binary tree may undercut.
pub fn optimal_cost(bvh: &Bvh, width: usize, w: CollapseCost) -> Result<f64, String> {
    if bvh.nodes.is_empty() {
        return Ok(0.0);
    }
    let (refs, order) = crate::wide::subtree_refs(&bvh.nodes)?;
    Ok(Optimal::plan(&bvh.nodes, &order, &refs, width, w).cost)
}
