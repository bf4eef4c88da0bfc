//! Spatial-split BVH (SBVH), Stich, Friedrich and Dietrich 2009, "Spatial Splits in Bounding Volume
//! Hierarchies". Unlike the other builders it sees the triangles, not only their boxes: a spatial
//! split clips a triangle against a plane and gives each side the box of its own piece, so one
//! triangle may be referenced by several leaves (`Bvh::prim_indices` then holds more references
//! than there are triangles; `bvhlab_bvh::validate_split` checks such trees).
//!
//! Per node (Stich 4.1): the best object split by a full SAH sweep over the references' box
//! centroids on all three axes (as `sweep_sah`, thesis 3.3.1, but sorting per node, since spatial
//! splits add references); if the overlap of its two children's boxes exceeds `alpha` times the
//! root's surface area (Stich 4.4, their eq. for lambda), also the best spatial split by chopped
//! binning (Stich 4.2: every reference is clipped bin by bin, the actual triangle clipped and the
//! piece's box intersected with the reference's box, so bins get tight boxes), then reference
//! unsplitting (Stich 4.3) when the chosen spatial split is applied. The cheaper split wins (below
//! `LOOKAHEAD_MIN` references; see the lookahead below); the SAH leaf test and the `leaf` threshold
//! are the other top-down builders' (thesis eq. 2-3).
//!
//! Where the paper is silent, bvhlab decides (docs/decisions.md, "SBVH"):
//! - Split budget: at most `growth` times as many references as triangles (default 2, a cap that
//!   conference (1.06x) and breakfast_room (1.19x) stay well under; production builders cap growth
//!   by a fixed factor too). The root gets
//!   `(growth - 1) * n` extra references; every node passes what its split did not use to its children
//!   in proportion to their reference counts (Embree's extended-range scheme), so the budget is a
//!   property of the subtree, never of the order of construction or the thread count.
//! - A spatial split must make progress (both children hold fewer references than the node), and
//!   none is tried below depth `MAX_SPATIAL_DEPTH`: with `leaf=1` two references straddling the same
//!   plane would otherwise split forever.
//! - Clipped boxes are rounded outwards (interpolation in f64, then to the enclosing f32), so the
//!   leaves' boxes together always cover every triangle and rays find the same closest hit as brute
//!   force.
//! - Areas and costs in f64, plane positions from f64: scale-free as the other builders (issue 15).
//! - Lookahead near the root (not in the paper): the greedy cost assumes both children become leaves,
//!   which misjudges large nodes; on conference the plain greedy SBVH is *worse* than the object-only
//!   full sweep (92.8 against 91.7; tinybvh's SBVH 96.8). Nodes of at least `LOOKAHEAD_MIN` references
//!   therefore cost every candidate within `LOOKAHEAD_MARGIN` of the greedy best (the best object and
//!   spatial split of each axis) as the full-sweep subtrees of its two children and take the cheapest:
//!   conference 86.9, breakfast_room 66.8, at about ten times the full sweep's build time.
use crate::{TopDownConfig, LEAF};
use bvhlab_bvh::{Aabb, Bvh, Node};
use bvhlab_geom::Triangle;
use bvhlab_params::{Kind, Method, ParamSpec, Params, Read};
use glam::Vec3;

pub const METHOD: Method = Method::new(
    "sbvh",
    "spatial-split BVH: full-sweep object splits and chopped-binned spatial splits with reference unsplitting \
     (Stich et al. 2009)",
    "Stich, Friedrich, Dietrich 2009",
    &[
        ParamSpec {
            name: "bins",
            default: "32",
            kind: Kind::UInt { min: 2, max: 1024 },
            about: "spatial-split bins per axis (Stich 4.2)",
            in_label: false,
        },
        ParamSpec {
            name: "alpha",
            default: "0.00001",
            kind: Kind::NonNegativeFloat,
            about: "try spatial splits only where the object split's child overlap exceeds alpha * SA(root) (Stich 4.4)",
            in_label: false,
        },
        ParamSpec {
            name: "growth",
            default: "2",
            kind: Kind::FloatAtLeast(1.0),
            about: "split budget: at most growth * triangles references (1 = object splits only); conference uses 1.06, breakfast_room 1.19",
            in_label: false,
        },
        LEAF,
    ],
);

