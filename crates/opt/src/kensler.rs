//! Tree rotations (Kensler 2008) with hill climbing or simulated annealing, the reference method
//! of Bittner 2013 (related work, 3.7 and tables 2-5: "Kensler's method, hill climbing" and
//! "simulated annealing").
//!
//! **Rotations.** At an inner node N with children L and R, a rotation exchanges two subtrees of
//! N that are not ancestors of each other: a child with a grandchild on the other side (L<->RL,
//! L<->RR, R<->LL, R<->LR) or, when both children are inner, two grandchildren (LL<->RL,
//! LL<->RR; LR<->RR and LR<->RL give the same trees). N's box, the boxes of its ancestors and
//! every leaf are unchanged, so the change of the SAH cost (thesis eq. 4) is the change of the
//! surface areas of the one or two rebuilt children of N times `c_T / SA(root)`. Leaves move as
//! units, so any leaf size works.
//!
//! **Hill climbing** (`anneal = false`): one pass visits the inner nodes in post-order (children
//! before parents, an explicit list, no recursion) and at each applies the rotation that reduces
//! the cost most, if any does. It stops when a pass applies none ([`Stop::Converged`]), at
//! `max_passes` or at `max_seconds`. The cost never increases (every applied rotation strictly
//! lowers the summed inner areas, so it cannot cycle).
//!
//! **Simulated annealing** (`anneal = true`): the same post-order passes; at each inner node the
//! best rotation is applied if it improves the cost, otherwise one valid rotation is drawn
//! uniformly (seeded [`SplitMix64`]) and applied with the Metropolis probability `exp(-ΔA / T)`.
//! Kensler's paper is not in our sources; this "greedy, else random uphill" reading degenerates to
//! the hill climber as T falls, so a cold schedule cannot end worse than hill climbing from the
//! same tree.
//! **Temperature unit:** T is a surface area, `T = t0 · SA(root)` at the first pass and `T *=
//! cooling` after every pass; ΔA is the change of summed inner-node areas, so in SAH cost units
//! the acceptance is `exp(-ΔC / (c_T · T / SA(root)))`. Annealing stops at `max_passes`, at
//! `max_seconds`, or when `T < 1e-9 · SA(root)` (below the f32 resolution of node areas:
//! [`Stop::Converged`]).
//!
//! **Trace and keep_best** as in [`crate::ibo`]: pass 0 is the input; each pass records its end
//! time, the cost after it and the rotations applied. With `keep_best` annealing returns the tree
//! of the cheapest pass (hill climbing's last pass is always its cheapest).
use bvhlab_bvh::dyntree::{DynTree, NONE};
use crate::{Bvh, CostParams, Optimized, PassRecord, SplitMix64, Stop};
use crate::{BUDGET, KEEP_BEST, MAX_PASSES, MAX_SECONDS, SEED};
use bvhlab_params::{Kind, Method, ParamSpec, Params, Read};
use std::time::Instant;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KenslerConfig {
    /// false: hill climbing (only improving rotations); true: simulated annealing.
    pub anneal: bool,
    /// Annealing start temperature (see the module for its unit).
    pub t0: f64,
    /// Annealing: temperature factor per pass, in (0, 1).
    pub cooling: f64,
    /// 0 = no limit.
    pub max_passes: u32,
    /// 0 = no limit.
    pub max_seconds: f64,
    /// Stop after [`pass_budget`] passes (`Stop::PassBudget`) even without `max_passes`.
    pub budget: bool,
    pub keep_best: bool,
    pub seed: u64,
    pub cost: CostParams,
}

/// The default pass budget for a tree of `nodes` nodes: 16 log2(nodes) + 64 passes (every pass
/// visits every node; hill climbing converges in tens of passes on the papers' scenes, so this only
/// cuts runs that keep finding float-sized gains).
pub fn pass_budget(nodes: usize) -> u32 {
    16 * (usize::BITS - nodes.max(1).leading_zeros()) + 64
}

pub const HILL_CLIMBING: Method = Method::new(
    "kensler-hc",
    "tree rotations, hill climbing: apply the best improving rotation at each node until a pass \
     finds none (Kensler 2008)",
    "Kensler 2008",
    &[MAX_PASSES, MAX_SECONDS, BUDGET, KEEP_BEST, SEED],
);

