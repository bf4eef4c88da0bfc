//! Binned SAH (Wald 2007) as Frantal 2019 section 3.1.1 implements it: `k` equal bins over the
//! node's centroid bounds along their largest axis only, binning by eq. 6 (epsilon 1e-5), two
//! sweeps over the bins, the original SAH leaf-vs-split test (eq. 2 and 3), in-place partition,
//! iteration with an explicit stack.
use crate::simd_box::BoxA;
use crate::primref::{
    make_refs, make_refs_parallel, object_median, partition, partition_parallel, PrimRef,
};
use crate::topdown::{build_nodes, build_nodes_parallel, Range};
use crate::{TopDownConfig, LEAF};
use bvhlab_bvh::{Aabb, Bvh, Node, Vec3};
use bvhlab_params::{Kind, Method, ParamSpec};
use serde::{Deserialize, Serialize};

/// Registered with [`build_parallel`] (thesis 3.1.2).
pub const METHOD: Method = Method::new(
    "binned-sah",
    "binned SAH (Wald 2007; thesis 3.1.1), parallel (thesis 3.1.2)",
    "Wald 2007; thesis 3.1.1",
    &[
        ParamSpec {
            name: "bins",
            default: "16",
            kind: Kind::UInt { min: 2, max: 4096 },
            about: "number of bins per axis",
            in_label: true,
        },
        LEAF,
        ParamSpec {
            name: "centroid_stop",
            default: "split-axis",
            kind: Kind::Choice(&["split-axis", "any-axis"]),
            about: "stop when the centroid extent is < 1e-7 of the node box along the split axis (default) or along any \
                    axis (the thesis' literal rule, 3.1.1; reproduces its BIN column)",
            in_label: false,
        },
    ],
);

/// Eq. 6's epsilon: shifts every centroid slightly left so the right boundary needs no special case.
const BIN_EPSILON: f64 = 1e-5;
/// Thesis 3.1.1: stop when the centroid bounds become "too small" (extent below 1e-7); see
/// [`CentroidTermination`] for which extent is tested. The thesis' 1e-7 is absolute (its scenes are
/// of unit size); bvhlab takes it relative to the node's own box (largest extent), so that a scene in
/// nanometres is split like the same scene in metres (issue 15: an absolute 1e-7 made every scene
/// smaller than 1e-7 a single leaf). Relative to the node, not the scene: a far outlier (thesis 4.3,
/// Riemersma) must not make the rest of the scene "too small" to split.
const MIN_CENTROID_EXTENT_REL: f64 = 1e-7;

/// Which centroid-bounds extent the "centroid bounds too small" termination (Wald 2007, thesis
/// 3.1.1) looks at.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum CentroidTermination {
    /// Stop when the extent along the chosen (largest) centroid axis is below 1e-7, i.e. when the
    /// centroids are that close in *every* dimension and no plane can separate them. The default.
    #[default]
    SplitAxis,
    /// The thesis' literal wording: stop when the extent along *any* dimension is below 1e-7.
    /// Every node whose centroids lie in one axis-aligned plane (a floor, a wall, a flat scene at
    /// the root) then becomes a leaf however many primitives it holds; this raises the SAH cost of
    /// architectural scenes. Kept to reproduce the thesis' BIN column.
    AnyAxis,
}

impl std::str::FromStr for CentroidTermination {
    type Err = ();
    fn from_str(s: &str) -> Result<CentroidTermination, ()> {
        match s {
            "split-axis" => Ok(CentroidTermination::SplitAxis),
            "any-axis" => Ok(CentroidTermination::AnyAxis),
            _ => Err(()),
        }
    }
}

/// `bins` is `k` of the thesis (16 in its tables); values below 2 are treated as 2.
pub fn build(boxes: &[Aabb], centers: &[Vec3], bins: u32, cfg: &TopDownConfig) -> Bvh {
    build_with_termination(boxes, centers, bins, cfg, CentroidTermination::default())
}

/// [`build`] with an explicit choice of the centroid-bounds termination rule.
pub fn build_with_termination(
    boxes: &[Aabb],
    centers: &[Vec3],
    bins: u32,
    cfg: &TopDownConfig,
    term: CentroidTermination,
) -> Bvh {
    let (mut refs, root) = make_refs(boxes, centers);
    let mut binner = Binner::new(bins.max(2) as usize);
    let s = scene_scale(&root);
    let nodes = build_nodes(refs.len(), root, |r| {
        split(&mut refs, r, &mut binner, cfg, term, s)
    });
    Bvh {
        nodes,
        prim_indices: refs.iter().map(|p| p.idx).collect(),
    }
}

