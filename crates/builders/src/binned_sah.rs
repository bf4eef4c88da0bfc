//! Binned SAH (Wald 2007) as Frantal 2019 section 3.1.1 implements it: `k` equal bins over the
//! node's centroid bounds along their largest axis only, binning by eq. 6 (epsilon 1e-5), two
//! sweeps over the bins, the original SAH leaf-vs-split test (eq. 2 and 3), in-place partition,
//! iteration with an explicit stack.
use crate::primref::{
    make_refs, make_refs_parallel, object_median, partition_known_all, partition_known_bounds, partition_parallel, with_refs, Ref,
};
use crate::simd_box::BoxA;
use crate::topdown::{build_nodes, build_nodes_parallel, Range};
use crate::{TopDownConfig, LEAF};
use bvhlab_bvh::{Aabb, Bvh, Node, Vec3};
use bvhlab_params::{Kind, Method, ParamSpec};
use glam::Vec3A;
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
        ParamSpec {
            name: "axes",
            default: "largest",
            kind: Kind::Choice(&["largest", "all"]),
            about: "bin along the largest centroid axis only (Wald 2007, thesis 3.1.1; the default) or along all three \
                    in one pass over the primitives, taking the cheapest plane of any axis (as Embree and tinybvh do)",
            in_label: false,
        },
    ],
)
// 2: the same trees; the split is also compiled for AVX2 and chosen at run time (faster build):
//    build times re-measured.
// 3: the same trees; a primitive's centroid on the split axis read as two scalars instead of
//    indexing a vector by a run-time axis (a match): build times re-measured.
// 4: the same trees; the children's centroid bounds gathered per bin during binning (no pass
//    after the partition): build times re-measured.
// 5: the same trees; the largest-axis bins emptied after use (only the non-empty ones) instead of
//    filled before, and the children's boxes unioned over the non-empty bins: build times
//    re-measured.
// 6: the same trees; the all-axes binning alternates two sets of bins on nodes of 64+ primitives:
//    build times re-measured.
.with_version(6);

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

bvhlab_params::choice_from_str!(CentroidTermination {
    "split-axis" => CentroidTermination::SplitAxis,
    "any-axis" => CentroidTermination::AnyAxis,
});

/// Which axes a node bins along.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Axes {
    /// The largest axis of the centroid bounds only (Wald 2007; thesis 3.1.1). The default.
    #[default]
    Largest,
    /// All three axes in one pass over the primitives (each primitive's three bin indices from one
    /// SIMD expression), the cheapest of the `3 (k - 1)` planes wins. Lower SAH cost for about the
    /// cost of the largest-axis build (issue 19.4: tinybvh's BuildAVX and Embree bin all axes).
    All,
}

bvhlab_params::choice_from_str!(Axes { "largest" => Axes::Largest, "all" => Axes::All });

/// Everything of [`METHOD`] that shapes the tree besides [`TopDownConfig`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BinnedOptions {
    /// `k` of the thesis (16 in its tables); values below 2 are treated as 2.
    pub bins: u32,
    pub term: CentroidTermination,
    pub axes: Axes,
}

