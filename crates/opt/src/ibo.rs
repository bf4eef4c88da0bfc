//! Insertion-based optimization (Bittner, Hapala and Havran 2013; thesis 3.4).
use crate::search::{find_best, SearchScratch};
use bvhlab_bvh::dyntree::{DynTree, NONE};
use crate::{Bvh, CostParams, Optimized, BUDGET, KEEP_BEST, MAX_PASSES, MAX_SECONDS, SEED};
use bvhlab_params::{Kind, Method, ParamSpec, Params, Read};

pub const METHOD: Method = Method::new(
    "ibo",
    "insertion-based optimization: remove a node's children, reinsert each where the cost grows \
     least (Bittner et al. 2013; thesis 3.4)",
    "Bittner et al. 2013; thesis 3.4",
    &[
        ParamSpec {
            name: "measure",
            default: "comb",
            kind: Kind::Choice(&["sum", "min", "area", "comb", "random"]),
            about: "node inefficiency measure selecting the nodes of a pass (Bittner 2013 3.4)",
            in_label: true,
        },
        ParamSpec {
            name: "ibo_frac",
            default: "0.01",
            kind: Kind::PositiveFloat,
            about: "fraction of the nodes updated per pass (k = 1%; which nodes it counts: ibo_nodes)",
            in_label: false,
        },
        ParamSpec {
            name: "ibo_nodes",
            default: "inner",
            kind: Kind::Choice(&["inner", "all"]),
            about: "what ibo_frac counts: inner nodes (Bittner 2013 fig. 8, \"1% of inner nodes\") or all \
                    nodes (thesis 3.4.3, \"1% of nodes\", of which only inner ones are updated)",
            in_label: false,
        },
        ParamSpec {
            name: "schedule",
            default: "bittner",
            kind: Kind::Choice(&["bittner", "thesis"]),
            about: "termination: bittner = stop after p_T passes without improving the best cost, \
                    random sampling after p_R of them (Bittner 2013 3.5); thesis = check the cost \
                    every p_T passes against the previous check, at the first check without \
                    improvement switch to random sampling checked every p_R passes, stop at its \
                    first check without improvement and return the last tree (keep_best=false \
                    unless given; Frantal 2019 3.4.3, what tables 20 and 38 measure)",
            in_label: false,
        },
        ParamSpec {
            name: "pt",
            default: "10",
            kind: Kind::UInt { min: 1, max: 1 << 20 },
            about: "bittner: stop after p_T passes without improving the cost (Bittner 2013 3.5); \
                    thesis: passes between the cost checks of the measure stage",
            in_label: false,
        },
        ParamSpec {
            name: "pr",
            default: "5",
            kind: Kind::UInt { min: 0, max: 1 << 20 },
            about: "bittner: switch to random sampling after p_R passes without improvement; thesis: \
                    passes between the checks of the random stage (0: no random sampling)",
            in_label: false,
        },
        MAX_PASSES,
        MAX_SECONDS,
        BUDGET,
        KEEP_BEST,
        SEED,
    ],
)
.with_finish(schedule_rules);

/// p_R <= p_T (Bittner 2013 section 3.5); `schedule = "thesis"` returns the last tree (thesis
/// 3.4.3, 5.2.1) unless `keep_best` is given.
fn schedule_rules(given: &Params, params: &mut Params) -> Result<(), String> {
    if params.word("schedule") == "thesis" {
        // The thesis' run as a whole (3.4.3, 5.2.1): the last tree, and k = 1% of all nodes;
        // either can still be set explicitly.
        if !given.contains_key("keep_best") {
            params.insert("keep_best".into(), "false".into());
        }
        if !given.contains_key("ibo_nodes") {
            params.insert("ibo_nodes".into(), "all".into());
        }
    }
    let (pt, pr) = (params.typed::<u32>("pt"), params.typed::<u32>("pr"));
    if pr > pt {
        return Err(format!("pr={pr} must not exceed pt={pt} (Bittner 2013 3.5: p_R <= p_T)"));
    }
    if params.word("measure") == "random" {
        // Random sampling has nothing to switch to.
        params.insert("pr".into(), "0".into());
    }
    Ok(())
}

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