/// Bin storage, allocated once per build and reused by every node.
struct Binner {
    k: usize,
    count: Vec<u32>,
    bounds: Vec<BoxA>,
    /// Left-sweep results: half area and count of bins `0..=i`.
    left_area: Vec<f32>,
    left_count: Vec<u32>,
}

/// The best binned split of a node.
#[derive(Clone, Copy, Debug)]
struct BinSplit {
    /// Bins `0..=last_left_bin` go left.
    last_left_bin: usize,
    /// `SA_L * n_L + SA_R * n_R` (half areas, f64).
    cost: f32,
}

/// Eq. 6's binning frame of one node, over centroids scaled by the build's power of two `s`
/// (`simd_box::pow2_for_max` of the scene: every scaled coordinate is in [-1, 1], so `c s - cb_min`
/// cannot overflow, as it did for centroids at -3e38 and 3e38; the scaling is exact, so a scene
/// times 2^k gets the same bins). f32, as fast as the unscaled original (f64 here and in the bin
/// sweep cost the build 12 %).
#[derive(Clone, Copy, Debug)]
struct Bins {
    s: f32,
    cb_min: f32,
    k0: f32,
}

/// Eq. 6 (in the form of eq. 7): `bin = (c - cb_min) * k0` with `k0 = k (1 - eps) / extent`,
/// clamped so float rounding can never index past the last bin (NaN maps to bin 0).
#[inline(always)]
fn bin_of(c: f32, b: &Bins, k: usize) -> usize {
    (((c * b.s - b.cb_min) * b.k0) as usize).min(k - 1)
}

impl Binner {
    fn new(k: usize) -> Self {
        Binner {
            k,
            count: vec![0; k],
            bounds: vec![BoxA::EMPTY; k],
            left_area: vec![0.0; k],
            left_count: vec![0; k],
        }
    }

    /// Bins `prims` along `axis` (eq. 6) into `self.count` / `self.bounds`.
    fn bin(&mut self, prims: &[PrimRef], axis: usize, bins: &Bins) {
        let k = self.k;
        self.count.fill(0);
        self.bounds.fill(BoxA::EMPTY);
        for p in prims {
            let b = bin_of(p.c[axis], bins, k);
            self.count[b] += 1;
            self.bounds[b].grow(p.min, p.max);
        }
    }

    /// The two sweeps over the bins (thesis 3.1.1). Returns the cheapest candidate that puts
    /// primitives on both sides, or `None` if all centroids landed in one bin. Ties go to the
    /// lowest plane.
    /// Areas are `BoxA::half_area_scaled` by the build's power of two `s` (f32 like the original,
    /// scale-free: see [`Bins`]).
    fn sweep(&mut self, s: f32) -> Option<BinSplit> {
        let s = glam::Vec3A::splat(s);
        let k = self.k;
        // Sweep 1, left to right: accumulate counts and boxes left of each plane.
        let mut acc = BoxA::EMPTY;
        let mut n = 0;
        for i in 0..k - 1 {
            acc = acc.union(&self.bounds[i]);
            n += self.count[i];
            self.left_area[i] = acc.half_area_scaled(s);
            self.left_count[i] = n;
        }
        // Sweep 2, right to left: evaluate the k-1 planes (plane i lies between bins i and i+1).
        let mut best: Option<BinSplit> = None;
        let mut acc = BoxA::EMPTY;
        let mut n_r = 0;
        for i in (0..k - 1).rev() {
            acc = acc.union(&self.bounds[i + 1]);
            n_r += self.count[i + 1];
            let n_l = self.left_count[i];
            if n_l == 0 || n_r == 0 {
                continue;
            }
            let cost = self.left_area[i] * n_l as f32 + acc.half_area_scaled(s) * n_r as f32;
            if best.is_none_or(|b| cost <= b.cost) {
                best = Some(BinSplit {
                    last_left_bin: i,
                    cost,
                });
            }
        }
        best
    }
}

/// What a node needs before its primitives are looked at.
enum Plan {
    Leaf,
    /// Centroids too close to bin (only with `leaf = 1`): object median on this axis.
    Median(usize),
    Bin { axis: usize, bins: Bins },
}

/// The build's power of two (see [`Bins`]): from the scene box, which holds every centroid.
fn scene_scale(root: &Range) -> f32 {
    let m = root.bounds.min.abs().max(root.bounds.max.abs()).max_element();
    crate::simd_box::pow2_for_max(m)
}