impl BinnedOptions {
    /// The thesis' configuration (largest axis) with `bins` bins and the default termination.
    pub fn new(bins: u32) -> Self {
        BinnedOptions {
            bins,
            term: CentroidTermination::default(),
            axes: Axes::default(),
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
    let opts = BinnedOptions {
        bins,
        term,
        axes: Axes::Largest,
    };
    build_with_options(boxes, centers, &opts, cfg)
}

/// The sequential build with every option.
pub fn build_with_options(
    boxes: &[Aabb],
    centers: &[Vec3],
    opts: &BinnedOptions,
    cfg: &TopDownConfig,
) -> Bvh {
    with_refs!(boxes, centers, false, build_refs(boxes, centers, opts, cfg, has_avx2()))
}

/// `avx2`: split with [`split_avx2`] (only where [`has_avx2`]).
fn build_refs<R: Ref>(boxes: &[Aabb], centers: &[Vec3], opts: &BinnedOptions, cfg: &TopDownConfig, avx2: bool) -> Bvh {
    let (mut refs, root) = make_refs::<R>(boxes, centers);
    let mut binner = Binner::new(opts.bins.max(2) as usize);
    let s = scene_scale(&root);
    let nodes = build_nodes(refs.len(), root, |r| {
        split_fastest(avx2, &mut refs, r, &mut binner, cfg, opts, s)
    });
    Bvh {
        nodes,
        prim_indices: refs.iter().map(|p| p.idx()).collect(),
    }
}

/// Nodes with at least this many primitives bin into two alternating sets ([`Binner::bin`]).
const DUAL_BINS_FROM: usize = 64;

/// Bin storage, allocated once per build and reused by every node.
struct Binner {
    k: usize,
    /// Counts and boxes of the bins, `k` per axis (`axis * k + bin`); the largest-axis build uses
    /// the first `k` (and the next `k` as scratch: the second of `bin`'s alternating sets).
    count: Vec<u32>,
    bounds: Vec<BoxA>,
    /// Centroid bounds of the bins ([`Binner::bin`] only; `2 k`, as `bounds`): the children's
    /// centroid bounds are their bins' unions (exact: min / max of the same centroids), so the
    /// partition needs no pass over the primitives to gather them.
    cbounds: Vec<BoxA>,
    /// Left-sweep results: half area and count of bins `0..=i`.
    left_area: Vec<f32>,
    left_count: Vec<u32>,
    /// The non-empty bins of the axis swept last (`k` long, the first `m` used): the sweep visits
    /// only these, and the largest-axis build unions and clears only these afterwards.
    nonempty: Vec<u32>,
    m: usize,
    /// Whether bins beyond the largest-axis build's invariant may be in use: [`Binner::bin3`]
    /// fills all `3 k` bins itself and leaves them as they are; [`Binner::bin`] expects its `2 k`
    /// bins empty (count 0, boxes empty), as [`Binner::clear_used`] leaves them.
    dirty: bool,
}

/// The best binned split of a node.
#[derive(Clone, Copy, Debug)]
struct BinSplit {
    /// Bins `0..=last_left_bin` go left.
    last_left_bin: usize,
    /// How many of the swept axis' non-empty bins go left (`Binner::nonempty[..left_bins]`).
    left_bins: usize,
    /// The axis binned (always the plan's axis with [`Axes::Largest`]).
    axis: usize,
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
    // The same bins as `(x as usize).min(k - 1)` for every x (NaN and negatives to 0, the rest
    // truncated and capped), clamped in float first so that one convert suffices.
    let f = ((c * b.s - b.cb_min) * b.k0).max(0.0).min((k - 1) as f32);
    // SAFETY: `f` is in [0, k - 1] (`max` maps NaN to 0), so it fits a u32.
    unsafe { f.to_int_unchecked::<u32>() as usize }
}

/// The binning frames of all three axes ([`Axes::All`]): eq. 6 per axis over the scaled centroids
/// (see [`Bins`]). An axis too thin to bin has `k0 = 0` (every primitive lands in its bin 0) and is
/// not swept.
#[derive(Clone, Copy, Debug)]
struct Bins3 {
    s: Vec3A,
    cb_min: Vec3A,
    k0: Vec3A,
    /// `k - 1` as f32: the bin indices are clamped to `[0, k - 1]` before the conversion.
    kmax: f32,
    /// Which axes are swept.
    live: [bool; 3],
}

impl Bins3 {
    /// Eq. 6 for one axis: exactly the lane `axis` of [`Bins3::bins_of`] (same f32 operations in
    /// the same order; `f32::max` / `min` pick the non-NaN operand like `maxps` / `minps` with the
    /// constant second, so a NaN centroid lands in bin 0 both ways; the legacy [`bin_of`] gives
    /// the same bins for every value).
    #[inline(always)]
    fn bin_of_axis(&self, c: f32, axis: usize) -> usize {
        let f = (((c * self.s[axis] - self.cb_min[axis]) * self.k0[axis]).max(0.0))
            .min(self.kmax);
        // SAFETY: `f` is in [0, k - 1] (max/min above removed NaN), so it fits a u32: one convert
        // instead of the saturating cast's range fix-ups.
        unsafe { f.to_int_unchecked::<u32>() as usize }
    }
    /// The three bin indices of a centroid at once (SSE: one mul, sub, mul, max, min, convert).
    #[inline(always)]
    fn bins_of(&self, c: Vec3A) -> [u32; 4] {
        let f = ((c * self.s - self.cb_min) * self.k0)
            .max(Vec3A::ZERO)
            .min(Vec3A::splat(self.kmax));
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{__m128i, _mm_cvttps_epi32, _mm_storeu_si128};
            let mut out = [0u32; 4];
            // SAFETY: SSE2 is part of x86_64; the store writes the 16 bytes of `out`. The values
            // are in [0, k - 1], so truncation equals the scalar `as usize`.
            #[allow(unused_unsafe)]
            unsafe {
                _mm_storeu_si128(out.as_mut_ptr() as *mut __m128i, _mm_cvttps_epi32(f.into()))
            };
            out
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            [f.x as u32, f.y as u32, f.z as u32, 0]
        }
    }
}

impl Binner {
    fn new(k: usize) -> Self {
        Binner {
            k,
            count: vec![0; 6 * k],
            bounds: vec![BoxA::EMPTY; 6 * k],
            cbounds: vec![BoxA::EMPTY; 2 * k],
            left_area: vec![0.0; k],
            left_count: vec![0; k],
            nonempty: vec![0; k],
            m: 0,
            dirty: false,
        }
    }