/// When the run stops (and when it switches to random sampling).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Schedule {
    /// Bittner 2013 3.4-3.5: one counter of passes since the best cost; random sampling after
    /// `pr` of them, stop after `pt`.
    #[default]
    Bittner,
    /// Frantal 2019 3.4.3: the cost is checked every `pt` passes against the previous check (the
    /// first one against the input's cost); the first check without improvement ends the measure
    /// stage, then a random-sampling stage is checked every `pr` passes the same way (its first
    /// check compares with the check that ended the measure stage); the random stage's first check
    /// without improvement ends the run. With `pr = 0` (or `measure = random`) there is one stage.
    Thesis,
}

impl Schedule {
    pub fn parse(s: &str) -> Option<Schedule> {
        Some(match s {
            "bittner" => Schedule::Bittner,
            "thesis" => Schedule::Thesis,
            _ => return None,
        })
    }
    pub fn as_str(&self) -> &'static str {
        match self {
            Schedule::Bittner => "bittner",
            Schedule::Thesis => "thesis",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IboConfig {
    pub measure: Measure,
    /// Termination rule (and stage switch) reading `pt` and `pr`.
    pub schedule: Schedule,
    /// Fraction of the inner nodes updated per pass (k = 1% in Bittner 2013).
    pub frac: f32,
    /// Bittner: stop after this many passes without improving the best cost (p_T = 10). Thesis:
    /// the period of the measure stage's cost checks.
    pub pt: u32,
    /// Bittner: switch from the measure to random sampling after this many passes without
    /// improvement (p_R = 5, p_R <= p_T). Thesis: the period of the random stage's checks. 0
    /// disables random sampling (under both schedules).
    pub pr: u32,
    /// 0 = no limit.
    pub max_passes: u32,
    /// 0 = no limit.
    pub max_seconds: f64,
    /// Stop after [`pass_budget`] passes (`Stop::PassBudget`) even without `max_passes`.
    pub budget: bool,
    /// `frac` counts all nodes, not only the inner ones: the thesis' reading (3.4.3: "optimize 1%
    /// of nodes ... allowing only the inner nodes to be processed"), about twice as many updates
    /// per pass as Bittner 2013's figure 8 ("1% of inner nodes"), which is the default.
    pub frac_of_all: bool,
    /// Return the best tree seen instead of the last (the thesis returned the last, 5.2.1).
    pub keep_best: bool,
    /// Seed of random sampling.
    pub seed: u64,
    pub cost: CostParams,
}

impl IboConfig {
    /// From the canonical parameters of [`METHOD`] and the chain's cost constants.
    pub fn from_params(p: &Params, cost: CostParams) -> IboConfig {
        IboConfig {
            measure: Measure::parse(p.word("measure")).unwrap_or(Measure::Comb),
            schedule: Schedule::parse(p.word("schedule")).unwrap_or_default(),
            frac: p.typed::<f64>("ibo_frac") as f32,
            pt: p.typed("pt"),
            pr: p.typed("pr"),
            max_passes: p.typed("max_passes"),
            max_seconds: p.typed("max_seconds"),
            budget: p.word("budget") != "off",
            frac_of_all: p.word("ibo_nodes") == "all",
            keep_best: p.typed("keep_best"),
            seed: p.typed::<u32>("seed") as u64,
            cost,
        }
    }
}

impl Default for IboConfig {
    fn default() -> Self {
        IboConfig {
            measure: Measure::Comb,
            schedule: Schedule::Bittner,
            frac: 0.01,
            pt: 10,
            pr: 5,
            max_passes: 0,
            max_seconds: 0.0,
            budget: true,
            frac_of_all: false,
            keep_best: true,
            seed: 1,
            cost: CostParams::default(),
        }
    }
}

/// Reinsertions per inner node that the default budget allows: a converging run updates each node
/// a few times (Bittner 2013 figure 7: most of the gain in the first passes), so 25 only cuts
/// runs that keep finding float-sized gains forever.
pub const BUDGET_UPDATES_PER_NODE: u64 = 25;

/// The default pass budget of a tree with `inner` inner nodes updated `k` per pass:
/// `BUDGET_UPDATES_PER_NODE * inner / k` passes, at least 100.
pub fn pass_budget(inner: usize, k: usize) -> u32 {
    (BUDGET_UPDATES_PER_NODE * inner as u64).div_ceil(k.max(1) as u64).clamp(100, u32::MAX as u64) as u32
}

/// Optimizes `bvh` (any builder's output, any leaf sizes: leaves move as units).
///
/// Passes (Bittner 2013 3.4-3.5): each pass updates k = max(1, round(frac x inner nodes)) inner
/// nodes with [`reinsert_children`]: the k with the highest measure, most inefficient first (ties
/// by node index), or k drawn uniformly (with replacement, seeded SplitMix64) in the random phase.
/// The root cannot be updated (it has no parent) and is never selected. After `pr` passes without
/// improving the best cost the selection switches to random sampling for the rest of the run; after
/// `pt` passes without improvement the run stops (one counter for both, Bittner 3.5; it is not reset
/// by the switch). With [`Schedule::Thesis`] the stages end at periodic checks instead (see
/// there; one counter per stage, reset at the switch). The cost is recomputed exactly after every pass by a linear sweep over the inner
/// nodes (node slots keep their role, so the inner nodes are a fixed index set): the leaf term of
/// eq. 2 and the root box never change when whole leaves move.
pub fn optimize(bvh: &Bvh, cfg: &IboConfig) -> Optimized {
    let start = std::time::Instant::now();
    let mut tree = DynTree::from_bvh(bvh);
    let inner: Vec<u32> = (0..tree.nodes.len() as u32).filter(|&i| !tree.is_leaf(i)).collect();
    let cost_of = CostOf::new(&tree, cfg.cost);
    let c0 = cost_of.eval(&tree, &inner);
    let mut trace = vec![crate::PassRecord { pass: 0, seconds: 0.0, sah_cost: c0, moved: 0, phase: cfg.measure.as_str().to_string() }];
    // Updatable nodes: every inner node but the root.
    let cand: Vec<u32> = inner.iter().copied().filter(|&i| i != tree.root).collect();
    if cand.is_empty() {
        return Optimized { bvh: tree.to_bvh(), trace, stop: crate::Stop::Converged, returned_pass: 0 };
    }
    let counted = if cfg.frac_of_all { tree.nodes.len() } else { inner.len() };
    let k = ((cfg.frac as f64 * counted as f64).round() as usize).clamp(1, cand.len());
    let mut rng = crate::SplitMix64::new(cfg.seed);
    let mut scratch = SearchScratch::new();
    let mut keyed: Vec<(f64, u32)> = Vec::with_capacity(cand.len());
    let mut area: Vec<f64> = Vec::with_capacity(tree.nodes.len());
    let mut batch: Vec<u32> = Vec::with_capacity(k);
    let mut best_cost = c0;
    let mut best_pass = 0u32;
    // keep_best: the best tree's nodes and root, updated from the list of nodes changed since it
    // was taken (Bittner's passes change a few percent of the nodes; copying all of them after
    // every improving pass was a tenth of the run time on conference).
    let mut best_nodes = tree.nodes.clone();
    let mut best_root = tree.root;
    let mut dirty: Vec<u32> = Vec::new();
    let mut dirty_overflow = false; // more changes than nodes since the copy: copy everything
    let mut since_best = 0u32;
    let mut random_phase = cfg.measure == Measure::Random;
    // Thesis schedule: passes since the stage's last check, and the cost at that check.
    let mut since_check = 0u32;
    let mut last_check = c0;
    let mut pass = 0u32;
    let stop = loop {
        pass += 1;
        batch.clear();
        if random_phase {
            for _ in 0..k {
                batch.push(cand[rng.below(cand.len() as u64) as usize]);
            }
        } else {
            // Areas of all nodes in one linear sweep, then the measures read children's areas
            // from this small array instead of chasing scattered 40-byte nodes.
            area.clear();
            area.extend(tree.nodes.iter().map(|d| d.bounds.area()));
            keyed.clear();
            keyed.extend(cand.iter().map(|&i| {
                let d = &tree.nodes[i as usize];
                (measure_of(area[i as usize], area[d.left as usize], area[d.right as usize], cfg.measure), i)
            }));
            // Highest measure first, ties by lower index: a total order, so the selection is
            // deterministic (select_nth then sort of the k selected; thesis 3.4.3).
            let cmp = |a: &(f64, u32), b: &(f64, u32)| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1));
            if k < keyed.len() {
                keyed.select_nth_unstable_by(k, cmp);
            }
            keyed[..k].sort_unstable_by(cmp);
            batch.extend(keyed[..k].iter().map(|e| e.1));
        }
        let mut moved = 0u64;
        for &n in &batch {
            moved += if cfg.keep_best {
                reinsert_logged(&mut tree, n, &mut scratch, &mut dirty)
            } else {
                reinsert_children(&mut tree, n, &mut scratch)
            } as u64;
        }
        let c = cost_of.eval(&tree, &inner);
        trace.push(crate::PassRecord {
            pass,
            seconds: start.elapsed().as_secs_f64(),
            sah_cost: c,
            moved,
            phase: if random_phase { "random".to_string() } else { cfg.measure.as_str().to_string() },
        });
        if c < best_cost {
            best_cost = c;
            best_pass = pass;
            since_best = 0;
            if cfg.keep_best {
                if dirty_overflow || dirty.len() > best_nodes.len() / 4 {
                    best_nodes.copy_from_slice(&tree.nodes);
                } else {
                    for &i in &dirty {
                        best_nodes[i as usize] = tree.nodes[i as usize];
                    }
                }
                best_root = tree.root;
                dirty.clear();
                dirty_overflow = false;
            }
        } else {
            since_best += 1;
            if dirty.len() > best_nodes.len() {
                dirty.clear();
                dirty_overflow = true;
            }
        }
        match cfg.schedule {
            Schedule::Bittner => {
                if since_best >= cfg.pt {
                    break crate::Stop::Converged;
                }
                if !random_phase && cfg.pr > 0 && since_best >= cfg.pr {
                    random_phase = true;
                }
            }
            Schedule::Thesis => {
                // The measure stage (or a measure=random run) is checked every p_T passes, the
                // random stage after it every p_R passes.
                since_check += 1;
                let second_stage = random_phase && cfg.measure != Measure::Random;
                let period = if second_stage { cfg.pr } else { cfg.pt };
                if since_check >= period.max(1) {
                    since_check = 0;
                    let improved = c < last_check;
                    last_check = c;
                    if !improved {
                        if random_phase || cfg.pr == 0 {
                            break crate::Stop::Converged;
                        }
                        random_phase = true;
                    }
                }
            }
        }
        if cfg.max_passes > 0 && pass >= cfg.max_passes {
            break crate::Stop::MaxPasses;
        }
        if cfg.budget && pass >= pass_budget(inner.len(), k) {
            break crate::Stop::PassBudget;
        }
        if cfg.max_seconds > 0.0 && start.elapsed().as_secs_f64() >= cfg.max_seconds {
            break crate::Stop::MaxSeconds;
        }
    };
    let (out, returned_pass) = if cfg.keep_best {
        if best_pass == pass {
            (tree.to_bvh(), pass)
        } else if best_pass == 0 {
            (bvh.clone(), 0)
        } else {
            // to_bvh reads only the nodes and the root (the parent array is not needed).
            tree.nodes = best_nodes;
            tree.root = best_root;
            (tree.to_bvh(), best_pass)
        }
    } else {
        (tree.to_bvh(), pass)
    };
    Optimized { bvh: out, trace, stop, returned_pass }
}

