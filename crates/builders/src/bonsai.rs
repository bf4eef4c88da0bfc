//! Bonsai (Ganestam, Barringer, Doggett and Akenine-Möller 2015; thesis 3.3): spatial-median
//! selection of primitive sets of at most N, a presorted full-sweep SAH mini tree per set (in
//! parallel), optional mini-tree pruning with threshold T times the mean mini-tree area (3.3.3),
//! then a full-sweep SAH top tree over the mini-tree roots weighted by their primitive counts.
//!
//! Phases (thesis 3.3.2) and how they run here:
//! 1. centroids: the given centres, copied with their indices into 16-byte records;
//! 2. selection: in-place spatial-median partition of the records (largest axis of the centroid
//!    bounds, split at its middle; an empty side falls back to the object median, so coincident
//!    centroids terminate) until a set has at most N primitives. No nodes are made;
//! 3. mini trees: `sweep_sah::build_local` over each set, with the SAH leaf test of `cfg.top`.
//!    Phases 2 and 3 run as one `rayon::join` recursion: a set's mini tree is built as soon as the
//!    set is found, concurrently with the selection elsewhere;
//! 4. pruning (optional, see [`prune`]);
//! 5. top tree: `sweep_sah::build_weighted` over the mini-tree roots (boxes, box centres, primitive
//!    counts as SAH weights), one root per top-tree leaf.
//!
//! The final tree is laid out as [`crate::topdown`]'s sequential driver would lay it out: root at 0,
//! child pairs allocated when their parent is expanded, left subtrees first. A mini (sub)tree's
//! descendants are one contiguous block of its own array in that order, so they are copied as a
//! block with shifted indices (in parallel), and the primitives are renumbered in leaf order.
//! Every decision depends only on the input, never on scheduling: same bytes at any thread count.
use crate::simd_box::BoxA;
use crate::sweep_sah;
use crate::{TopDownConfig, LEAF};
use bvhlab_bvh::{Aabb, Bvh, Node, Vec3};
use bvhlab_params::{Kind, Method, ParamSpec, Params, Read};
use rayon::prelude::*;

pub const METHOD: Method = Method::new(
    "bonsai",
    "Bonsai: spatial-median mini-tree sets of at most n, full-sweep SAH mini trees in parallel, optional \
     pruning, full-sweep SAH top tree (Ganestam et al. 2015; thesis 3.3)",
    "Ganestam et al. 2015; thesis 3.3",
    &[
        ParamSpec {
            name: "n",
            default: "512",
            kind: Kind::UInt { min: 2, max: 1 << 24 },
            about: "primitive set size threshold N (thesis table 3: 512 or 4096)",
            in_label: true,
        },
        ParamSpec {
            name: "t",
            default: "0.1",
            kind: Kind::PositiveFloat,
            about: "pruning threshold T, times the mean mini-tree area (thesis 3.3.3: 0.1 or 0.01)",
            in_label: false,
        },
        ParamSpec {
            name: "prune",
            default: "false",
            kind: Kind::Choice(&["true", "false"]),
            about: "prune mini trees larger than T times the mean (thesis 3.3.3)",
            in_label: true,
        },
        LEAF,
    ],
)
.with_finish(t_only_with_pruning)
.with_label(label)
// 2: the same trees; the full sweeps hold indices instead of box records (less memory, another
//    build time): build times and memory re-measured.
.with_version(2);

/// `t` only matters with `prune=true`; without pruning it is dropped from the key, so BP0 has one
/// spelling.
fn t_only_with_pruning(_given: &Params, params: &mut Params) -> Result<(), String> {
    if params.word("prune") != "true" {
        params.remove("t");
    }
    Ok(())
}