    /// Bins `prims` along all three axes in one pass (issue 19.4: one read of each primitive for
    /// the three axes instead of three passes).
    #[inline(always)]
    fn bin3<R: Ref>(&mut self, prims: &[R], b: &Bins3) {
        let k = self.k;
        let n3 = 3 * k;
        self.count[..n3].fill(0);
        self.bounds[..n3].fill(BoxA::EMPTY);
        self.dirty = true;
        // Slots `axis * k + bin`; the second set (`n3..`, empty between calls) as in `bin`: two
        // sets of bins, alternate primitives to each, merged exactly afterwards, so that coherent
        // neighbours do not chain every update on the previous one's store (three chains per
        // primitive here).
        let (ca, cb) = self.count.split_at_mut(n3);
        let (ba, bb) = self.bounds.split_at_mut(n3);
        let slots = |p: &R| {
            let i = b.bins_of(p.c());
            [i[0] as usize, k + i[1] as usize, 2 * k + i[2] as usize]
        };
        let (cb, bb) = (&mut cb[..n3], &mut bb[..n3]);
        let dual = prims.len() >= DUAL_BINS_FROM;
        let mut pairs = prims.chunks_exact(2);
        if dual {
            for pq in pairs.by_ref() {
                let (p, q) = (&pq[0], &pq[1]);
                let (i, j) = (slots(p), slots(q));
                let (pmin, pmax, qmin, qmax) = (p.min(), p.max(), q.min(), q.max());
                for a in 0..3 {
                    ca[i[a]] += 1;
                    ba[i[a]].grow(pmin, pmax);
                    cb[j[a]] += 1;
                    bb[j[a]].grow(qmin, qmax);
                }
            }
        }
        let rest = if dual { pairs.remainder() } else { prims };
        for p in rest {
            let i = slots(p);
            let (pmin, pmax) = (p.min(), p.max());
            for a in 0..3 {
                ca[i[a]] += 1;
                ba[i[a]].grow(pmin, pmax);
            }
        }
        if dual {
            for t in 0..n3 {
                ca[t] += std::mem::take(&mut cb[t]);
                ba[t] = ba[t].union(&std::mem::replace(&mut bb[t], BoxA::EMPTY));
            }
        }
    }

    /// The boxes of bins `0..=last` and of the rest on `axis`: the children's exact boxes.
    #[inline(always)]
    fn child_boxes(&self, axis: usize, last: usize) -> (BoxA, BoxA) {
        let b = &self.bounds[axis * self.k..(axis + 1) * self.k];
        let union = |bs: &[BoxA]| bs.iter().fold(BoxA::EMPTY, |a, b| a.union(b));
        (union(&b[..=last]), union(&b[last + 1..]))
    }

    /// After [`Binner::bin`] and [`Binner::sweep`]: the children's boxes and centroid bounds, the
    /// unions of their non-empty bins (the same values as [`Binner::child_boxes`]: an empty bin is
    /// the identity of min / max, and the order of the others is kept).
    #[inline(always)]
    fn children_of_sweep(&self, best: &BinSplit) -> ((BoxA, BoxA), (BoxA, BoxA)) {
        let (l, r) = self.nonempty[..self.m].split_at(best.left_bins);
        let union = |ids: &[u32]| {
            ids.iter().fold((BoxA::EMPTY, BoxA::EMPTY), |(b, c), &i| {
                (b.union(&self.bounds[i as usize]), c.union(&self.cbounds[i as usize]))
            })
        };
        (union(l), union(r))
    }

    /// Empties the bins [`Binner::bin`] filled (the non-empty ones found by [`Binner::sweep`]):
    /// `bin` then needs no fill of all `k` bins, which cost small nodes (most of them, with fewer
    /// primitives than bins) more than their binning.
    #[inline(always)]
    fn clear_used(&mut self) {
        for &i in &self.nonempty[..self.m] {
            let i = i as usize;
            self.count[i] = 0;
            self.bounds[i] = BoxA::EMPTY;
            self.cbounds[i] = BoxA::EMPTY;
        }
        self.m = 0;
    }

    /// Adds another binner's bins (exact: counts add, boxes take min / max).
    fn merge(&mut self, o: &Binner) {
        for (a, b) in self.count.iter_mut().zip(&o.count) {
            *a += b;
        }
        for (a, b) in self.bounds.iter_mut().zip(&o.bounds) {
            *a = a.union(b);
        }
        for (a, b) in self.cbounds.iter_mut().zip(&o.cbounds) {
            *a = a.union(b);
        }
    }

    /// The best plane over the live axes of `b`; ties go to the lower axis, then the lower plane.
    #[inline(always)]
    fn sweep3(&mut self, s: f32, b: &Bins3) -> Option<BinSplit> {
        let mut best: Option<BinSplit> = None;
        for axis in 0..3 {
            if !b.live[axis] {
                continue;
            }
            if let Some(c) = self.sweep_axis(s, axis) {
                if best.is_none_or(|b| c.cost < b.cost) {
                    best = Some(c);
                }
            }
        }
        best
    }

