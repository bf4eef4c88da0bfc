//! Incremental construction by insertion with global updates (Bittner, Hapala and Havran 2015;
//! thesis 3.5.1).
//!
//! - **Allocation** (thesis 3.5.1): all 2n - 1 nodes up front: leaf i (slots `0..n`) holds
//!   primitive i, inner nodes take slots `n..2n-1` in the order insertions consume them.
//! - **Insertion** in input order: each leaf (or coherent pair, below) goes where
//!   [`find_best`] says (the branch-and-bound search of Bittner 2013 shared with [`bvhlab_opt::ibo`]),
//!   linked with the node X found under a fresh inner node (X left, the inserted node right, as
//!   in thesis 3.4.2); boxes are refitted upwards until they stop changing.
//! - **Coherence clustering** (thesis eq. 13): two consecutive primitives x, y with
//!   SA(x ∪ y) / (SA(x) + SA(y)) < `coh` are linked under one inner node and inserted together;
//!   pairs do not overlap (after a pair the test restarts with the next two primitives). Two
//!   zero-area boxes count as coherent iff their union has zero area too. `coh = 0` disables it.
//! - **Global updates** (thesis 3.5.1): after every `batch` inserted primitives, one
//!   optimization pass in the spirit of ibo over the node-update cache: the inner nodes on the
//!   paths from the insertion points to the root since the last pass (flags, one per node), of
//!   which the `ofrac` fraction (at least one) with the highest combined inefficiency (thesis eq.
//!   12, [`measure_value`]) are updated with [`reinsert_children`], most inefficient first (ties by
//!   node index). The cache is then cleared. No pass after the last, incomplete batch (the
//!   post-process optimization of the paper is the separate `ibo` stage).
//!
//! Deterministic: no randomness, ties broken by index.
use bvhlab_opt::ibo::{measure_value, reinsert_children, Measure};
use bvhlab_opt::search::{find_best, SearchScratch};
use bvhlab_bvh::dyntree::{DNode, DynTree, NONE};
use bvhlab_bvh::{Aabb, Bvh, CostParams};
use bvhlab_params::{Kind, Method, ParamSpec, Params, Read};

pub const METHOD: Method = Method::new(
    "incremental",
    "insertion of primitives in input order with branch-and-bound search and an optimization pass \
     per batch (Bittner et al. 2015; thesis 3.5.1); one primitive per leaf: add compact = \"collapse\"",
    "Bittner et al. 2015; thesis 3.5.1",
    &[
        ParamSpec {
            name: "batch",
            default: "8000",
            kind: Kind::UInt { min: 1, max: u32::MAX },
            about: "primitives inserted between optimization passes (thesis table 5)",
            in_label: false,
        },
        ParamSpec {
            name: "ofrac",
            default: "0.01",
            kind: Kind::PositiveFloat,
            about: "fraction of the touched inner nodes optimized after each batch (thesis table 5)",
            in_label: false,
        },
        ParamSpec {
            name: "coh",
            default: "1.5",
            kind: Kind::NonNegativeFloat,
            about: "coherence threshold R_max of thesis eq. 13 (0 disables clustering)",
            in_label: false,
        },
    ],
);

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IncConfig {
    /// Primitives inserted between two optimization passes (8000).
    pub batch: u32,
    /// Fraction of the cached (touched) inner nodes optimized after each batch (0.01).
    pub ofrac: f32,
    /// Coherence threshold R_max of eq. 13 (1.5): two consecutive primitives whose union's area is
    /// below R_max times the sum of their areas are clustered and inserted as one subtree.
    pub coh: f32,
    pub cost: CostParams,
}

impl Default for IncConfig {
    fn default() -> Self {
        IncConfig {
            batch: 8000,
            ofrac: 0.01,
            coh: 1.5,
            cost: CostParams::default(),
        }
    }
}

impl IncConfig {
    /// From the canonical parameters of [`METHOD`].
    pub fn from_params(p: &Params, cost: CostParams) -> IncConfig {
        IncConfig {
            batch: p.typed("batch"),
            ofrac: p.typed("ofrac"),
            coh: p.typed("coh"),
            cost,
        }
    }
}

/// Counters of one build, for measurements (what [`build`] does, plus what it did).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct IncStats {
    /// Coherent pairs inserted as one subtree.
    pub clusters: u64,
    /// Optimization passes run (one per complete batch).
    pub passes: u64,
    /// Nodes updated by those passes, and how many of them changed the topology.
    pub updated: u64,
    pub moved: u64,
    /// Nodes expanded by the insertion searches (not the update passes').
    pub visited: u64,
}

/// Builds a BVH with one primitive per leaf, inserting primitives in input order.
pub fn build(boxes: &[Aabb], cfg: &IncConfig) -> Bvh {
    build_with_stats(boxes, cfg).0
}

/// Readings of the node-update cache where the thesis is terse, for measurements (`inc_bench`);
/// [`build`] uses `Variant::default()`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Variant {
    /// false (default): the whole branch of an insertion is flagged (link node up to the root);
    /// true: only the link node and the ancestors whose box the insertion changed.
    pub changed_only: bool,
    /// false (default): k = ofrac x flagged nodes; true: k = ofrac x inner nodes in the tree
    /// (chosen among the flagged ones).
    pub k_of_tree: bool,
    /// Also run a pass after the last, incomplete batch.
    pub final_pass: bool,
    /// A batch counts insertions (a coherent pair is one) instead of primitives.
    pub batch_of_insertions: bool,
}

/// Thesis eq. 13: R_coh(x, y) < R_max.
fn coherent(x: &Aabb, y: &Aabb, r_max: f32) -> bool {
    let (sx, sy) = (x.area_f64(), y.area_f64());
    let su = x.union(y).area_f64();
    let denom = sx + sy;
    if denom > 0.0 {
        su / denom < r_max as f64
    } else {
        su == 0.0 && r_max > 0.0
    }
}