/// No spatial split below this depth (termination guard; see the module doc).
const MAX_SPATIAL_DEPTH: u32 = 48;
/// Nodes with at least this many references check a greedily better spatial split against the
/// object split with their children costed as subtrees ([`Ctx::best_by_subtrees`]). Conference:
/// 4096 gives SAH 87.3, 2048 86.9 (growth 2); below, the greedy choice.
const LOOKAHEAD_MIN: usize = 2048;
/// How much above the greedy best cost a candidate may be to be costed as subtrees (conference:
/// 0.25 and 0.5 give the same SAH, 0.5 builds 50 % longer).
const LOOKAHEAD_MARGIN: f64 = 0.25;
/// Subtrees with at least this many references are built as two parallel tasks (`rayon::join`).
const PARALLEL_MIN: usize = 4096;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SbvhConfig {
    pub bins: u32,
    pub alpha: f64,
    pub growth: f64,
    pub top: TopDownConfig,
}

impl Default for SbvhConfig {
    fn default() -> Self {
        SbvhConfig { bins: 32, alpha: 1e-5, growth: 2.0, top: TopDownConfig::default() }
    }
}

impl SbvhConfig {
    /// From the canonical parameters of [`METHOD`]; `top` carries `leaf` and the cost constants.
    pub fn from_params(p: &Params, top: TopDownConfig) -> SbvhConfig {
        SbvhConfig {
            bins: p.typed("bins"),
            alpha: p.typed::<f32>("alpha") as f64,
            growth: p.typed::<f32>("growth") as f64,
            top,
        }
    }
}

/// A reference: (part of) triangle `tri` inside `b`.
#[derive(Clone, Copy, Debug)]
struct Ref {
    b: Aabb,
    tri: u32,
}

#[inline]
fn half_area(b: &Aabb) -> f64 {
    if b.is_empty() {
        return 0.0;
    }
    let e = b.extent_f64();
    e.x * e.y + e.y * e.z + e.z * e.x
}

#[inline]
fn intersect(a: &Aabb, b: &Aabb) -> Aabb {
    Aabb { min: a.min.max(b.min), max: a.max.min(b.max) }
}

/// The largest f32 <= x (x finite).
#[inline]
fn f32_down(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) > x {
        f.next_down()
    } else {
        f
    }
}

/// The smallest f32 >= x (x finite).
#[inline]
fn f32_up(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) < x {
        f.next_up()
    } else {
        f
    }
}

/// The boxes of the parts of `t` inside `r` on either side of the plane `x[axis] = p` (Stich 4.2:
/// clip the triangle, then intersect with the reference's box). An edge crossing the plane adds its
/// crossing point to both sides, computed in f64 and rounded outwards with a margin for the f64
/// interpolation error, so the two boxes cover the piece exactly or slightly more, never less.
/// A side the triangle does not reach is empty.
fn split_ref(t: &Triangle, r: &Aabb, axis: usize, p: f32) -> (Aabb, Aabb) {
    let (mut l, mut rr) = (Aabb::EMPTY, Aabb::EMPTY);
    for i in 0..3 {
        let (v0, v1) = (t.v[i], t.v[(i + 1) % 3]);
        let (a0, a1) = (v0[axis], v1[axis]);
        if a0 <= p {
            l.grow_point(v0);
        }
        if a0 >= p {
            rr.grow_point(v0);
        }
        if (a0 < p && a1 > p) || (a0 > p && a1 < p) {
            let (d0, d1) = (v0.as_dvec3(), v1.as_dvec3());
            let s = (p as f64 - a0 as f64) / (a1 as f64 - a0 as f64);
            let q = d0 + (d1 - d0) * s;
            let eps = (d0.abs() + d1.abs()) * (1.0 / (1u64 << 48) as f64);
            let (lo, hi) = (q - eps, q + eps);
            let mut qb = Aabb {
                min: Vec3::new(f32_down(lo.x), f32_down(lo.y), f32_down(lo.z)),
                max: Vec3::new(f32_up(hi.x), f32_up(hi.y), f32_up(hi.z)),
            };
            qb.min[axis] = p;
            qb.max[axis] = p;
            l.grow(&qb);
            rr.grow(&qb);
        }
    }
    let mut lc = *r;
    lc.max[axis] = lc.max[axis].min(p);
    let mut rc = *r;
    rc.min[axis] = rc.min[axis].max(p);
    (intersect(&l, &lc), intersect(&rr, &rc))
}