    /// Bins `prims` along `axis` (eq. 6) into `self.count` / `self.bounds`, and their centroids'
    /// bounds into `self.cbounds`.
    #[inline(always)]
    fn bin<R: Ref>(&mut self, prims: &[R], axis: usize, bins: &Bins) {
        let k = self.k;
        if std::mem::take(&mut self.dirty) {
            self.count.fill(0);
            self.bounds.fill(BoxA::EMPTY);
            self.cbounds.fill(BoxA::EMPTY);
        }
        debug_assert!(self.count[..2 * k].iter().all(|&c| c == 0));
        if prims.len() < DUAL_BINS_FROM {
            for p in prims {
                let b = bin_of(p.c_axis(axis), bins, k);
                self.count[b] += 1;
                self.bounds[b].grow(p.min(), p.max());
                self.cbounds[b].grow_point(p.c());
            }
            return;
        }
        // Two sets of bins, alternate primitives to each, then merged: neighbours in memory tend
        // to fall in the same bin (coherent meshes, sorted scenes), and one set chains every such
        // update on the previous one's store. The merge is exact (counts add, boxes take min / max),
        // so the bins are the single set's. The second set is the y-axis slots, unused here, and
        // emptied again by the merge.
        let (ca, cb) = self.count[..2 * k].split_at_mut(k);
        let (ba, bb) = self.bounds[..2 * k].split_at_mut(k);
        let (pa, pb) = self.cbounds[..2 * k].split_at_mut(k);
        let mut pairs = prims.chunks_exact(2);
        for pq in pairs.by_ref() {
            let (p, q) = (&pq[0], &pq[1]);
            let (i, j) = (bin_of(p.c_axis(axis), bins, k), bin_of(q.c_axis(axis), bins, k));
            ca[i] += 1;
            ba[i].grow(p.min(), p.max());
            pa[i].grow_point(p.c());
            cb[j] += 1;
            bb[j].grow(q.min(), q.max());
            pb[j].grow_point(q.c());
        }
        for p in pairs.remainder() {
            let i = bin_of(p.c_axis(axis), bins, k);
            ca[i] += 1;
            ba[i].grow(p.min(), p.max());
            pa[i].grow_point(p.c());
        }
        for i in 0..k {
            ca[i] += std::mem::take(&mut cb[i]);
            ba[i] = ba[i].union(&std::mem::replace(&mut bb[i], BoxA::EMPTY));
            pa[i] = pa[i].union(&std::mem::replace(&mut pb[i], BoxA::EMPTY));
        }
    }

    /// The two sweeps over the bins (thesis 3.1.1). Returns the cheapest candidate that puts
    /// primitives on both sides, or `None` if all centroids landed in one bin. Ties go to the
    /// lowest plane.
    /// Areas are `BoxA::half_area_scaled` by the build's power of two `s` (f32 like the original,
    /// scale-free: see [`Bins`]).
    #[inline(always)]
    fn sweep(&mut self, s: f32) -> Option<BinSplit> {
        self.sweep_axis(s, 0)
    }