/// The "too small" centroid extent of a node: [`MIN_CENTROID_EXTENT_REL`] times the largest
/// extent of its box (0 for a point node; +inf never: the extent is an f64 of f32 differences).
fn min_centroid_extent(r: &Range) -> f64 {
    MIN_CENTROID_EXTENT_REL * r.bounds.max_extent_f64()
}

fn plan(r: &Range, k: usize, cfg: &TopDownConfig, term: CentroidTermination, s: f32) -> Plan {
    if r.len() <= cfg.max_leaf() {
        return Plan::Leaf;
    }
    let min_ext = min_centroid_extent(r);
    let forced = cfg.forced_single();
    let axis = r.cbounds.largest_axis();
    let (cb_min, cb_max) = (r.cbounds.min[axis] as f64, r.cbounds.max[axis] as f64);
    let extent = cb_max - cb_min;
    // The scaled frame; its k0 is finite unless the scaled extent is below ~2^-124 (centroids that
    // close, relative to the scene's largest coordinate, count as too close to bin).
    let cb_min_s = r.cbounds.min[axis] * s;
    let k0 = (k as f64 * (1.0 - BIN_EPSILON)) as f32 / (r.cbounds.max[axis] * s - cb_min_s);
    // `>=` is false for NaN extents too, so those count as too small; a zero extent never bins.
    let tiny = !(extent >= min_ext && extent > 0.0 && k0.is_finite());
    let min_extent = (r.cbounds.max.as_dvec3() - r.cbounds.min.as_dvec3()).min_element();
    let stop = tiny
        || (term == CentroidTermination::AnyAxis && !(min_extent >= min_ext && min_extent > 0.0));
    if stop && !forced {
        return Plan::Leaf;
    }
    if tiny {
        // leaf = 1 disables early termination; binning cannot separate these centroids.
        return Plan::Median(axis);
    }
    Plan::Bin { axis, bins: Bins { s, cb_min: cb_min_s, k0 } }
}

/// After binning and sweeping: leaf, object-median fallback, or the split to partition by.
enum Decision {
    Leaf,
    Median(usize),
    Split(BinSplit),
}

fn decide(best: Option<BinSplit>, r: &Range, axis: usize, cfg: &TopDownConfig, s: f32) -> Decision {
    let forced = cfg.forced_single();
    let Some(best) = best else {
        // All centroids in one bin (only possible through float rounding at extreme coordinates).
        return if forced {
            Decision::Median(axis)
        } else {
            Decision::Leaf
        };
    };
    let node_area = r.bounds.half_area_scaled(glam::Vec3A::splat(s)) as f64;
    if !forced && cfg.sah_prefers_leaf(r.len(), node_area, best.cost as f64) {
        return Decision::Leaf;
    }
    Decision::Split(best)
}

/// The split decision for one node: `None` makes a leaf.
fn split(
    refs: &mut [PrimRef],
    r: &Range,
    binner: &mut Binner,
    cfg: &TopDownConfig,
    term: CentroidTermination,
    s: f32,
) -> Option<(Range, Range)> {
    let k = binner.k;
    let (axis, bins) = match plan(r, k, cfg, term, s) {
        Plan::Leaf => return None,
        Plan::Median(axis) => return Some(object_median(refs, r, axis)),
        Plan::Bin { axis, bins } => (axis, bins),
    };
    binner.bin(&refs[r.begin..r.end], axis, &bins);
    match decide(binner.sweep(s), r, axis, cfg, s) {
        Decision::Leaf => None,
        Decision::Median(axis) => Some(object_median(refs, r, axis)),
        Decision::Split(best) => {
            // Re-applying the binning formula decides each primitive's side (thesis 3.1.1); it is
            // the same float expression as in `bin`, so the sides match the counts the SAH was
            // computed from.
            let last = best.last_left_bin;
            let (left, right) = partition(refs, r, |p| bin_of(p.c[axis], &bins, k) <= last);
            debug_assert!(left.len() > 0 && right.len() > 0);
            Some((left, right))
        }
    }
}

/// Speed knobs of [`build_parallel_tuned`]. The tree never depends on them (tests set them tiny to
/// exercise every code path on small inputs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ParallelTuning {
    /// Nodes with fewer primitives become independent tasks (vertical phase); larger nodes are
    /// split by all threads together (horizontal phase).
    pub vertical_min: usize,
    /// Smallest work item (primitives) of the horizontal phase's parallel binning and partition;
    /// a node of `n` primitives is cut into about 4 items per thread, none smaller than this.
    pub min_chunk: usize,
}