/// [`build`] plus counters.
pub fn build_with_stats(boxes: &[Aabb], cfg: &IncConfig) -> (Bvh, IncStats) {
    build_variant(boxes, cfg, Variant::default())
}

/// [`build_with_stats`] with a [`Variant`] of the node-update cache.
pub fn build_variant(boxes: &[Aabb], cfg: &IncConfig, var: Variant) -> (Bvh, IncStats) {
    let n = boxes.len();
    let mut stats = IncStats::default();
    if n == 0 {
        return (Bvh::default(), stats);
    }
    let total = 2 * n - 1;
    let mut nodes: Vec<DNode> = Vec::with_capacity(total);
    nodes.extend(
        boxes
            .iter()
            .enumerate()
            .map(|(i, b)| DNode::leaf(*b, i as u32, 1)),
    );
    nodes.resize(total, DNode::inner(Aabb::EMPTY, NONE, NONE));
    let mut tree = DynTree {
        nodes,
        parent: vec![NONE; total],
        prims: (0..n as u32).collect(),
        root: NONE,
    };
    let mut next_inner = n as u32;

    let mut scratch = SearchScratch::new();
    // Node-update cache: flags plus the list of flagged nodes (so a pass never scans all nodes).
    let mut flag = vec![false; total];
    let mut cached: Vec<u32> = Vec::new();
    let batch = cfg.batch.max(1) as usize;
    let mut inserted = 0usize;

    let mut i = 0usize;
    while i < n {
        // Coherent pair -> one subtree (thesis eq. 13).
        let (sub, count) =
            if cfg.coh > 0.0 && i + 1 < n && coherent(&boxes[i], &boxes[i + 1], cfg.coh) {
                let c = next_inner;
                next_inner += 1;
                tree.set_children(c, i as u32, i as u32 + 1);
                stats.clusters += 1;
                (c, 2)
            } else {
                (i as u32, 1)
            };
        i += count;
        if tree.root == NONE {
            tree.root = sub;
            tree.parent[sub as usize] = NONE;
        } else {
            let v0 = scratch.visited;
            let (x, _) = find_best(&tree, tree.bounds(sub), &mut scratch);
            stats.visited += scratch.visited - v0;
            let link = next_inner;
            next_inner += 1;
            let xp = tree.parent[x as usize];
            tree.replace_child(xp, x, link);
            tree.set_children(link, x, sub);
            if var.changed_only {
                if !flag[link as usize] {
                    flag[link as usize] = true;
                    cached.push(link);
                }
                let mut a = xp;
                while a != NONE {
                    let d = tree.nodes[a as usize];
                    let b = tree.nodes[d.left as usize]
                        .bounds
                        .union(&tree.nodes[d.right as usize].bounds);
                    if b == d.bounds {
                        break;
                    }
                    tree.nodes[a as usize].bounds = b;
                    if !flag[a as usize] {
                        flag[a as usize] = true;
                        cached.push(a);
                    }
                    a = tree.parent[a as usize];
                }
            } else {
                tree.refit_up_until_stable(xp);
                // Flag the branch: link and its ancestors, up to the first flagged one (within a
                // batch a flagged node's ancestors are flagged: insertions only add nodes below
                // them).
                let mut a = link;
                while a != NONE && !flag[a as usize] {
                    flag[a as usize] = true;
                    cached.push(a);
                    a = tree.parent[a as usize];
                }
            }
        }
        if !tree.is_leaf(sub) && !flag[sub as usize] {
            flag[sub as usize] = true;
            cached.push(sub);
        }
        let before = inserted;
        inserted += if var.batch_of_insertions { 1 } else { count };
        if (inserted / batch > before / batch && inserted < n) || (var.final_pass && inserted == n)
        {
            let base = if var.k_of_tree {
                Some(next_inner as usize - n)
            } else {
                None
            };
            optimize_cached(
                &mut tree,
                &mut cached,
                &mut flag,
                cfg.ofrac,
                base,
                &mut scratch,
                &mut stats,
            );
        }
    }
    debug_assert_eq!(next_inner as usize, total);
    debug_assert!(tree.check().is_ok());
    (tree.to_bvh(), stats)
}

/// One global update pass over the node-update cache (thesis 3.5.1), then clears the cache.
fn optimize_cached(
    tree: &mut DynTree,
    cached: &mut Vec<u32>,
    flag: &mut [bool],
    ofrac: f32,
    k_base: Option<usize>,
    scratch: &mut SearchScratch,
    stats: &mut IncStats,
) {
    stats.passes += 1;
    // Candidates: cached inner nodes that have a parent (the root cannot be updated).
    let mut cand: Vec<(f64, u32)> = cached
        .iter()
        .filter(|&&c| tree.parent[c as usize] != NONE)
        .map(|&c| (measure_value(tree, c, Measure::Comb), c))
        .collect();
    for &c in cached.iter() {
        flag[c as usize] = false;
    }
    cached.clear();
    if cand.is_empty() {
        return;
    }
    let base = k_base.unwrap_or(cand.len());
    let k = ((ofrac as f64 * base as f64).round() as usize).clamp(1, cand.len());
    // Highest measure first, ties by node index.
    let order = |a: &(f64, u32), b: &(f64, u32)| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1));
    if k < cand.len() {
        cand.select_nth_unstable_by(k - 1, order);
        cand.truncate(k);
    }
    cand.sort_unstable_by(order);
    for &(_, c) in &cand {
        stats.updated += 1;
        if reinsert_children(tree, c, scratch) {
            stats.moved += 1;
        }
    }
}