/// `bonsai n=512 prune t=0.1`, plus `leaf` when changed.
fn label(p: &Params) -> String {
    let mut s = format!("bonsai n={}", p.typed::<u32>("n"));
    if p.typed::<bool>("prune") {
        s.push_str(&format!(" prune t={}", p.word("t")));
    }
    if p.get("leaf").map(String::as_str) != Some(LEAF.default) {
        s.push_str(&format!(" leaf={}", p.typed::<u32>("leaf")));
    }
    s
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BonsaiConfig {
    /// Primitive set size threshold N (512 or 4096).
    pub n: u32,
    /// Pruning threshold T (0.1 or 0.01), relative to the mean mini-tree surface area.
    pub t: f32,
    pub prune: bool,
    /// Leaf threshold and SAH constants of the mini-tree and top-tree sweeps.
    pub top: TopDownConfig,
}

impl BonsaiConfig {
    /// Thesis table 3, "Bonsai" (BP0): N = 512, no pruning.
    pub const BP0: BonsaiConfig = BonsaiConfig {
        n: 512,
        t: 0.1,
        prune: false,
        top: TopDownConfig {
            leaf: 2,
            cost: bvhlab_bvh::CostParams { c_t: 3.0, c_i: 2.0 },
        },
    };
    /// Thesis table 3, "BonsaiP" (BP1): N = 512, T = 0.1, pruning.
    pub const BP1: BonsaiConfig = BonsaiConfig {
        prune: true,
        ..Self::BP0
    };
    /// Thesis table 3, "BonsaiP*" (BP2): N = 4096, T = 0.01, pruning.
    pub const BP2: BonsaiConfig = BonsaiConfig {
        n: 4096,
        t: 0.01,
        prune: true,
        ..Self::BP0
    };
}

impl BonsaiConfig {
    /// From the canonical parameters of [`METHOD`]; `top` carries `leaf` and the cost constants.
    pub fn from_params(p: &Params, top: TopDownConfig) -> BonsaiConfig {
        BonsaiConfig {
            n: p.typed("n"),
            t: p.typed("t"),
            prune: p.typed("prune"),
            top,
        }
    }
}

/// A selection record: centroid and primitive index (16 bytes, so the partitions stream).
#[derive(Clone, Copy, Debug)]
struct Rec {
    c: Vec3,
    idx: u32,
}

/// One mini tree: nodes in the sequential driver's layout (leaf `first` indexes `prims`) and the
/// global primitive indices in leaf order.
struct MiniTree {
    nodes: Vec<Node>,
    prims: Vec<u32>,
}

/// A top-tree item: the subtree of `tree` rooted at local node `root` (the whole mini tree, or a
/// subtree left by pruning). Its primitives are `prims[prim_begin..prim_begin + prim_count]` of the
/// mini tree, its `desc` descendants are the local nodes `[first child, first child + desc)`.
#[derive(Clone, Copy, Debug)]
struct Item {
    tree: u32,
    root: u32,
    prim_begin: u32,
    prim_count: u32,
    desc: u32,
}

/// Builds over the current rayon pool; the same tree bytes at any thread count.
pub fn build(boxes: &[Aabb], centers: &[Vec3], cfg: &BonsaiConfig) -> Bvh {
    assert_eq!(
        boxes.len(),
        centers.len(),
        "builders need one centre per primitive box"
    );
    assert!(boxes.len() < u32::MAX as usize, "primitive indices are u32");
    let n = boxes.len();
    if n == 0 {
        return Bvh::default();
    }

    // Phase 1: centroid records and the root centroid bounds (min/max: exact in any merge order).
    let mut recs: Vec<Rec> = centers
        .par_iter()
        .enumerate()
        .map(|(i, &c)| Rec { c, idx: i as u32 })
        .collect();
    let cb = recs
        .par_chunks(1 << 14)
        .map(centroid_bounds)
        .reduce(|| BoxA::EMPTY, |a, b| a.union(&b));

    // Phases 2 and 3: selection and mini trees.
    let sel = Selector {
        boxes,
        set_max: cfg.n.max(1) as usize,
        // The recursion is one level per halving; deeper (degenerate) inputs continue iteratively.
        max_depth: 2 * (usize::BITS - n.leading_zeros()) as usize + 16,
        top: &cfg.top,
    };
    let minis = sel.select(&mut recs, cb, 0);
    drop(recs);

    // Phase 4: the top-tree items.
    let items: Vec<Item> = if cfg.prune {
        // Threshold: T times the mean root surface area of all mini trees (thesis 3.3.3, "the first
        // idea"); summed in set order, so it does not depend on the thread count.
        let sum: f64 = minis.iter().map(|m| m.nodes[0].bounds.area_f64()).sum();
        let threshold = cfg.t as f64 * sum / minis.len() as f64;
        minis
            .par_iter()
            .enumerate()
            .map(|(t, m)| prune(t as u32, &m.nodes, threshold))
            .collect::<Vec<Vec<Item>>>()
            .concat()
    } else {
        minis
            .iter()
            .enumerate()
            .map(|(t, m)| Item {
                tree: t as u32,
                root: 0,
                prim_begin: 0,
                prim_count: m.prims.len() as u32,
                desc: m.nodes.len() as u32 - 1,
            })
            .collect()
    };

    // Phase 5: the top tree over the items, weighted by primitive counts.
    let item_boxes: Vec<Aabb> = items
        .iter()
        .map(|it| minis[it.tree as usize].nodes[it.root as usize].bounds)
        .collect();
    let weights: Vec<u32> = items.iter().map(|it| it.prim_count).collect();
    let (top, order) = sweep_sah::build_weighted(&item_boxes, &weights);
    assemble(n, &minis, &items, &top, &order)
}

fn centroid_bounds(recs: &[Rec]) -> BoxA {
    let mut b = BoxA::EMPTY;
    for r in recs {
        b.grow_point(r.c.into());
    }
    b
}

/// The selection and mini-tree phases' shared inputs.
struct Selector<'a> {
    boxes: &'a [Aabb],
    set_max: usize,
    max_depth: usize,
    top: &'a TopDownConfig,
}