/// SAH cost (thesis eq. 4 / Bittner eq. 2) of a tree whose leaves only move as units: the root box
/// (the union of all leaves) and the leaf term are fixed, so only the inner areas are summed.
struct CostOf {
    c_t: f64,
    leaf_term: f64,
    root_sa: f64,
}

impl CostOf {
    fn new(tree: &DynTree, cost: CostParams) -> CostOf {
        let root_sa = if tree.root == NONE { 0.0 } else { tree.nodes[tree.root as usize].bounds.area_f64() };
        let degenerate = !(root_sa > 0.0);
        let leaf_term: f64 = tree
            .nodes
            .iter()
            .filter(|d| d.is_leaf())
            .map(|d| if degenerate { 1.0 } else { d.bounds.area_f64() } * d.count as f64)
            .sum::<f64>()
            * cost.c_i as f64;
        CostOf { c_t: cost.c_t as f64, leaf_term, root_sa: if degenerate { 0.0 } else { root_sa } }
    }
    fn eval(&self, tree: &DynTree, inner: &[u32]) -> f64 {
        if self.root_sa == 0.0 {
            // Zero-area root: every node counts with ratio 1 (docs/decisions.md, "Metrics with a zero-area root").
            return self.c_t * inner.len() as f64 + self.leaf_term;
        }
        let s: f64 = inner.iter().map(|&i| tree.nodes[i as usize].bounds.area_f64()).sum();
        (self.c_t * s + self.leaf_term) / self.root_sa
    }
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
    reinsert_logged(tree, n, scratch, &mut NoLog)
}