pub const ANNEALING: Method = Method::new(
    "kensler-sa",
    "tree rotations, simulated annealing (Kensler 2008); capped by max_passes / max_seconds",
    "Kensler 2008",
    &[
        ParamSpec {
            name: "t0",
            // 0.01 wrecks real trees in the first passes (dragon: cost 414 at pass 10);
            // 1e-5 still escapes hill climbing's optimum (dragon 144.27 vs HC 144.35).
            default: "0.00001",
            kind: Kind::PositiveFloat,
            about: "start temperature T0, an area relative to the root surface area (T = t0 SA(root))",
            in_label: false,
        },
        ParamSpec {
            name: "cooling",
            default: "0.9",
            kind: Kind::PositiveFloat,
            about: "temperature factor per pass, in (0, 1)",
            in_label: false,
        },
        ParamSpec { default: "100", ..MAX_PASSES },
        ParamSpec { default: "600", ..MAX_SECONDS },
        BUDGET,
        KEEP_BEST,
        SEED,
    ],
)
.with_finish(cooling_below_one);

fn cooling_below_one(_given: &Params, params: &mut Params) -> Result<(), String> {
    let c: f64 = params.typed("cooling");
    if !(c > 0.0 && c < 1.0) {
        return Err(format!("cooling={c} must be in (0, 1)"));
    }
    Ok(())
}

impl KenslerConfig {
    /// From the canonical parameters of [`HILL_CLIMBING`] or [`ANNEALING`] (`anneal`) and the
    /// chain's cost constants.
    pub fn from_params(p: &Params, cost: CostParams, anneal: bool) -> KenslerConfig {
        KenslerConfig {
            anneal,
            t0: p.typed("t0"),
            cooling: p.typed("cooling"),
            max_passes: p.typed("max_passes"),
            max_seconds: p.typed("max_seconds"),
            budget: p.word("budget") != "off",
            keep_best: p.typed("keep_best"),
            seed: p.typed::<u32>("seed") as u64,
            cost,
        }
    }
}

impl Default for KenslerConfig {
    /// The defaults of [`HILL_CLIMBING`] (a pipeline test checks it); t0 and cooling only
    /// matter to annealing ([`ANNEALING`] starts at t0 = 1e-5 and caps at 100 passes).
    fn default() -> Self {
        KenslerConfig {
            anneal: false,
            t0: 0.01,
            cooling: 0.9,
            max_passes: 0,
            max_seconds: 0.0,
            budget: true,
            keep_best: true,
            seed: 1,
            cost: CostParams::default(),
        }
    }
}

/// The six rotations at a node N = (L, R); `a <-> b` exchanges the two subtrees.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rotation {
    LwithRL,
    LwithRR,
    RwithLL,
    RwithLR,
    LLwithRL,
    LLwithRR,
}

pub const ROTATIONS: [Rotation; 6] = [
    Rotation::LwithRL,
    Rotation::LwithRR,
    Rotation::RwithLL,
    Rotation::RwithLR,
    Rotation::LLwithRL,
    Rotation::LLwithRR,
];