/// Order-preserving u32 of an f32 (total order; -0 < +0).
#[inline]
fn ordered(c: f32) -> u32 {
    let b = c.to_bits();
    if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    }
}

/// The box centre on `axis`, halves first so that huge coordinates cannot overflow.
#[inline]
fn centroid(b: &Aabb, axis: usize) -> f32 {
    b.min[axis] * 0.5 + b.max[axis] * 0.5
}

/// A node's split: the references of each child.
struct Split {
    left: Vec<Ref>,
    right: Vec<Ref>,
}

/// The best object split of one axis (full sweep): the number of references left in the axis'
/// `order`, SAH sum `SA_L n_L + SA_R n_R` (half areas) and the children's boxes.
struct ObjectSplit {
    n_left: usize,
    cost: f64,
    lb: Aabb,
    rb: Aabb,
    order: Vec<u32>,
}

/// The best spatial split: axis, plane index `k` (bins `0..k` left), cost.
struct SpatialSplit {
    axis: usize,
    k: usize,
    cost: f64,
}

/// The bin planes of one axis of a node: `planes[k]` for `k = 0..=bins`, computed in f64 and
/// rounded to f32 (non-decreasing; `planes[0]` and `planes[bins]` the box's faces).
struct Planes {
    p: Vec<f32>,
    lo: f64,
    inv: f64,
}

impl Planes {
    fn new(lo: f32, hi: f32, bins: usize) -> Planes {
        let (lo64, hi64) = (lo as f64, hi as f64);
        let p = (0..=bins)
            .map(|k| {
                if k == 0 {
                    lo
                } else if k == bins {
                    hi
                } else {
                    (lo64 + (hi64 - lo64) * k as f64 / bins as f64) as f32
                }
            })
            .collect();
        Planes { p, lo: lo64, inv: bins as f64 / (hi64 - lo64) }
    }
    #[inline]
    fn bins(&self) -> usize {
        self.p.len() - 1
    }
    #[inline]
    fn guess(&self, x: f32) -> usize {
        let g = ((x as f64 - self.lo) * self.inv).floor();
        if g.is_nan() || g < 0.0 {
            0
        } else {
            (g as usize).min(self.bins() - 1)
        }
    }
    /// The bin holding the reference's low end: the largest `k < bins` with `planes[k] <= x`.
    #[inline]
    fn first(&self, x: f32) -> usize {
        let mut k = self.guess(x);
        while k + 1 < self.bins() && self.p[k + 1] <= x {
            k += 1;
        }
        while k > 0 && self.p[k] > x {
            k -= 1;
        }
        k
    }
    /// The bin holding the reference's high end: the smallest `k` with `planes[k + 1] >= x`, at
    /// least `first` (a box ending exactly on a plane does not reach into the next bin).
    #[inline]
    fn last(&self, x: f32, first: usize) -> usize {
        let mut k = self.guess(x);
        while k > 0 && self.p[k] >= x {
            k -= 1;
        }
        while k + 1 < self.bins() && self.p[k + 1] < x {
            k += 1;
        }
        k.max(first)
    }
}

/// Builder state shared by all tasks (read-only).
struct Ctx<'a> {
    tris: &'a [Triangle],
    cfg: SbvhConfig,
    /// `alpha * SA(root)` (half areas): the overlap above which spatial splits are tried.
    min_overlap: f64,
}

/// A built subtree in the sequential driver's layout: root at 0, sibling pairs adjacent, left
/// subtrees first; leaf `first` indexes `prims`.
struct Sub {
    nodes: Vec<Node>,
    prims: Vec<u32>,
}

/// Builds the SBVH of `tris`. Empty input gives an empty BVH.
pub fn build(tris: &[Triangle], cfg: &SbvhConfig) -> Bvh {
    assert!(tris.len() < u32::MAX as usize, "primitive indices are u32");
    if tris.is_empty() {
        return Bvh::default();
    }
    let refs: Vec<Ref> = tris.iter().enumerate().map(|(i, t)| Ref { b: t.bounds(), tri: i as u32 }).collect();
    let root = bounds_of(&refs);
    let ctx = Ctx { tris, cfg: *cfg, min_overlap: cfg.alpha * half_area(&root) };
    let extra = ((cfg.growth - 1.0).max(0.0) * tris.len() as f64).floor();
    let budget = if extra.is_finite() { extra.min(u32::MAX as f64) as usize } else { u32::MAX as usize };
    let sub = ctx.subtree(refs, budget, 0);
    Bvh { nodes: sub.nodes, prim_indices: sub.prims }
}