/// Receives every node whose [`bvhlab_bvh::dyntree::DNode`] a reinsertion changes (child links or box), so
/// the optimizer can update its copy of the best tree in O(changed) instead of copying it whole.
trait Log {
    fn touch(&mut self, n: u32);
}

struct NoLog;
impl Log for NoLog {
    #[inline]
    fn touch(&mut self, _: u32) {}
}

impl Log for Vec<u32> {
    #[inline]
    fn touch(&mut self, n: u32) {
        if n != NONE {
            self.push(n);
        }
    }
}

fn reinsert_logged(tree: &mut DynTree, n: u32, scratch: &mut SearchScratch, log: &mut impl Log) -> bool {
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
    log.touch(g);
    refit_logged(tree, g, log);
    let d = tree.nodes[n as usize];
    let (l, r) = (d.left, d.right);
    // Larger child (by surface area) first; ties keep the left child first.
    let (c1, c2) = if tree.bounds(r).area() > tree.bounds(l).area() { (r, l) } else { (l, r) };
    let x1 = insert_at_best(tree, c1, n, scratch, log);
    let x2 = insert_at_best(tree, c2, p, scratch, log);
    !(x1 == s && x2 == c1)
}

/// Inserts the detached subtree `c` beside the best node X (Bittner 2013 algorithm 1) using the
/// free inner node `link` as their parent; returns X.
fn insert_at_best(tree: &mut DynTree, c: u32, link: u32, scratch: &mut SearchScratch, log: &mut impl Log) -> u32 {
    let (x, _) = find_best(tree, tree.bounds(c), scratch);
    let xp = tree.parent[x as usize];
    tree.replace_child(xp, x, link);
    tree.set_children(link, x, c);
    log.touch(xp);
    log.touch(link);
    refit_logged(tree, xp, log);
    x
}