impl Selector<'_> {
    /// The mini trees of `recs` (centroid bounds `cb`), in set order (thesis 3.3.2 phases 2, 3).
    fn select(&self, recs: &mut [Rec], cb: BoxA, depth: usize) -> Vec<MiniTree> {
        if recs.len() <= self.set_max {
            return vec![self.mini_tree(recs)];
        }
        if depth >= self.max_depth {
            return self.select_iterative(recs, cb);
        }
        let (m, lcb, rcb) = split_set(recs, cb);
        let (l, r) = recs.split_at_mut(m);
        let (mut a, b) = rayon::join(
            || self.select(l, lcb, depth + 1),
            || self.select(r, rcb, depth + 1),
        );
        a.extend(b);
        a
    }

    /// The depth-limit fallback: the same splits with an explicit stack, then the sets' mini trees
    /// in parallel (same sets, same order as the recursion).
    fn select_iterative(&self, recs: &mut [Rec], cb: BoxA) -> Vec<MiniTree> {
        let mut sets: Vec<(usize, usize)> = Vec::new();
        let mut stack = vec![(0, recs.len(), cb)];
        while let Some((b, e, cb)) = stack.pop() {
            if e - b <= self.set_max {
                sets.push((b, e));
                continue;
            }
            let (m, lcb, rcb) = split_set(&mut recs[b..e], cb);
            stack.push((b + m, e, rcb));
            stack.push((b, b + m, lcb));
        }
        // Left first: the sets come in increasing order and tile `recs`.
        let mut parts: Vec<&mut [Rec]> = Vec::with_capacity(sets.len());
        let mut rest = recs;
        for &(b, e) in &sets {
            let (mine, tail) = std::mem::take(&mut rest).split_at_mut(e - b);
            parts.push(mine);
            rest = tail;
        }
        parts.into_par_iter().map(|s| self.mini_tree(s)).collect()
    }

    /// Full-sweep SAH mini tree over one set (thesis 3.3.1), with the SAH leaf test of `top`.
    fn mini_tree(&self, set: &[Rec]) -> MiniTree {
        // Gather the set's boxes once: the sweep reads each box once per axis.
        let local: Vec<Aabb> = set.iter().map(|r| self.boxes[r.idx as usize]).collect();
        let (nodes, order) =
            sweep_sah::build_local(set.len(), |j| set[j].c, |j| local[j], self.top);
        MiniTree {
            nodes,
            prims: order.iter().map(|&j| set[j as usize].idx).collect(),
        }
    }
}