fn bounds_of(refs: &[Ref]) -> Aabb {
    let mut b = Aabb::EMPTY;
    for r in refs {
        b.grow(&r.b);
    }
    b
}

impl Ctx<'_> {
    /// A subtree: large ones split here and build both halves in parallel, small ones go to the
    /// sequential [`Self::task`]. The node order does not depend on where the work was cut.
    fn subtree(&self, refs: Vec<Ref>, budget: usize, depth: u32) -> Sub {
        if refs.len() < PARALLEL_MIN {
            return self.task(refs, budget, depth);
        }
        let bounds = bounds_of(&refs);
        match self.split(refs, &bounds, budget, depth) {
            Err(refs) => leaf_sub(bounds, &refs),
            Ok((s, bl, br)) => {
                let (l, r) = rayon::join(
                    || self.subtree(s.left, bl, depth + 1),
                    || self.subtree(s.right, br, depth + 1),
                );
                merge(bounds, l, r)
            }
        }
    }

    /// The sequential driver (thesis 3.1.1's explicit stack), same node order as `topdown`.
    fn task(&self, refs: Vec<Ref>, budget: usize, depth: u32) -> Sub {
        let mut nodes = Vec::with_capacity(2 * refs.len());
        let mut prims = Vec::with_capacity(refs.len());
        let root = bounds_of(&refs);
        nodes.push(Node { bounds: root, first: 0, count: 0 });
        let mut stack = vec![(0usize, refs, root, budget, depth)];
        while let Some((ni, refs, bounds, budget, depth)) = stack.pop() {
            match self.split(refs, &bounds, budget, depth) {
                Err(refs) => {
                    nodes[ni] = Node::leaf(bounds, prims.len() as u32, refs.len() as u32);
                    prims.extend(refs.iter().map(|r| r.tri));
                }
                Ok((s, bl, br)) => {
                    let li = nodes.len();
                    let (lb, rb) = (bounds_of(&s.left), bounds_of(&s.right));
                    nodes.push(Node { bounds: lb, first: 0, count: 0 });
                    nodes.push(Node { bounds: rb, first: 0, count: 0 });
                    nodes[ni] = Node::inner(bounds, li as u32);
                    stack.push((li + 1, s.right, rb, br, depth + 1));
                    stack.push((li, s.left, lb, bl, depth + 1));
                }
            }
        }
        Sub { nodes, prims }
    }

    /// The split decision for one node with box `bounds`: `Err(refs)` makes a leaf, `Ok` gives the
    /// children's references and split budgets.
    fn split(
        &self,
        mut refs: Vec<Ref>,
        bounds: &Aabb,
        budget: usize,
        depth: u32,
    ) -> Result<(Split, usize, usize), Vec<Ref>> {
        let n = refs.len();
        let top = &self.cfg.top;
        if n <= top.max_leaf() {
            return Err(refs);
        }
        let objs = object_splits(&refs);
        // The greedy choice (Stich 4.1): the cheapest object split (lowest axis on ties) ...
        let obj = (0..3).fold(0, |b, a| if objs[a].cost < objs[b].cost { a } else { b });
        let mut best_cost = objs[obj].cost;
        let mut spatial = [None, None, None];
        // ... or spatial split. Stich 4.4: tried only where the object split's children overlap.
        let overlap = intersect(&objs[obj].lb, &objs[obj].rb);
        let lambda = if overlap.is_empty() { 0.0 } else { half_area(&overlap) };
        if budget > 0 && depth < MAX_SPATIAL_DEPTH && lambda > self.min_overlap {
            spatial = self.spatial_splits(&refs, bounds, budget);
            for s in spatial.iter().flatten() {
                best_cost = best_cost.min(s.cost);
            }
        }
        if !top.forced_single() && top.sah_prefers_leaf(n, half_area(bounds), best_cost) {
            return Err(refs);
        }
        // Candidates in order of preference on equal cost: object splits by axis, spatial by axis.
        let mut cands: Vec<(f64, Option<usize>, Option<&SpatialSplit>)> =
            (0..3).map(|a| (objs[a].cost, Some(a), None)).collect();
        cands.extend(spatial.iter().flatten().map(|s| (s.cost, None, Some(s))));
        let look = n >= LOOKAHEAD_MIN;
        let margin = if look { LOOKAHEAD_MARGIN } else { 0.0 };
        let mut splits: Vec<Split> = Vec::new();
        for (cost, o, s) in cands {
            if !(cost <= best_cost * (1.0 + margin)) || (!look && !splits.is_empty()) {
                continue;
            }
            if !look && cost > best_cost {
                continue;
            }
            match (o, s) {
                (Some(a), _) => splits.push(object_children(&refs, &objs[a])),
                (_, Some(s)) => {
                    if let Some(split) = self.apply_spatial(&refs, bounds, s) {
                        if split.left.len() + split.right.len() - n <= budget {
                            splits.push(split);
                        }
                    }
                }
                _ => {}
            }
        }
        if splits.is_empty() {
            // Only a spatial split was cheapest and it could not be applied: the object split.
            splits.push(object_children(&refs, &objs[obj]));
        }
        let pick = if splits.len() > 1 { self.best_by_subtrees(&splits) } else { 0 };
        let split = splits.swap_remove(pick);
        refs.clear();
        let used = split.left.len() + split.right.len() - n;
        let (bl, br) = share(budget - used, split.left.len(), split.right.len());
        Ok((split, bl, br))
    }

    /// Chopped binning on every axis with extent (Stich 4.2): each reference is clipped at every
    /// bin plane it crosses and each piece's box goes to its bin; entries count in the first bin,
    /// exits in the last. The best plane by `SA_L n_L + SA_R n_R`, among those whose children both
    /// hold fewer references than the node and whose duplicates fit the budget.
    fn spatial_splits(&self, refs: &[Ref], bounds: &Aabb, budget: usize) -> [Option<SpatialSplit>; 3] {
        let n = refs.len();
        let bins = self.cfg.bins as usize;
        let mut best: [Option<SpatialSplit>; 3] = [None, None, None];
        let mut bin_box = vec![Aabb::EMPTY; bins];
        let mut enter = vec![0usize; bins];
        let mut exit = vec![0usize; bins];
        let mut right_box = vec![Aabb::EMPTY; bins];
        for axis in 0..3 {
            let (lo, hi) = (bounds.min[axis], bounds.max[axis]);
            if !(lo < hi) {
                continue;
            }
            let planes = Planes::new(lo, hi, bins);
            bin_box.iter_mut().for_each(|b| *b = Aabb::EMPTY);
            enter.iter_mut().for_each(|c| *c = 0);
            exit.iter_mut().for_each(|c| *c = 0);
            for r in refs {
                let f = planes.first(r.b.min[axis]);
                let l = planes.last(r.b.max[axis], f);
                enter[f] += 1;
                exit[l] += 1;
                if f == l {
                    bin_box[f].grow(&r.b);
                    continue;
                }
                let t = &self.tris[r.tri as usize];
                let mut cur = r.b;
                for k in f..l {
                    let (a, b) = split_ref(t, &cur, axis, planes.p[k + 1]);
                    bin_box[k].grow(&a);
                    cur = b;
                    if cur.is_empty() {
                        break;
                    }
                }
                bin_box[l].grow(&cur);
            }
            let mut acc = Aabb::EMPTY;
            for k in (0..bins).rev() {
                acc.grow(&bin_box[k]);
                right_box[k] = acc;
            }
            let (mut lacc, mut n_l) = (Aabb::EMPTY, 0usize);
            let mut n_r: usize = exit.iter().sum();
            for k in 1..bins {
                lacc.grow(&bin_box[k - 1]);
                n_l += enter[k - 1];
                n_r -= exit[k - 1];
                let p = planes.p[k];
                if !(p > lo && p < hi) || n_l == 0 || n_r == 0 || n_l >= n || n_r >= n {
                    continue;
                }
                if n_l + n_r - n > budget {
                    continue;
                }
                let cost = half_area(&lacc) * n_l as f64 + half_area(&right_box[k]) * n_r as f64;
                if best[axis].as_ref().is_none_or(|b| cost < b.cost) {
                    best[axis] = Some(SpatialSplit { axis, k, cost });
                }
            }
        }
        best
    }

    /// Splits the references at the chosen plane: wholly left or right as in the binning, the rest
    /// clipped, then reference unsplitting (Stich 4.3): a straddling reference goes wholly to one
    /// side when that is cheaper than splitting it (`SA(B_L + B) n_L + SA(B_R)(n_R - 1)` against
    /// `SA(B_L) n_L + SA(B_R) n_R`, and symmetrically). `None` if no progress is made.
    fn apply_spatial(&self, refs: &[Ref], bounds: &Aabb, s: &SpatialSplit) -> Option<Split> {
        let n = refs.len();
        let axis = s.axis;
        let planes = Planes::new(bounds.min[axis], bounds.max[axis], self.cfg.bins as usize);
        let p = planes.p[s.k];
        let mut left = Vec::with_capacity(n);
        let mut right = Vec::with_capacity(n);
        // (reference, its left part, its right part)
        let mut straddle: Vec<(Ref, Aabb, Aabb)> = Vec::new();
        let (mut lb, mut rb) = (Aabb::EMPTY, Aabb::EMPTY);
        for r in refs {
            let f = planes.first(r.b.min[axis]);
            let l = planes.last(r.b.max[axis], f);
            if l < s.k {
                lb.grow(&r.b);
                left.push(*r);
            } else if f >= s.k {
                rb.grow(&r.b);
                right.push(*r);
            } else {
                let (a, b) = split_ref(&self.tris[r.tri as usize], &r.b, axis, p);
                if b.is_empty() {
                    lb.grow(&r.b);
                    left.push(*r);
                } else if a.is_empty() {
                    rb.grow(&r.b);
                    right.push(*r);
                } else {
                    lb.grow(&a);
                    rb.grow(&b);
                    straddle.push((*r, a, b));
                }
            }
        }
        let (mut n_l, mut n_r) = (left.len() + straddle.len(), right.len() + straddle.len());
        for (r, a, b) in straddle {
            let (al, ar) = (half_area(&lb), half_area(&rb));
            let c_split = al * n_l as f64 + ar * n_r as f64;
            let c_left = half_area(&lb.union(&r.b)) * n_l as f64 + ar * (n_r - 1) as f64;
            let c_right = al * (n_l - 1) as f64 + half_area(&rb.union(&r.b)) * n_r as f64;
            // Ties keep fewer references.
            if c_left <= c_split && c_left <= c_right {
                lb.grow(&r.b);
                n_r -= 1;
                left.push(r);
            } else if c_right <= c_split {
                rb.grow(&r.b);
                n_l -= 1;
                right.push(r);
            } else {
                left.push(Ref { b: a, tri: r.tri });
                right.push(Ref { b, tri: r.tri });
            }
        }
        debug_assert_eq!((n_l, n_r), (left.len(), right.len()));
        if left.is_empty() || right.is_empty() || left.len() >= n || right.len() >= n {
            return None;
        }
        Some(Split { left, right })
    }
}