/// Change of the summed inner-node surface area if `rot` were applied at inner node `n`, or
/// `None` if `rot` needs an inner child that is a leaf. Computed in f64 from exact f32 box unions,
/// so a rotation and its inverse give exactly opposite values.
pub fn rotation_delta(t: &DynTree, n: u32, rot: Rotation) -> Option<f64> {
    let d = &t.nodes[n as usize];
    let (l, r) = (&t.nodes[d.left as usize], &t.nodes[d.right as usize]);
    let b = |i: u32| &t.nodes[i as usize].bounds;
    use Rotation::*;
    match rot {
        // R becomes (L, RR) / (RL, L).
        LwithRL | LwithRR => {
            if r.is_leaf() {
                return None;
            }
            let keep = if rot == LwithRL { r.right } else { r.left };
            Some(l.bounds.union(b(keep)).area_f64() - r.bounds.area_f64())
        }
        // L becomes (R, LR) / (LL, R).
        RwithLL | RwithLR => {
            if l.is_leaf() {
                return None;
            }
            let keep = if rot == RwithLL { l.right } else { l.left };
            Some(r.bounds.union(b(keep)).area_f64() - l.bounds.area_f64())
        }
        // L becomes (RL, LR) / (RR, LR), R becomes (LL, RR) / (RL, LL).
        LLwithRL | LLwithRR => {
            if l.is_leaf() || r.is_leaf() {
                return None;
            }
            let (moved_in, r_keep) = if rot == LLwithRL {
                (r.left, r.right)
            } else {
                (r.right, r.left)
            };
            let new_l = b(moved_in).union(b(l.right)).area_f64();
            let new_r = b(l.left).union(b(r_keep)).area_f64();
            Some((new_l + new_r) - (l.bounds.area_f64() + r.bounds.area_f64()))
        }
    }
}

/// Applies `rot` at inner node `n` (which must be valid for it: [`rotation_delta`] is `Some`).
/// Child positions are kept (the moved subtree takes the slot of the one it replaces); the boxes
/// of the rebuilt children are recomputed, N's box and its ancestors' are unchanged.
pub fn apply_rotation(t: &mut DynTree, n: u32, rot: Rotation) {
    let d = t.nodes[n as usize];
    let (l, r) = (d.left, d.right);
    use Rotation::*;
    // (child of N, its parent-to-be, the grandchild it swaps with)
    let swap_child = |t: &mut DynTree, child: u32, other: u32, grand: u32| {
        t.replace_child(other, grand, child);
        t.replace_child(n, child, grand);
        refit_one(t, other);
    };
    match rot {
        LwithRL => swap_child(t, l, r, t.nodes[r as usize].left),
        LwithRR => swap_child(t, l, r, t.nodes[r as usize].right),
        RwithLL => swap_child(t, r, l, t.nodes[l as usize].left),
        RwithLR => swap_child(t, r, l, t.nodes[l as usize].right),
        LLwithRL | LLwithRR => {
            let ll = t.nodes[l as usize].left;
            let rx = if rot == LLwithRL {
                t.nodes[r as usize].left
            } else {
                t.nodes[r as usize].right
            };
            t.replace_child(l, ll, rx);
            t.replace_child(r, rx, ll);
            refit_one(t, l);
            refit_one(t, r);
        }
    }
}

#[inline]
fn refit_one(t: &mut DynTree, n: u32) {
    let d = t.nodes[n as usize];
    t.nodes[n as usize].bounds = t.nodes[d.left as usize]
        .bounds
        .union(&t.nodes[d.right as usize].bounds);
}

/// Inner nodes reachable from the root in post-order (children before parents), iteratively:
/// the reverse of a node-right-left pre-order.
fn inner_post_order(t: &DynTree, out: &mut Vec<u32>, stack: &mut Vec<u32>) {
    out.clear();
    stack.clear();
    if t.root == NONE {
        return;
    }
    stack.push(t.root);
    while let Some(n) = stack.pop() {
        let d = &t.nodes[n as usize];
        if d.is_leaf() {
            continue;
        }
        out.push(n);
        stack.push(d.left);
        stack.push(d.right);
    }
    out.reverse();
}

/// The rotation at `n` with the lowest area change (ties: the first in [`ROTATIONS`] order), and
/// the number of valid rotations.
fn best_rotation(t: &DynTree, n: u32) -> (Option<(Rotation, f64)>, usize) {
    let mut best: Option<(Rotation, f64)> = None;
    let mut valid = 0;
    for rot in ROTATIONS {
        if let Some(delta) = rotation_delta(t, n, rot) {
            valid += 1;
            if best.map_or(true, |(_, b)| delta < b) {
                best = Some((rot, delta));
            }
        }
    }
    (best, valid)
}

pub fn optimize(bvh: &Bvh, cfg: &KenslerConfig) -> Optimized {
    optimize_scaled(bvh, cfg, TempScale::Root)
}