/// One spatial-median step of the selection (thesis 3.3.2): Hoare partition of `recs` (>= 2) by
/// `c[axis] < middle` on the largest axis of the centroid bounds `cb`, gathering the children's
/// centroid bounds. If a side is empty (coincident centroids, or adjacent floats), the set is split
/// at the object median by (centroid, index) instead. Returns the left size and both bounds.
fn split_set(recs: &mut [Rec], cb: BoxA) -> (usize, BoxA, BoxA) {
    debug_assert!(recs.len() >= 2);
    let axis = cb.largest_axis();
    // Halves first: the same float as 0.5 (lo + hi) but no overflow near f32::MAX.
    let mid = 0.5 * cb.min[axis] + 0.5 * cb.max[axis];
    // One monomorphized loop per axis (no per-element axis dispatch).
    let (i, lcb, rcb) = match axis {
        0 => partition(recs, |r| r.c.x < mid),
        1 => partition(recs, |r| r.c.y < mid),
        _ => partition(recs, |r| r.c.z < mid),
    };
    if i > 0 && i < recs.len() {
        return (i, lcb, rcb);
    }
    let m = recs.len() / 2;
    recs.select_nth_unstable_by(m, |a, b| {
        a.c[axis].total_cmp(&b.c[axis]).then(a.idx.cmp(&b.idx))
    });
    (m, centroid_bounds(&recs[..m]), centroid_bounds(&recs[m..]))
}

/// Hoare partition (`is_left` first) gathering both sides' centroid bounds; returns the left size.
#[inline(always)]
fn partition(recs: &mut [Rec], is_left: impl Fn(&Rec) -> bool) -> (usize, BoxA, BoxA) {
    let (mut lcb, mut rcb) = (BoxA::EMPTY, BoxA::EMPTY);
    let (mut i, mut j) = (0, recs.len());
    loop {
        while i < j && is_left(&recs[i]) {
            lcb.grow_point(recs[i].c.into());
            i += 1;
        }
        while i < j && !is_left(&recs[j - 1]) {
            rcb.grow_point(recs[j - 1].c.into());
            j -= 1;
        }
        if i >= j {
            break;
        }
        recs.swap(i, j - 1);
        lcb.grow_point(recs[i].c.into());
        rcb.grow_point(recs[j - 1].c.into());
        i += 1;
        j -= 1;
    }
    (i, lcb, rcb)
}

/// Mini-tree pruning (thesis 3.3.3) of mini tree `tree`: its top-tree items.
///
/// A mini tree whose root area is at most `threshold` stays whole. A larger one is traversed from
/// the root for "the first node smaller than the threshold"; such a node becomes a new root and
/// the nodes on its path to the former root are deleted. Our reading of the three-stack
/// description: the traversed siblings on the roots stack become roots *whole* (they were
/// traversed and held no node below the threshold), the untraversed ones on the traversal stack
/// are checked again the same way, and a (sub)tree in which no node is below the threshold is
/// never split (if nothing is found, nothing is deleted). As a rule over subtrees: `X` becomes a
/// root if `area(X) < threshold` or no node of `X`'s subtree is below the threshold; otherwise `X`
/// is deleted and its two children are examined. (The other possible reading, cutting down to the
/// nodes below the threshold and turning every larger leaf into its own root, would also dissolve
/// subtrees whose leaves are all large.) The result lists the roots in depth-first order, which is
/// also increasing primitive order.
fn prune(tree: u32, nodes: &[Node], threshold: f64) -> Vec<Item> {
    let whole = |root: usize, prim_begin: u32, prim_count: u32, desc: u32| Item {
        tree,
        root: root as u32,
        prim_begin,
        prim_count,
        desc,
    };
    let area = |i: usize| nodes[i].bounds.area_f64();
    if area(0) <= threshold {
        let prims = subtree_prims(nodes);
        return vec![whole(0, 0, prims, nodes.len() as u32 - 1)];
    }
    // Children come after their parent in the layout: one reverse pass gives every node's
    // primitive range, descendant count and "a node below the threshold inside".
    let k = nodes.len();
    let mut begin = vec![0u32; k];
    let mut end = vec![0u32; k];
    let mut desc = vec![0u32; k];
    let mut found = vec![false; k];
    for i in (0..k).rev() {
        let nd = &nodes[i];
        let small = area(i) < threshold;
        if nd.is_leaf() {
            begin[i] = nd.first;
            end[i] = nd.first + nd.count;
            found[i] = small;
        } else {
            let (l, r) = (nd.first as usize, nd.first as usize + 1);
            begin[i] = begin[l];
            end[i] = end[r];
            desc[i] = 2 + desc[l] + desc[r];
            found[i] = small || found[l] || found[r];
        }
    }
    let mut items = Vec::new();
    let mut stack = vec![0usize];
    while let Some(x) = stack.pop() {
        if area(x) < threshold || !found[x] {
            items.push(whole(x, begin[x], end[x] - begin[x], desc[x]));
        } else {
            // Deleted; right pushed first so the left child is examined first.
            let l = nodes[x].first as usize;
            stack.push(l + 1);
            stack.push(l);
        }
    }
    items
}