/// Unnormalized SAH (half areas) of the full-sweep object-split tree over `refs` (thesis 3.3.1):
/// what a child would cost as a subtree, for [`Ctx::best_by_subtrees`].
fn subtree_estimate(refs: &[Ref], cfg: &TopDownConfig) -> f64 {
    let boxes: Vec<Aabb> = refs.iter().map(|r| r.b).collect();
    let centers: Vec<Vec3> = boxes.iter().map(|b| b.min * 0.5 + b.max * 0.5).collect();
    // The full sweep, not the binned build: binned trees are 20 % worse on conference (109.6 vs
    // 91.7) and choosing by them made the SBVH worse than the greedy choice (101.7).
    let bvh = crate::sweep_sah::build(&boxes, &centers, cfg);
    let (c_t, c_i) = (cfg.cost.c_t as f64, cfg.cost.c_i as f64);
    bvh.nodes
        .iter()
        .map(|n| if n.is_leaf() { c_i * n.count as f64 * half_area(&n.bounds) } else { c_t * half_area(&n.bounds) })
        .sum()
}

impl Ctx<'_> {
    /// Near the root the greedy SAH's assumption that both children become leaves (Stich 4.1,
    /// thesis eq. 2) misjudges splits: on conference the first spatial splits lower the node's
    /// greedy cost by 18 % and raise the tree's by 3 %. So nodes of at least `LOOKAHEAD_MIN`
    /// references choose among the candidates within `LOOKAHEAD_MARGIN` of the greedy best (the
    /// best object split of each axis, the best spatial split of each axis) by the cost of the
    /// subtrees a quick object-split build gives their children. Returns the index of the winner
    /// (the first on ties).
    fn best_by_subtrees(&self, splits: &[Split]) -> usize {
        use rayon::prelude::*;
        let top = &self.cfg.top;
        let est: Vec<f64> = splits
            .par_iter()
            .map(|s| {
                let (a, b) = rayon::join(|| subtree_estimate(&s.left, top), || subtree_estimate(&s.right, top));
                a + b
            })
            .collect();
        (0..est.len()).fold(0, |b, i| if est[i] < est[b] { i } else { b })
    }
}