    /// [`Binner::sweep`] over the bins of `axis` (`axis * k ..`), visiting only its non-empty
    /// bins: the planes between two non-empty bins all give the same children (an empty bin adds
    /// nothing to a box or a count), hence bit-identical costs, and the lowest of them, right after
    /// the left group's last non-empty bin, is the one the full sweep's tie rule keeps. So the
    /// result is the full sweep's, and small nodes (most of them: fewer primitives than bins) skip
    /// most of it.
    #[inline(always)]
    fn sweep_axis(&mut self, s: f32, axis: usize) -> Option<BinSplit> {
        let sv = Vec3A::splat(s);
        let k = self.k;
        let count = &self.count[axis * k..(axis + 1) * k];
        let bounds = &self.bounds[axis * k..(axis + 1) * k];
        // Gathered from a bit mask of the non-empty bins, 64 at a time (compares the compiler
        // vectorizes), then one step per non-empty bin: small nodes have few of them.
        let mut m = 0;
        for (w, word) in count.chunks(64).enumerate() {
            let mut mask = word.iter().enumerate().fold(0u64, |a, (i, &c)| a | (((c != 0) as u64) << i));
            while mask != 0 {
                // m <= the bin's index < k.
                self.nonempty[m] = (w * 64) as u32 + mask.trailing_zeros();
                m += 1;
                mask &= mask - 1;
            }
        }
        self.m = m;
        if m < 2 {
            return None;
        }
        let nonempty = &self.nonempty[..m];
        // Sweep 1, left to right: boxes and counts up to each non-empty bin.
        let la = &mut self.left_area[..m - 1];
        let lc = &mut self.left_count[..m - 1];
        let mut acc = BoxA::EMPTY;
        let mut n = 0;
        for ((a, c), &i) in la.iter_mut().zip(lc.iter_mut()).zip(nonempty.iter()) {
            acc = acc.union(&bounds[i as usize]);
            n += count[i as usize];
            *a = acc.half_area_scaled(sv);
            *c = n;
        }
        // Sweep 2, right to left: the plane after the j-th non-empty bin.
        let mut acc = BoxA::EMPTY;
        let mut n_r = 0;
        let mut best: Option<BinSplit> = None;
        for j in (0..m - 1).rev() {
            let i = nonempty[j + 1] as usize;
            acc = acc.union(&bounds[i]);
            n_r += count[i];
            let cost = la[j] * lc[j] as f32 + acc.half_area_scaled(sv) * n_r as f32;
            if best.is_none_or(|b| cost <= b.cost) {
                best = Some(BinSplit {
                    last_left_bin: nonempty[j] as usize,
                    left_bins: j + 1,
                    axis,
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
    Bin {
        axis: usize,
        bins: Bins,
    },
    /// [`Axes::All`]: bin along every live axis of the frame.
    Bin3 {
        bins: Bins3,
    },
}

/// The build's power of two (see [`Bins`]): from the scene box, which holds every centroid.
fn scene_scale(root: &Range) -> f32 {
    let m = root
        .bounds
        .min
        .abs()
        .max(root.bounds.max.abs())
        .max_element();
    crate::simd_box::pow2_for_max(m)
}

/// The "too small" centroid extent of a node: [`MIN_CENTROID_EXTENT_REL`] times the largest
/// extent of its box (0 for a point node; +inf never: the extent is an f64 of f32 differences).
fn min_centroid_extent(r: &Range) -> f64 {
    MIN_CENTROID_EXTENT_REL * r.bounds.max_extent_f64()
}

#[inline(always)]
fn plan(r: &Range, k: usize, cfg: &TopDownConfig, opts: &BinnedOptions, s: f32) -> Plan {
    if r.len() <= cfg.max_leaf() {
        return Plan::Leaf;
    }
    let term = opts.term;
    if opts.axes == Axes::All {
        return plan3(r, k, cfg, term, s);
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
    Plan::Bin {
        axis,
        bins: Bins {
            s,
            cb_min: cb_min_s,
            k0,
        },
    }
}

/// [`plan`] for [`Axes::All`]: the same "too small" test per axis; an axis passing it is live. With
/// no live axis the node is a leaf (object median when `leaf = 1`), as with the largest axis alone.
#[inline(always)]
fn plan3(r: &Range, k: usize, cfg: &TopDownConfig, term: CentroidTermination, s: f32) -> Plan {
    let min_ext = min_centroid_extent(r);
    let forced = cfg.forced_single();
    let kf = (k as f64 * (1.0 - BIN_EPSILON)) as f32;
    let mut live = [false; 3];
    let mut k0 = [0.0f32; 3];
    let mut cb_min = [0.0f32; 3];
    let mut any_tiny = false;
    for a in 0..3 {
        let extent = r.cbounds.max[a] as f64 - r.cbounds.min[a] as f64;
        cb_min[a] = r.cbounds.min[a] * s;
        let k0a = kf / (r.cbounds.max[a] * s - cb_min[a]);
        // As in `plan`: `>=` is false for NaN extents; a zero extent never bins.
        let ok = extent >= min_ext && extent > 0.0 && k0a.is_finite();
        live[a] = ok;
        any_tiny |= !(extent >= min_ext && extent > 0.0);
        if ok {
            k0[a] = k0a;
        } else {
            cb_min[a] = 0.0;
        }
    }
    let none = !live.iter().any(|&l| l);
    let stop = none || (term == CentroidTermination::AnyAxis && any_tiny);
    if stop && !forced {
        return Plan::Leaf;
    }
    if none {
        return Plan::Median(r.cbounds.largest_axis());
    }
    Plan::Bin3 {
        bins: Bins3 {
            s: Vec3A::splat(s),
            cb_min: Vec3A::from_array(cb_min),
            k0: Vec3A::from_array(k0),
            kmax: (k - 1) as f32,
            live,
        },
    }
}

/// After binning and sweeping: leaf, object-median fallback, or the split to partition by.
enum Decision {
    Leaf,
    Median(usize),
    Split(BinSplit),
}

#[inline(always)]
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
#[inline(always)]
fn split<R: Ref>(
    refs: &mut [R],
    r: &Range,
    binner: &mut Binner,
    cfg: &TopDownConfig,
    opts: &BinnedOptions,
    s: f32,
) -> Option<(Range, Range)> {
    let k = binner.k;
    let (axis, bins) = match plan(r, k, cfg, opts, s) {
        Plan::Leaf => return None,
        Plan::Median(axis) => return Some(object_median(refs, r, axis)),
        Plan::Bin { axis, bins } => (axis, bins),
        Plan::Bin3 { bins } => {
            binner.bin3(&refs[r.begin..r.end], &bins);
            let best = binner.sweep3(s, &bins);
            let axis = best.map_or(r.cbounds.largest_axis(), |b| b.axis);
            return match decide(best, r, axis, cfg, s) {
                Decision::Leaf => None,
                Decision::Median(axis) => Some(object_median(refs, r, axis)),
                Decision::Split(best) => Some(partition3(refs, r, &bins, &best, binner)),
            };
        }
    };
    binner.bin(&refs[r.begin..r.end], axis, &bins);
    let decision = decide(binner.sweep(s), r, axis, cfg, s);
    // The children's boxes and centroid bounds are the unions of their bins' (exact: min / max of
    // the same values), so the partition only moves the primitives. Gathering the centroid bounds
    // in the binning instead of a pass after the partition: +6 % instructions but a quarter fewer
    // cache misses, 6-14 % faster builds (docs/decisions.md).
    let children = match &decision {
        Decision::Split(best) => Some(binner.children_of_sweep(best)),
        _ => None,
    };
    binner.clear_used();
    match (decision, children) {
        (Decision::Split(best), Some((lbs, rbs))) => {
            // Re-applying the binning formula decides each primitive's side (thesis 3.1.1); it is
            // the same float expression as in `bin`, so the sides match the counts the SAH was
            // computed from.
            let last = best.last_left_bin;
            let (left, right) = partition_known_all(refs, r, lbs, rbs, |p| {
                bin_of(p.c_axis(axis), &bins, k) <= last
            });
            debug_assert!(left.len() > 0 && right.len() > 0);
            Some((left, right))
        }
        (Decision::Median(axis), _) => Some(object_median(refs, r, axis)),
        _ => None,
    }
}

/// Whether [`split_avx2`] can run here.
fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2")
            && std::is_x86_feature_detected!("bmi1")
            && std::is_x86_feature_detected!("bmi2")
            && std::is_x86_feature_detected!("lzcnt")
    }
    #[cfg(not(target_arch = "x86_64"))]
    false
}

/// [`split`], through [`split_avx2`] when `avx2` ([`has_avx2`]).
#[inline(always)]
fn split_fastest<R: Ref>(
    avx2: bool,
    refs: &mut [R],
    r: &Range,
    binner: &mut Binner,
    cfg: &TopDownConfig,
    opts: &BinnedOptions,
    s: f32,
) -> Option<(Range, Range)> {
    #[cfg(target_arch = "x86_64")]
    if avx2 {
        // SAFETY: `avx2` is `has_avx2()`: the CPU has every feature `split_avx2` is compiled for.
        return unsafe { split_avx2(refs, r, binner, cfg, opts, s) };
    }
    let _ = avx2;
    split(refs, r, binner, cfg, opts, s)
}

/// [`split`] (binning, sweep, partition: all inlined here) compiled for AVX2 with BMI and LZCNT:
/// three-operand VEX forms instead of SSE's register copies. The same operations in the same order
/// (no FMA: Rust never fuses a multiply and an add it was not asked to), so the same trees (test
/// `avx2_and_sse_builds_are_identical`). Callgrind, conference, one build: 856 M -> 755 M
/// instructions (the whole crate built for x86-64-v3: 746 M; issue 19.4).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,lzcnt,popcnt")]
unsafe fn split_avx2<R: Ref>(
    refs: &mut [R],
    r: &Range,
    binner: &mut Binner,
    cfg: &TopDownConfig,
    opts: &BinnedOptions,
    s: f32,
) -> Option<(Range, Range)> {
    split(refs, r, binner, cfg, opts, s)
}

/// The partition of an [`Axes::All`] split: each primitive's bin on the split axis, by the same
/// float expression as in [`Binner::bin3`].
#[inline(always)]
fn partition3<R: Ref>(
    refs: &mut [R],
    r: &Range,
    bins: &Bins3,
    best: &BinSplit,
    binner: &Binner,
) -> (Range, Range) {
    let (axis, last) = (best.axis, best.last_left_bin);
    let (lb, rb) = binner.child_boxes(axis, last);
    let (left, right) =
        partition_known_bounds(refs, r, lb, rb, |p| bins.bin_of_axis(p.c_axis(axis), axis) <= last);
    debug_assert!(left.len() > 0 && right.len() > 0);
    (left, right)
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
    let opts = BinnedOptions {
        bins,
        term,
        axes: Axes::Largest,
    };
    build_parallel_with_options(boxes, centers, &opts, cfg)
}

/// [`build_parallel`] with every option: the tree of [`build_with_options`] at any thread count.
pub fn build_parallel_with_options(
    boxes: &[Aabb],
    centers: &[Vec3],
    opts: &BinnedOptions,
    cfg: &TopDownConfig,
) -> Bvh {
    let threads = rayon::current_num_threads();
    if threads <= 1 {
        return build_with_options(boxes, centers, opts, cfg);
    }
    let tuning = ParallelTuning::for_size(boxes.len(), threads);
    build_parallel_options_tuned(boxes, centers, opts, cfg, tuning)
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
    let opts = BinnedOptions {
        bins,
        term,
        axes: Axes::Largest,
    };
    build_parallel_options_tuned(boxes, centers, &opts, cfg, tuning)
}

/// [`build_parallel_with_options`] with explicit speed knobs (always the parallel code path).
pub fn build_parallel_options_tuned(
    boxes: &[Aabb],
    centers: &[Vec3],
    opts: &BinnedOptions,
    cfg: &TopDownConfig,
    tuning: ParallelTuning,
) -> Bvh {
    with_refs!(boxes, centers, true, build_parallel_refs(boxes, centers, opts, cfg, tuning))
}

fn build_parallel_refs<R: Ref>(
    boxes: &[Aabb],
    centers: &[Vec3],
    opts: &BinnedOptions,
    cfg: &TopDownConfig,
    tuning: ParallelTuning,
) -> Bvh {
    use rayon::prelude::*;
    let (mut refs, root) = make_refs_parallel::<R>(boxes, centers);
    let k = opts.bins.max(2) as usize;
    let threads = rayon::current_num_threads();
    // From the whole scene (the vertical tasks see only their slice): the same bins as sequential.
    let s = scene_scale(&root);
    // Horizontal phase: a large node's binning and partition spread over the threads.
    let horizontal =
        |refs: &mut [R], flags: &mut [bool], r: &Range| -> Option<(Range, Range)> {
            let chunk = tuning.chunk(r.len(), threads);
            let (best, axis, is_left): (_, _, Box<dyn Fn(&R, usize) -> bool + Sync>) =
                match plan(r, k, cfg, opts, s) {
                    Plan::Leaf => return None,
                    Plan::Median(axis) => return Some(object_median(refs, r, axis)),
                    Plan::Bin { axis, bins } => {
                        // Per-chunk bins merged afterwards: counts add and boxes take min/max,
                        // both exact, so the merged bins equal the sequential ones whatever the
                        // chunking.
                        let mut binner = refs[r.begin..r.end]
                            .par_chunks(chunk)
                            .map(|ps| {
                                let mut b = Binner::new(k);
                                b.bin(ps, axis, &bins);
                                b
                            })
                            .reduce_with(|mut a, b| {
                                a.merge(&b);
                                a
                            })?;
                        let best = binner.sweep(s);
                        let f = move |p: &R, last: usize| bin_of(p.c_axis(axis), &bins, k) <= last;
                        (best, axis, Box::new(f))
                    }
                    Plan::Bin3 { bins } => {
                        let mut binner = refs[r.begin..r.end]
                            .par_chunks(chunk)
                            .map(|ps| {
                                let mut b = Binner::new(k);
                                b.bin3(ps, &bins);
                                b
                            })
                            .reduce_with(|mut a, b| {
                                a.merge(&b);
                                a
                            })?;
                        let best = binner.sweep3(s, &bins);
                        let axis = best.map_or(r.cbounds.largest_axis(), |b| b.axis);
                        let f =
                            move |p: &R, last: usize| bins.bin_of_axis(p.c_axis(axis), axis) <= last;
                        (best, axis, Box::new(f))
                    }
                };
            match decide(best, r, axis, cfg, s) {
                Decision::Leaf => None,
                Decision::Median(axis) => Some(object_median(refs, r, axis)),
                Decision::Split(best) => {
                    let last = best.last_left_bin;
                    let f = &mut flags[r.begin..r.end];
                    let (left, right) = partition_parallel(refs, r, f, chunk, |p| is_left(p, last));
                    debug_assert!(left.len() > 0 && right.len() > 0);
                    Some((left, right))
                }
            }
        };
    // Vertical phase: each small subtree is the sequential builder on its own slice.
    let avx2 = has_avx2();
    let vertical = |refs: &mut [R], r: &Range| -> Vec<Node> {
        let mut binner = Binner::new(k);
        build_nodes(r.len(), *r, |r| split_fastest(avx2, refs, r, &mut binner, cfg, opts, s))
    };
    let nodes = build_nodes_parallel(&mut refs, root, tuning.vertical_min, horizontal, vertical);
    Bvh {
        nodes,
        prim_indices: refs.par_iter().map(|p| p.idx()).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::primref::{centres_are_box_centres, BoxRef, PrimRef};

    /// The AVX2 build of the split ([`split_avx2`]) gives the SSE build's trees, byte for byte.
    #[test]
    fn avx2_and_sse_builds_are_identical() {
        if !has_avx2() {
            eprintln!("no AVX2 here: nothing to compare");
            return;
        }
        for spec in ["gen:sphere:n=5000", "gen:degenerate:n=2000", "gen:outlier:n=3000,e=25", "gen:scale:n=2000,s=1e-30", "gen:city:blocks=3"] {
            let (boxes, centers) = bvhlab_geom::load_scene(spec).unwrap().boxes_and_centers();
            let shifted: Vec<Vec3> = centers.iter().map(|c| *c + Vec3::splat(1e-3)).collect();
            for opts in [BinnedOptions::new(16), BinnedOptions::new(32), BinnedOptions { axes: Axes::All, ..BinnedOptions::new(8) }] {
                let cfg = TopDownConfig::default();
                let sse = build_refs::<BoxRef>(&boxes, &centers, &opts, &cfg, false);
                assert!(sse.nodes.len() > 1, "{spec}");
                let avx = build_refs::<BoxRef>(&boxes, &centers, &opts, &cfg, true);
                assert!(sse.canonical_bytes() == avx.canonical_bytes(), "{spec} {opts:?}");
                let sse = build_refs::<PrimRef>(&boxes, &shifted, &opts, &cfg, false);
                let avx = build_refs::<PrimRef>(&boxes, &shifted, &opts, &cfg, true);
                assert!(sse.canonical_bytes() == avx.canonical_bytes(), "{spec} {opts:?} other centres");
            }
        }
    }

    /// A binner reused node after node (bins emptied after use, not filled before) bins, sweeps
    /// and gives children exactly as a fresh one does with every bin visited, small and large
    /// nodes, 16 and 32 bins, also after an all-axes binning left every bin in use.
    #[test]
    fn reused_binner_equals_a_fresh_one() {
        let (boxes, centers) = bvhlab_geom::load_scene("gen:sphere:n=3000").unwrap().boxes_and_centers();
        let (refs, root) = make_refs::<BoxRef>(&boxes, &centers);
        let s = scene_scale(&root);
        let opts = BinnedOptions::new(16);
        let cfg = TopDownConfig::default();
        for k in [16usize, 32] {
            let mut reused = Binner::new(k);
            // Slices of many sizes and places: fewer primitives than bins, and both binning loops.
            let mut splits = 0;
            for (i, len) in [1usize, 3, 7, 40, 63, 64, 65, 200, 1000, 2, 17, 500].into_iter().cycle().take(40).enumerate() {
                let begin = (i * 211) % (refs.len() - len);
                let part = &refs[begin..begin + len];
                let (b, c) = crate::primref::bounds_of(part);
                let r = Range { begin: 0, end: len, bounds: b, cbounds: c };
                if i % 7 == 3 {
                    // Leaves every bin of all three axes in use.
                    let all = BinnedOptions { axes: Axes::All, ..BinnedOptions::new(k as u32) };
                    if let Plan::Bin3 { bins } = plan(&r, k, &TopDownConfig::default(), &all, s) {
                        reused.bin3(part, &bins);
                    }
                }
                let Plan::Bin { axis, bins } = plan(&r, k, &TopDownConfig { leaf: 1, ..cfg }, &opts, s) else {
                    continue;
                };
                let mut fresh = Binner::new(k);
                fresh.bin(part, axis, &bins);
                reused.bin(part, axis, &bins);
                assert_eq!(fresh.count[..k], reused.count[..k], "k {k} slice {i}");
                assert_eq!(fresh.bounds[..k], reused.bounds[..k], "k {k} slice {i}");
                assert_eq!(fresh.cbounds[..k], reused.cbounds[..k], "k {k} slice {i}");
                let (a, b) = (fresh.sweep(s), reused.sweep(s));
                assert_eq!(a.map(|a| (a.last_left_bin, a.cost.to_bits())), b.map(|b| (b.last_left_bin, b.cost.to_bits())));
                if let Some(best) = b {
                    splits += 1;
                    let last = best.last_left_bin;
                    let union = |bs: &[BoxA]| bs.iter().fold(BoxA::EMPTY, |a, b| a.union(b));
                    let every = (
                        (union(&fresh.bounds[..=last]), union(&fresh.cbounds[..=last])),
                        (union(&fresh.bounds[last + 1..k]), union(&fresh.cbounds[last + 1..k])),
                    );
                    assert_eq!(reused.children_of_sweep(&best), every, "k {k} slice {i}");
                }
                reused.clear_used();
                assert!(reused.count.iter().all(|&c| c == 0) || reused.dirty);
            }
            assert!(splits > 20, "{splits}");
        }
    }

    /// The 32-byte references (centre recomputed from the box) and the 48-byte ones (centre
    /// stored) give identical trees when the centres are the boxes' centres, sequential and
    /// parallel, largest axis and all axes; other centres take the 48-byte path and are used.
    #[test]
    fn both_references_build_the_same_tree() {
        let tiny = ParallelTuning { vertical_min: 64, min_chunk: 16 };
        for spec in ["gen:sphere:n=3000", "gen:degenerate:n=2000", "gen:outlier:n=2000,e=20", "gen:scale:n=2000,s=1e30"] {
            let (boxes, centers) = bvhlab_geom::load_scene(spec).unwrap().boxes_and_centers();
            assert!(centres_are_box_centres(&boxes, &centers, false), "{spec}");
            assert!(centres_are_box_centres(&boxes, &centers, true), "{spec}");
            for frame in [crate::spatial_median::Frame::Centroids, crate::spatial_median::Frame::Node] {
                let cfg = TopDownConfig::default();
                let a = crate::spatial_median::build_refs::<BoxRef>(&boxes, &centers, &cfg, frame);
                let b = crate::spatial_median::build_refs::<PrimRef>(&boxes, &centers, &cfg, frame);
                assert_eq!(a, b, "{spec} spatial median {frame:?}");
            }
            for opts in [BinnedOptions::new(16), BinnedOptions { bins: 8, axes: Axes::All, ..BinnedOptions::new(8) }] {
                let cfg = TopDownConfig::default();
                let a = build_refs::<BoxRef>(&boxes, &centers, &opts, &cfg, has_avx2());
                let b = build_refs::<PrimRef>(&boxes, &centers, &opts, &cfg, has_avx2());
                assert_eq!(a, b, "{spec} {opts:?}");
                let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
                let (pa, pb) = pool.install(|| {
                    (
                        build_parallel_refs::<BoxRef>(&boxes, &centers, &opts, &cfg, tiny),
                        build_parallel_refs::<PrimRef>(&boxes, &centers, &opts, &cfg, tiny),
                    )
                });
                assert_eq!(pa, a, "{spec} {opts:?} parallel");
                assert_eq!(pb, a, "{spec} {opts:?} parallel");
                // Centres at the boxes' minimum corners: not box centres, so the 48-byte path.
                let corners: Vec<Vec3> = boxes.iter().map(|b| b.min).collect();
                assert!(!centres_are_box_centres(&boxes, &corners, false) || boxes.iter().all(|b| b.min == b.max));
                let c = build_with_options(&boxes, &corners, &opts, &cfg);
                assert_eq!(c, build_refs::<PrimRef>(&boxes, &corners, &opts, &cfg, has_avx2()), "{spec} {opts:?} corners");
                bvhlab_bvh::validate(&c, &boxes).unwrap();
            }
        }
    }
}