/// Number of primitives under a node array's root (the leaves' counts).
fn subtree_prims(nodes: &[Node]) -> u32 {
    nodes.iter().filter(|n| n.is_leaf()).map(|n| n.count).sum()
}

/// The final tree: the top tree's nodes, each top-tree leaf replaced by its item's subtree, in the
/// sequential driver's layout (module docs); primitives renumbered in leaf order.
fn assemble(n: usize, minis: &[MiniTree], items: &[Item], top: &[Node], order: &[u32]) -> Bvh {
    let total = top.len() + items.iter().map(|it| it.desc as usize).sum::<usize>();
    let placeholder = Node {
        bounds: top[0].bounds,
        first: 0,
        count: 0,
    };
    let mut nodes: Vec<Node> = (0..total).into_par_iter().map(|_| placeholder).collect();
    // Replay the allocation order: an inner node allocates its child pair when it is expanded, an
    // item its descendants as one block. (global index of the item root, block, first prim, item)
    let mut placed: Vec<(usize, usize, usize, usize)> = Vec::with_capacity(items.len());
    let (mut next, mut prim_next) = (1usize, 0usize);
    let mut stack: Vec<(usize, usize)> = vec![(0, 0)];
    while let Some((gi, ti)) = stack.pop() {
        let t = &top[ti];
        if t.is_leaf() {
            debug_assert_eq!(t.count, 1);
            let it = order[t.first as usize] as usize;
            placed.push((gi, next, prim_next, it));
            next += items[it].desc as usize;
            prim_next += items[it].prim_count as usize;
        } else {
            let li = next;
            next += 2;
            nodes[gi] = Node::inner(t.bounds, li as u32);
            stack.push((li + 1, t.first as usize + 1));
            stack.push((li, t.first as usize));
        }
    }
    debug_assert_eq!(next, total);
    debug_assert_eq!(prim_next, n);
    // Local node -> global: descendants shift by (block - first child), primitives by
    // (first prim - prim_begin).
    let relocate = |nd: &Node, c0: u32, block: usize, prim0: usize, it: &Item| {
        if nd.is_leaf() {
            Node::leaf(
                nd.bounds,
                (prim0 + (nd.first - it.prim_begin) as usize) as u32,
                nd.count,
            )
        } else {
            Node::inner(nd.bounds, (block + (nd.first - c0) as usize) as u32)
        }
    };
    for &(gi, block, prim0, it) in &placed {
        let item = &items[it];
        let root = &minis[item.tree as usize].nodes[item.root as usize];
        nodes[gi] = relocate(root, root.first, block, prim0, item);
    }
    // Blocks and primitive ranges both appear in increasing order in `placed`: carve the arrays
    // into disjoint slices and copy in parallel.
    let mut prim_indices = vec![0u32; n];
    // (nodes of the block, primitive slots, block start, first primitive, item)
    type Job<'a> = (&'a mut [Node], &'a mut [u32], usize, usize, usize);
    let mut jobs: Vec<Job> = Vec::with_capacity(placed.len());
    let (mut rest_n, mut rest_p): (&mut [Node], &mut [u32]) = (&mut nodes, &mut prim_indices);
    let (mut pos_n, mut pos_p) = (0, 0);
    for &(_, block, prim0, it) in &placed {
        let item = &items[it];
        let (d, c) = (item.desc as usize, item.prim_count as usize);
        let (_, tail) = std::mem::take(&mut rest_n).split_at_mut(block - pos_n);
        let (mine_n, tail) = tail.split_at_mut(d);
        rest_n = tail;
        pos_n = block + d;
        let (_, tail) = std::mem::take(&mut rest_p).split_at_mut(prim0 - pos_p);
        let (mine_p, tail) = tail.split_at_mut(c);
        rest_p = tail;
        pos_p = prim0 + c;
        jobs.push((mine_n, mine_p, block, prim0, it));
    }
    jobs.into_par_iter()
        .for_each(|(out_n, out_p, block, prim0, it)| {
            let item = &items[it];
            let m = &minis[item.tree as usize];
            let b = item.prim_begin as usize;
            out_p.copy_from_slice(&m.prims[b..b + out_p.len()]);
            if out_n.is_empty() {
                return;
            }
            let c0 = m.nodes[item.root as usize].first;
            let src = &m.nodes[c0 as usize..c0 as usize + out_n.len()];
            for (o, nd) in out_n.iter_mut().zip(src) {
                *o = relocate(nd, c0, block, prim0, item);
            }
        });
    Bvh {
        nodes,
        prim_indices,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn recs(cs: &[[f32; 3]]) -> Vec<Rec> {
        cs.iter()
            .enumerate()
            .map(|(i, c)| Rec {
                c: Vec3::from(*c),
                idx: i as u32,
            })
            .collect()
    }

    #[test]
    fn split_set_is_a_spatial_median_with_object_median_fallback() {
        let mut r = recs(&[
            [3.0, 0.0, 0.0],
            [0.0, 0.0, 0.0],
            [1.0, 0.5, 0.0],
            [4.0, 0.0, 0.0],
        ]);
        let cb = centroid_bounds(&r);
        let (m, l, rb) = split_set(&mut r, cb);
        assert_eq!(m, 2);
        assert!(r[..2].iter().all(|x| x.c.x < 2.0) && r[2..].iter().all(|x| x.c.x >= 2.0));
        assert_eq!(l.max.x, 1.0);
        assert_eq!(rb.min.x, 3.0);
        let mut same = recs(&[[1.0; 3]; 5]);
        let cb = centroid_bounds(&same);
        let (m, _, _) = split_set(&mut same, cb);
        assert_eq!(m, 2);
        let mut low: Vec<u32> = same[..2].iter().map(|x| x.idx).collect();
        low.sort_unstable();
        assert_eq!(low, vec![0, 1], "object median by (centroid, index)");
    }

    #[test]
    fn iterative_selection_gives_the_recursive_sets() {
        // Points at 2^k beside a cluster: a deep, one-sided selection.
        let mut boxes: Vec<Aabb> = (0..300)
            .map(|i| {
                let p = Vec3::new((i % 17) as f32, (i % 13) as f32, (i % 7) as f32) * 0.01;
                Aabb::new(p, p + Vec3::splat(0.001))
            })
            .collect();
        boxes.extend((0..60).map(|k| Aabb::from_point(Vec3::splat(2f32.powi(k)))));
        let mut rs: Vec<Rec> = boxes
            .iter()
            .enumerate()
            .map(|(i, b)| Rec {
                c: b.center(),
                idx: i as u32,
            })
            .collect();
        let cb = centroid_bounds(&rs);
        let top = TopDownConfig::default();
        let run = |max_depth: usize, rs: &mut [Rec]| {
            let sel = Selector {
                boxes: &boxes,
                set_max: 8,
                max_depth,
                top: &top,
            };
            sel.select(rs, cb, 0)
                .into_iter()
                .map(|m| (m.nodes, m.prims))
                .collect::<Vec<_>>()
        };
        let mut rs2 = rs.clone();
        let deep = run(1000, &mut rs);
        let flat = run(0, &mut rs2);
        assert!(deep.len() > 60);
        assert!(
            deep == flat,
            "the fallback must find the same sets in the same order"
        );
    }
}