/// What a node's split did not use, shared by its children in proportion to their references.
fn share(rest: usize, n_l: usize, n_r: usize) -> (usize, usize) {
    let l = (rest as u128 * n_l as u128 / (n_l + n_r) as u128) as usize;
    (l, rest - l)
}

/// Full SAH sweep over the references' centroids on each axis (thesis 3.3.1, with eq. 2 costs):
/// per axis the best split (lowest position on ties) with that axis' order (indices into `refs`).
/// Centroid ties break by triangle index: a node never holds two references of one triangle, so the
/// order is total and the tree deterministic.
fn object_splits(refs: &[Ref]) -> [ObjectSplit; 3] {
    let n = refs.len();
    let mut right_area = vec![0f64; n];
    std::array::from_fn(|axis| {
        let mut order: Vec<(u64, u32)> = refs
            .iter()
            .enumerate()
            .map(|(i, r)| (((ordered(centroid(&r.b, axis)) as u64) << 32) | r.tri as u64, i as u32))
            .collect();
        order.sort_unstable_by_key(|e| e.0);
        let mut acc = Aabb::EMPTY;
        for i in (1..n).rev() {
            acc.grow(&refs[order[i].1 as usize].b);
            right_area[i] = half_area(&acc);
        }
        let (mut n_left, mut cost) = (n / 2, f64::INFINITY);
        let mut acc = Aabb::EMPTY;
        for i in 0..n - 1 {
            acc.grow(&refs[order[i].1 as usize].b);
            let c = half_area(&acc) * (i + 1) as f64 + right_area[i + 1] * (n - i - 1) as f64;
            if c < cost {
                (n_left, cost) = (i + 1, c);
            }
        }
        let order: Vec<u32> = order.iter().map(|e| e.1).collect();
        let (mut lb, mut rb) = (Aabb::EMPTY, Aabb::EMPTY);
        for (j, &i) in order.iter().enumerate() {
            if j < n_left {
                lb.grow(&refs[i as usize].b);
            } else {
                rb.grow(&refs[i as usize].b);
            }
        }
        ObjectSplit { n_left, cost, lb, rb, order }
    })
}