impl ParallelTuning {
    /// For `n` primitives and `threads` threads: about 16 vertical tasks per thread (enough for
    /// rayon's work stealing to even out unequal subtrees), at least 4096 primitives each.
    pub fn for_size(n: usize, threads: usize) -> Self {
        ParallelTuning {
            vertical_min: (n / (16 * threads.max(1))).max(4096),
            min_chunk: 1024,
        }
    }
    /// Work-item size for a node of `n` primitives.
    fn chunk(&self, n: usize, threads: usize) -> usize {
        n.div_ceil(4 * threads.max(1)).max(self.min_chunk).max(1)
    }
}

/// The parallel binned SAH (thesis 3.1.2, Wald's mixed horizontal/vertical scheme) on the current
/// rayon pool. Gives exactly the tree (same bytes) of [`build_with_termination`] at any thread
/// count; with one thread it runs the sequential builder.
pub fn build_parallel(
    boxes: &[Aabb],
    centers: &[Vec3],
    bins: u32,
    cfg: &TopDownConfig,
    term: CentroidTermination,
) -> Bvh {
    let threads = rayon::current_num_threads();
    if threads <= 1 {
        return build_with_termination(boxes, centers, bins, cfg, term);
    }
    let tuning = ParallelTuning::for_size(boxes.len(), threads);
    build_parallel_tuned(boxes, centers, bins, cfg, term, tuning)
}

/// [`build_parallel`] with explicit speed knobs (always takes the parallel code path).
pub fn build_parallel_tuned(
    boxes: &[Aabb],
    centers: &[Vec3],
    bins: u32,
    cfg: &TopDownConfig,
    term: CentroidTermination,
    tuning: ParallelTuning,
) -> Bvh {
    use rayon::prelude::*;
    let (mut refs, root) = make_refs_parallel(boxes, centers);
    let k = bins.max(2) as usize;
    let threads = rayon::current_num_threads();
    // From the whole scene (the vertical tasks see only their slice): the same bins as sequential.
    let s = scene_scale(&root);
    // Horizontal phase: a large node's binning and partition spread over the threads.
    let horizontal =
        |refs: &mut [PrimRef], flags: &mut [bool], r: &Range| -> Option<(Range, Range)> {
            let (axis, bins) = match plan(r, k, cfg, term, s) {
                Plan::Leaf => return None,
                Plan::Median(axis) => return Some(object_median(refs, r, axis)),
                Plan::Bin { axis, bins } => (axis, bins),
            };
            let chunk = tuning.chunk(r.len(), threads);
            // Per-chunk bins merged afterwards: counts add and boxes take min/max, both exact, so
            // the merged bins equal the sequential ones whatever the chunking.
            let (count, bounds) = refs[r.begin..r.end]
                .par_chunks(chunk)
                .map(|ps| {
                    let mut count = vec![0u32; k];
                    let mut bounds = vec![BoxA::EMPTY; k];
                    for p in ps {
                        let b = bin_of(p.c[axis], &bins, k);
                        count[b] += 1;
                        bounds[b].grow(p.min, p.max);
                    }
                    (count, bounds)
                })
                .reduce_with(|mut a, b| {
                    for i in 0..k {
                        a.0[i] += b.0[i];
                        a.1[i] = a.1[i].union(&b.1[i]);
                    }
                    a
                })?;
            let mut binner = Binner::new(k);
            binner.count.copy_from_slice(&count);
            binner.bounds.copy_from_slice(&bounds);
            match decide(binner.sweep(s), r, axis, cfg, s) {
                Decision::Leaf => None,
                Decision::Median(axis) => Some(object_median(refs, r, axis)),
                Decision::Split(best) => {
                    let last = best.last_left_bin;
                    let f = &mut flags[r.begin..r.end];
                    let (left, right) = partition_parallel(refs, r, f, chunk, |p| {
                        bin_of(p.c[axis], &bins, k) <= last
                    });
                    debug_assert!(left.len() > 0 && right.len() > 0);
                    Some((left, right))
                }
            }
        };
    // Vertical phase: each small subtree is the sequential builder on its own slice.
    let vertical = |refs: &mut [PrimRef], r: &Range| -> Vec<Node> {
        let mut binner = Binner::new(k);
        build_nodes(r.len(), *r, |r| split(refs, r, &mut binner, cfg, term, s))
    };
    let nodes = build_nodes_parallel(&mut refs, root, tuning.vertical_min, horizontal, vertical);
    Bvh {
        nodes,
        prim_indices: refs.par_iter().map(|p| p.idx).collect(),
    }
}