/// [`DynTree::refit_up_until_stable`] that reports the nodes whose box changed.
#[inline]
fn refit_logged(tree: &mut DynTree, mut n: u32, log: &mut impl Log) {
    while n != NONE {
        let d = tree.nodes[n as usize];
        let b = tree.nodes[d.left as usize].bounds.union(&tree.nodes[d.right as usize].bounds);
        if b == d.bounds {
            return;
        }
        tree.nodes[n as usize].bounds = b;
        log.touch(n);
        n = tree.parent[n as usize];
    }
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
pub fn measure_value(tree: &DynTree, n: u32, m: Measure) -> f64 {
    measure_f64(tree, n, m)
}

#[inline]
fn measure_f64(tree: &DynTree, n: u32, m: Measure) -> f64 {
    let d = &tree.nodes[n as usize];
    if d.is_leaf() {
        return 0.0;
    }
    let sa = |i: u32| tree.nodes[i as usize].bounds.area();
    measure_of(d.bounds.area(), sa(d.left), sa(d.right), m)
}

/// The smaller positive child area (0 if both are 0). A zero-area child (a degenerate triangle's
/// box: a segment or a point) has no SAH weight; taken literally it makes M_MIN infinite for
/// every node above such a leaf, whatever the node's size, and on conference those nodes filled
/// every batch with reinsertions that cannot change the cost. So eq. 10 ignores it here.
#[inline]
fn min_positive(a: f64, b: f64) -> f64 {
    match (a > 0.0, b > 0.0) {
        (true, true) => a.min(b),
        (true, false) => a,
        (false, true) => b,
        (false, false) => 0.0,
    }
}

/// The measure from the areas of N and its children (f64, as the search uses).
#[inline]
fn measure_of(sa: f64, sl: f64, sr: f64, m: Measure) -> f64 {
    match m {
        Measure::Sum => ratio(sa, 0.5 * (sl + sr)),
        Measure::Min => ratio(sa, min_positive(sl, sr)),
        Measure::Area => sa,
        Measure::Comb => {
            let v = ratio(sa, 0.5 * (sl + sr)) * ratio(sa, min_positive(sl, sr)) * sa;
            if v.is_nan() {
                0.0
            } else {
                v
            }
        }
        Measure::Random => 0.0,
    }
}
