//! Insertion-based optimization (Bittner, Hapala and Havran 2013; thesis 3.4).
use crate::search::{find_best, SearchScratch};
use crate::tree::{DynTree, NONE};
use crate::{Bvh, CostParams, Optimized};

/// Node inefficiency measure used to pick the nodes of a pass (Bittner 2013 section 3.4, thesis
/// eq. 9-12), or uniform random sampling.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Measure {
    Sum,
    Min,
    Area,
    Comb,
    Random,
}

impl Measure {
    pub fn parse(s: &str) -> Option<Measure> {
        Some(match s {
            "sum" => Measure::Sum,
            "min" => Measure::Min,
            "area" => Measure::Area,
            "comb" => Measure::Comb,
            "random" => Measure::Random,
            _ => return None,
        })
    }
    pub fn as_str(&self) -> &'static str {
        match self {
            Measure::Sum => "sum",
            Measure::Min => "min",
            Measure::Area => "area",
            Measure::Comb => "comb",
            Measure::Random => "random",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IboConfig {
    pub measure: Measure,
    /// Fraction of the inner nodes updated per pass (k = 1% in Bittner 2013).
    pub frac: f32,
    /// Stop after this many passes without improving the best cost (p_T = 10).
    pub pt: u32,
    /// Switch from the measure to random sampling after this many passes without improvement
    /// (p_R = 5, p_R <= p_T). 0 disables the switch.
    pub pr: u32,
    /// 0 = no limit.
    pub max_passes: u32,
    /// 0 = no limit.
    pub max_seconds: f64,
    /// Return the best tree seen instead of the last (the thesis' oscillation, 5.2.1).
    pub keep_best: bool,
    /// Seed of random sampling.
    pub seed: u64,
    pub cost: CostParams,
}

impl Default for IboConfig {
    fn default() -> Self {
        IboConfig {
            measure: Measure::Comb,
            frac: 0.01,
            pt: 10,
            pr: 5,
            max_passes: 0,
            max_seconds: 0.0,
            keep_best: true,
            seed: 1,
            cost: CostParams::default(),
        }
    }
}

/// Optimizes `bvh` (any builder's output, any leaf sizes: leaves move as units).
pub fn optimize(bvh: &Bvh, cfg: &IboConfig) -> Optimized {
    let _ = cfg;
    todo!("ibo helper: Bittner 2013 insertion-based optimization ({} nodes)", bvh.nodes.len())
}

/// Updates inner node `n` (Bittner 2013 3.3, thesis 3.4.2): removes N, its parent P and N's
/// children L and R (N's sibling takes P's place, boxes refitted upwards), then reinserts the child
/// with the larger surface area first, each at the position [`find_best`] finds in the whole
/// remaining tree, linked by N (first child) and P (second child), with X_best as the left child
/// and the inserted node as the right one (thesis 3.4.2). Boxes are refitted after each step, so
/// the tree is consistent on return. The node count and every slot's role are unchanged (N and P
/// stay inner nodes). Returns whether the topology changed (false when the two children end up
/// under a common parent beside N's old sibling, i.e. where they were).
///
/// Nothing to do (returns false) when `n` is a leaf, the root, or has no parent.
pub fn reinsert_children(tree: &mut DynTree, n: u32, scratch: &mut SearchScratch) -> bool {
    if n == NONE || tree.is_leaf(n) {
        return false;
    }
    let p = tree.parent[n as usize];
    if p == NONE {
        return false;
    }
    let s = tree.sibling(n);
    let g = tree.parent[p as usize];
    // Remove N and P: the sibling takes P's place (becomes the root when P was the root).
    tree.replace_child(g, p, s);
    tree.refit_up_until_stable(g);
    let d = tree.nodes[n as usize];
    let (l, r) = (d.left, d.right);
    // Larger child (by surface area) first; ties keep the left child first.
    let (c1, c2) = if tree.bounds(r).area() > tree.bounds(l).area() { (r, l) } else { (l, r) };
    let x1 = insert_at_best(tree, c1, n, scratch);
    let x2 = insert_at_best(tree, c2, p, scratch);
    !(x1 == s && x2 == c1)
}

/// Inserts the detached subtree `c` beside the best node X (Bittner 2013 algorithm 1) using the
/// free inner node `link` as their parent; returns X.
fn insert_at_best(tree: &mut DynTree, c: u32, link: u32, scratch: &mut SearchScratch) -> u32 {
    let (x, _) = find_best(tree, tree.bounds(c), scratch);
    let xp = tree.parent[x as usize];
    tree.replace_child(xp, x, link);
    tree.set_children(link, x, c);
    tree.refit_up_until_stable(xp);
    x
}

/// Ratio a / b for the inefficiency measures: a zero denominator (degenerate child boxes) gives
/// +inf unless the numerator is zero too (then 1: nothing to gain).
#[inline]
fn ratio(a: f64, b: f64) -> f64 {
    if b > 0.0 {
        a / b
    } else if a > 0.0 {
        f64::INFINITY
    } else {
        1.0
    }
}

/// Inefficiency of inner node `n` (Bittner 2013 3.4; thesis eq. 9-12), in f64 (SA^3 of `comb`
/// overflows f32 on large scenes): `sum` = SA(N) / mean SA(children), `min` = SA(N) / min
/// SA(children), `area` = SA(N), `comb` = their product. Leaves and `Random` give 0.
pub fn measure_value(tree: &DynTree, n: u32, m: Measure) -> f32 {
    measure_f64(tree, n, m) as f32
}

#[inline]
fn measure_f64(tree: &DynTree, n: u32, m: Measure) -> f64 {
    let d = &tree.nodes[n as usize];
    if d.is_leaf() {
        return 0.0;
    }
    let sa = d.bounds.area() as f64;
    let sl = tree.nodes[d.left as usize].bounds.area() as f64;
    let sr = tree.nodes[d.right as usize].bounds.area() as f64;
    match m {
        Measure::Sum => ratio(sa, 0.5 * (sl + sr)),
        Measure::Min => ratio(sa, sl.min(sr)),
        Measure::Area => sa,
        Measure::Comb => {
            let v = ratio(sa, 0.5 * (sl + sr)) * ratio(sa, sl.min(sr)) * sa;
            if v.is_nan() {
                0.0
            } else {
                v
            }
        }
        Measure::Random => 0.0,
    }
}