/// The children of an object split: the first `n_left` references in its axis' order go left.
fn object_children(refs: &[Ref], o: &ObjectSplit) -> Split {
    let left = o.order[..o.n_left].iter().map(|&i| refs[i as usize]).collect();
    let right = o.order[o.n_left..].iter().map(|&i| refs[i as usize]).collect();
    Split { left, right }
}

fn leaf_sub(bounds: Aabb, refs: &[Ref]) -> Sub {
    Sub { nodes: vec![Node::leaf(bounds, 0, refs.len() as u32)], prims: refs.iter().map(|r| r.tri).collect() }
}

/// Parent over two subtrees in the sequential driver's order: root, the children pair, the left
/// child's descendants, then the right's.
fn merge(bounds: Aabb, l: Sub, r: Sub) -> Sub {
    let mut nodes = Vec::with_capacity(1 + l.nodes.len() + r.nodes.len());
    nodes.push(Node::inner(bounds, 1));
    let l_block = 3usize;
    let r_block = l_block + l.nodes.len() - 1;
    let l_prims = l.prims.len() as u32;
    let reloc = |n: &Node, block: usize, prim0: u32| {
        if n.is_leaf() {
            Node::leaf(n.bounds, n.first + prim0, n.count)
        } else {
            Node::inner(n.bounds, (block + n.first as usize - 1) as u32)
        }
    };
    nodes.push(reloc(&l.nodes[0], l_block, 0));
    nodes.push(reloc(&r.nodes[0], r_block, l_prims));
    nodes.extend(l.nodes[1..].iter().map(|n| reloc(n, l_block, 0)));
    nodes.extend(r.nodes[1..].iter().map(|n| reloc(n, r_block, l_prims)));
    let mut prims = l.prims;
    prims.extend_from_slice(&r.prims);
    Sub { nodes, prims }
}