/// What the annealing temperature is relative to (for measurements; [`optimize`] uses `Root`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TempScale {
    /// `T = t0 · cooling^pass · SA(root)` for every node (the module's unit).
    Root,
    /// `T = t0 · cooling^pass · SA(N)` at node N: the same relative acceptance at every depth
    /// (an experiment: with `Root` deep nodes, whose area changes are tiny, walk almost freely
    /// while the top of the tree is frozen).
    Node,
}

/// [`optimize`] with a choice of [`TempScale`].
pub fn optimize_scaled(bvh: &Bvh, cfg: &KenslerConfig, scale: TempScale) -> Optimized {
    let start = Instant::now();
    let mut tree = DynTree::from_bvh(bvh);
    let phase = if cfg.anneal { "sa" } else { "hc" };
    let cost0 = tree.sah_cost(cfg.cost);
    let record = |pass: u32, seconds: f64, sah_cost: f64, moved: u64| PassRecord {
        pass,
        seconds,
        sah_cost,
        moved,
        phase: phase.to_string(),
    };
    let mut trace = vec![record(0, 0.0, cost0, 0)];
    if tree.root == NONE || tree.is_leaf(tree.root) {
        return Optimized {
            bvh: tree.to_bvh(),
            trace,
            stop: Stop::Converged,
            returned_pass: 0,
        };
    }
    let root_area = tree.bounds(tree.root).area_f64();
    // A zero-area root (flat degenerate scenes): every node has zero area, nothing to gain;
    // the temperature scale falls back to 1 so the schedule still ends.
    let area_unit = if root_area > 0.0 { root_area } else { 1.0 };
    let mut temp = cfg.t0 * area_unit;
    let t_min = 1e-9 * area_unit;
    let mut rng = SplitMix64::new(cfg.seed);

    // Best tree seen (annealing only: hill climbing never increases the cost).
    let snapshot = cfg.anneal && cfg.keep_best;
    let mut best: Option<(Vec<bvhlab_bvh::dyntree::DNode>, Vec<u32>, u32)> = None;
    let (mut best_cost, mut best_pass) = (cost0, 0u32);

    let mut order = Vec::new();
    let mut stack = Vec::new();
    let mut pass = 0u32;
    let stop = loop {
        if cfg.max_passes > 0 && pass >= cfg.max_passes {
            break Stop::MaxPasses;
        }
        if cfg.max_seconds > 0.0 && start.elapsed().as_secs_f64() >= cfg.max_seconds {
            break Stop::MaxSeconds;
        }
        if cfg.budget && pass >= pass_budget(tree.nodes.len()) {
            break Stop::PassBudget;
        }
        if cfg.anneal && temp < t_min {
            break Stop::Converged;
        }
        pass += 1;
        inner_post_order(&tree, &mut order, &mut stack);
        let mut moved = 0u64;
        for &n in &order {
            let (best_rot, valid) = best_rotation(&tree, n);
            let Some((rot, delta)) = best_rot else {
                continue;
            };
            if delta < 0.0 {
                apply_rotation(&mut tree, n, rot);
                moved += 1;
            } else if cfg.anneal {
                // No improving rotation: a uniformly drawn one, Metropolis acceptance.
                let k = rng.below(valid as u64) as usize;
                let rot = ROTATIONS
                    .iter()
                    .copied()
                    .filter(|&r| rotation_delta(&tree, n, r).is_some())
                    .nth(k)
                    .unwrap();
                let delta = rotation_delta(&tree, n, rot).unwrap();
                let t = match scale {
                    TempScale::Root => temp,
                    TempScale::Node => temp / area_unit * tree.bounds(n).area_f64(),
                };
                if rng.f64() < (-delta / t).exp() {
                    apply_rotation(&mut tree, n, rot);
                    moved += 1;
                }
            }
        }
        temp *= cfg.cooling;
        let c = tree.sah_cost(cfg.cost);
        trace.push(record(pass, start.elapsed().as_secs_f64(), c, moved));
        if c < best_cost {
            best_cost = c;
            best_pass = pass;
            // Annealing may leave this tree again: keep a copy to return it at the end.
            if snapshot {
                best = Some((tree.nodes.clone(), tree.parent.clone(), tree.root));
            }
        }
        if !cfg.anneal && moved == 0 {
            break Stop::Converged;
        }
    };
    let returned_pass = if snapshot && best_pass != pass {
        match best {
            Some((nodes, parent, root)) => {
                tree.nodes = nodes;
                tree.parent = parent;
                tree.root = root;
            }
            // The input was the best: start over from it.
            None => tree = DynTree::from_bvh(bvh),
        }
        best_pass
    } else {
        pass
    };
    Optimized {
        bvh: tree.to_bvh(),
        trace,
        stop,
        returned_pass,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bvhlab_bvh::{Aabb, Vec3};

    /// A random tree over `n` unit-ish boxes: random pairwise merges (so rotations have plenty to
    /// improve), laid out flat.
    fn random_tree(n: usize, seed: u64) -> (Bvh, Vec<Aabb>) {
        let mut rng = SplitMix64::new(seed);
        let boxes: Vec<Aabb> = (0..n)
            .map(|_| {
                let p = Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 10.0;
                Aabb::new(p, p + Vec3::splat(0.1 + rng.f32()))
            })
            .collect();
        // Build a DynTree by random merges, then lay it out.
        let mut nodes: Vec<bvhlab_bvh::dyntree::DNode> = boxes
            .iter()
            .enumerate()
            .map(|(i, b)| bvhlab_bvh::dyntree::DNode::leaf(*b, i as u32, 1))
            .collect();
        let mut parent = vec![NONE; n];
        let mut live: Vec<u32> = (0..n as u32).collect();
        while live.len() > 1 {
            let a = live.swap_remove(rng.below(live.len() as u64) as usize);
            let b = live.swap_remove(rng.below(live.len() as u64) as usize);
            let id = nodes.len() as u32;
            nodes.push(bvhlab_bvh::dyntree::DNode::inner(
                nodes[a as usize].bounds.union(&nodes[b as usize].bounds),
                a,
                b,
            ));
            parent.push(NONE);
            parent[a as usize] = id;
            parent[b as usize] = id;
            live.push(id);
        }
        let t = DynTree {
            nodes,
            parent,
            prims: (0..n as u32).collect(),
            root: live[0],
        };
        t.check().unwrap();
        (t.to_bvh(), boxes)
    }

    #[test]
    fn delta_matches_cost_change_for_every_rotation() {
        let cost = CostParams::default();
        let (bvh, boxes) = random_tree(60, 3);
        let t0 = DynTree::from_bvh(&bvh);
        let root_area = t0.bounds(t0.root).area_f64();
        let mut checked = 0;
        for n in t0.inner_nodes() {
            for rot in ROTATIONS {
                let Some(delta) = rotation_delta(&t0, n, rot) else {
                    continue;
                };
                let mut t = t0.clone();
                apply_rotation(&mut t, n, rot);
                t.check().unwrap();
                bvhlab_bvh::validate(&t.to_bvh(), &boxes).unwrap();
                let want = t.sah_cost(cost) - t0.sah_cost(cost);
                let got = cost.c_t as f64 * delta / root_area;
                assert!(
                    (want - got).abs() < 1e-9 * t0.sah_cost(cost),
                    "{rot:?} at {n}: {want} vs {got}"
                );
                // The inverse rotation exists with the exactly opposite delta.
                checked += 1;
            }
        }
        assert!(checked > 100, "only {checked} rotations checked");
    }

    #[test]
    fn hill_climbing_improves_a_random_tree() {
        let cost = CostParams::default();
        let (bvh, boxes) = random_tree(500, 9);
        let r = optimize(&bvh, &KenslerConfig::default());
        bvhlab_bvh::validate(&r.bvh, &boxes).unwrap();
        assert_eq!(r.stop, Stop::Converged);
        let before = bvhlab_bvh::metrics(&bvh, cost).sah_cost;
        let after = bvhlab_bvh::metrics(&r.bvh, cost).sah_cost;
        assert!(after < 0.7 * before, "{before} -> {after}");
        assert_eq!(r.trace.last().unwrap().moved, 0);
        assert!((r.trace.last().unwrap().sah_cost - after).abs() < 1e-9 * after);
    }
}
