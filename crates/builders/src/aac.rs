//! Approximate Agglomerative Clustering (Gu et al. 2013; thesis 3.2).
//!
//! The primitives arrive sorted by their codes. The *constraint tree* splits a code-sorted range at
//! the first primitive whose code has the current bit set, walking the bits from the most significant
//! one down (thesis 3.2.1, binary search on the sorted codes). A range with fewer than `delta`
//! primitives is a constraint-tree leaf. Clustering runs in post order: a leaf's primitives are
//! greedily merged (closest pair by the surface area of the union box, Walter et al. 2008) until
//! `f(delta)` clusters remain; an inner node unites its children's cluster sets and merges until
//! `f(|P|)` remain, `|P|` being the node's primitive count; the root merges until one is left. The
//! reduction function is `f(x) = c x^alpha`, `c = delta^(1/2 + eps) / 2`, `alpha = 1/2 - eps`
//! (Gu et al. 2013; the thesis gives `c` and the form `c x^alpha`), so `f(delta) = delta/2`;
//! see [`reduction`] for the rounding.
//!
//! Distance-matrix reuse (thesis 3.2.2, Gu et al. figure 12): the clusters of all sets that are
//! alive at once sit in one array in post order (a left sibling's set directly before the set being
//! built), and their packed lower-triangular distance matrices are stacked the same way. Merging
//! puts the new cluster at the lower of the two positions and moves the last cluster into the higher
//! one; only the new cluster's distances are computed, and the nearest neighbour is rescanned (from
//! the matrix) only for clusters whose neighbour was one of the merged two. Uniting two sibling sets
//! computes only the cross distances.
//!
//! Parallel: constraint subtrees with at least [`PAR_MIN`] primitives are built with `rayon::join`
//! (Gu et al.'s suggested scheme: each task has its own cluster array and matrix; results are united
//! at the higher levels). A task's merges are appended in post order with its inner-node ids shifted
//! by the merges before it, so the output is the sequential one, bit for bit, at any thread count.
use crate::bottomup::{finish, ClusterTree};
use crate::simd_box::BoxA;
use crate::sorted::SortedCodes;
use bvhlab_bvh::{Aabb, Bvh, CostParams};
use bvhlab_params::{fmt_f32, Kind, Method, ParamSpec, Params, Read};
use glam::Vec3A;
use serde::{Deserialize, Serialize};

pub const METHOD: Method = Method::new(
    "aac",
    "approximate agglomerative clustering (Gu et al. 2013; thesis 3.2), then SAH compaction",
    "Gu et al. 2013; thesis 3.2",
    &[
        ParamSpec {
            name: "preset",
            default: "none",
            kind: Kind::Choice(&["hq", "fast", "none"]),
            about: "hq: delta=20 epsilon=0.1, fast: delta=4 epsilon=0.2 (thesis table 2); none: use delta/epsilon",
            in_label: false,
        },
        ParamSpec {
            name: "delta",
            default: "20",
            kind: Kind::UInt { min: 1, max: 1 << 20 },
            about: "constraint-tree leaf threshold delta (thesis 3.2)",
            in_label: true,
        },
        ParamSpec {
            name: "epsilon",
            default: "0.1",
            kind: Kind::NonNegativeFloat,
            about: "cluster-count reduction exponent term epsilon (thesis 3.2)",
            in_label: true,
        },
    ],
)
.with_finish(presets)
.with_label(label)
// 2: the same trees; the compaction reads the cluster tree (`build_compacted`, less memory, another
//    build time): build times re-measured.
.with_version(2);

/// `preset=hq|fast` fills delta / epsilon (thesis table 2); explicit values must agree with it.
/// The canonical parameters are delta and epsilon only, so `preset=hq` and `delta=20,epsilon=0.1`
/// share a key.
fn presets(given: &Params, params: &mut Params) -> Result<(), String> {
    let preset = params.remove("preset").unwrap_or_else(|| "none".into());
    let cfg = match preset.as_str() {
        "hq" => AacConfig::HQ,
        "fast" => AacConfig::FAST,
        _ => return Ok(()),
    };
    for (name, val) in [("delta", cfg.delta.to_string()), ("epsilon", fmt_f32(cfg.epsilon))] {
        if given.contains_key(name) && params.get(name) != Some(&val) {
            return Err(format!(
                "preset={preset} sets {name}={val}, but {name}={} was given; give either the preset or delta/epsilon",
                given[name]
            ));
        }
        params.insert(name.to_string(), val);
    }
    Ok(())
}

/// `aac HQ`, `aac fast` (thesis table 2), else `aac delta=.. epsilon=..`.
fn label(p: &Params) -> String {
    let c = AacConfig::from_params(p);
    if c == AacConfig::HQ {
        "aac HQ".into()
    } else if c == AacConfig::FAST {
        "aac fast".into()
    } else {
        format!("aac delta={} epsilon={}", c.delta, fmt_f32(c.epsilon))
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AacConfig {
    /// Constraint-tree leaf threshold delta (thesis table 2).
    pub delta: u32,
    /// Reduction-function exponent term epsilon (thesis table 2).
    pub epsilon: f32,
}

impl AacConfig {
    /// High Quality: delta = 20, epsilon = 0.1 (thesis table 2, "AHQ").
    pub const HQ: AacConfig = AacConfig {
        delta: 20,
        epsilon: 0.1,
    };
    /// High Performance ("fast", "ALQ"): delta = 4, epsilon = 0.2.
    pub const FAST: AacConfig = AacConfig {
        delta: 4,
        epsilon: 0.2,
    };
}

impl AacConfig {
    /// From the canonical parameters of [`METHOD`] (presets already resolved).
    pub fn from_params(p: &Params) -> AacConfig {
        AacConfig {
            delta: p.typed("delta"),
            epsilon: p.typed("epsilon"),
        }
    }
}

/// Constraint subtrees at least this large are handed to `rayon::join`. Below it a task is a few
/// hundred microseconds of work, so the join overhead is negligible.
pub const PAR_MIN: usize = 1 << 12;

/// One primitive per leaf; the caller applies the SAH compaction.
pub fn build(boxes: &[Aabb], sorted: &SortedCodes, cfg: &AacConfig) -> Bvh {
    build_in(boxes, sorted, cfg, None)
}

/// [`build`] followed by the SAH compaction (`bvhlab_bvh::collapse`), the same bytes, without the
/// uncompacted layout in memory.
pub fn build_compacted(boxes: &[Aabb], sorted: &SortedCodes, cfg: &AacConfig, cost: CostParams) -> Bvh {
    build_in(boxes, sorted, cfg, Some(cost))
}

fn build_in(boxes: &[Aabb], sorted: &SortedCodes, cfg: &AacConfig, cost: Option<CostParams>) -> Bvh {
    let n = sorted.len("aac");
    assert!(n <= boxes.len(), "aac: more sorted primitives than boxes");
    if n == 0 {
        return Bvh::default();
    }
    assert!(n < (u32::MAX / 2) as usize, "aac: cluster ids are u32");
    let inp = Input::new(boxes, sorted, cfg);
    let mut ctx = Clusters::new(n as u32);
    // Every merge lands here: no reallocation copies (they showed up in profiles).
    ctx.merges.reserve_exact(n - 1);
    let root = build_node(&mut ctx, &inp, 0, n);
    // The root keeps merging until one cluster is left (Gu et al.: CombineClusters(C, 1)); continuing
    // the greedy loop from f(n) is the same as stopping at f(n) first.
    ctx.reduce(root, 1);
    debug_assert_eq!(ctx.merges.len(), n - 1);
    let root = ctx.id[0];
    // Only the merges are needed from here on.
    let merges = std::mem::take(&mut ctx.merges);
    drop(ctx);
    let tree = ClusterTree { leaf_prims: sorted.order, children: &merges, root };
    finish(boxes, &tree, cost)
}

/// Reduction function `f(x) = c x^alpha` of Gu et al. 2013, truncated to an integer, at least 1.
/// The papers leave the rounding open; truncation reproduces the thesis' table 10 best (dragon and
/// conference, HQ and fast, all within 0.6%; rounding to nearest gives dragon HQ 1.2% below). The
/// 1e-9 guard keeps `f(delta) = delta / 2` exact for even delta despite `powf` rounding.
pub fn reduction(cfg: &AacConfig, x: usize) -> usize {
    let delta = cfg.delta.max(1) as f64;
    let eps = cfg.epsilon as f64;
    let (c, alpha) = (delta.powf(0.5 + eps) / 2.0, 0.5 - eps);
    round_target(c * (x as f64).powf(alpha))
}

fn round_target(v: f64) -> usize {
    // NaN (a NaN epsilon) and values below 1 become 1; `as` saturates huge ones.
    if v >= 1.0 {
        (v + 1e-9) as usize
    } else {
        1
    }
}

const TABLE: usize = 4096;

/// Read-only input shared by all tasks.
struct Input<'a> {
    boxes: &'a [Aabb],
    order: &'a [u32],
    codes: &'a [u64],
    delta: usize,
    c: f64,
    alpha: f64,
    table: Vec<u32>,
    /// `simd_box::pow2_normalizer` of the boxes: distances are f32 half areas of scaled boxes.
    scale: f32,
}

impl<'a> Input<'a> {
    fn new(boxes: &'a [Aabb], sorted: &SortedCodes<'a>, cfg: &AacConfig) -> Self {
        let delta = cfg.delta.max(1) as f64;
        let eps = cfg.epsilon as f64;
        let (c, alpha) = (delta.powf(0.5 + eps) / 2.0, 0.5 - eps);
        let n = sorted.order.len();
        let table = (0..TABLE.min(n + 1))
            .map(|x| round_target(c * (x as f64).powf(alpha)).min(u32::MAX as usize) as u32)
            .collect();
        Input {
            boxes,
            order: sorted.order,
            codes: sorted.codes,
            delta: cfg.delta.max(1) as usize,
            c,
            alpha,
            table,
            scale: crate::simd_box::pow2_normalizer(boxes),
        }
    }

    /// Number of clusters a constraint node with `x` primitives hands to its parent.
    #[inline]
    fn target(&self, x: usize) -> usize {
        match self.table.get(x) {
            Some(&t) => t as usize,
            None => round_target(self.c * (x as f64).powf(self.alpha)),
        }
    }

    /// Constraint-tree children of the code-sorted range `lo..hi`, or `None` for a leaf (thesis 3.2.1:
    /// fewer than delta primitives; a single primitive is always a leaf, so delta <= 1 terminates).
    ///
    /// The split bit is the highest bit in which the range's codes differ: the bits above it are
    /// common to the whole range and would only give one-sided splits, whose empty child changes
    /// nothing (the node would merge the same set to the same `f(|P|)` again). When the codes are all
    /// equal (the bits ran out) the range is split in the middle, as Gu et al.'s implementation does;
    /// both halves are non-empty, so this terminates on any input.
    #[inline]
    fn split(&self, lo: usize, hi: usize) -> Option<usize> {
        let m = hi - lo;
        if m < self.delta || m <= 1 {
            return None;
        }
        let diff = self.codes[lo] ^ self.codes[hi - 1];
        if diff == 0 {
            return Some(lo + m / 2);
        }
        let bit = 1u64 << (63 - diff.leading_zeros());
        // Sorted codes that agree above `bit`: those with `bit` clear come first.
        Some(lo + self.codes[lo..hi].partition_point(|&c| c & bit == 0))
    }

    #[inline]
    fn prim_box(&self, i: usize) -> BoxA {
        // Clamped to +-f32::MAX (NaN becomes -f32::MAX) and max >= min: coordinates are finite and
        // extents non-negative, so no distance is ever NaN (inf * 0, inf - inf) and the hot loops
        // need no NaN test. Only non-finite and inverted boxes change (the clamp was 1e38, which
        // moved finite coordinates up to 3.4e38 and wrecked trees there: issue 15).
        let b = &self.boxes[self.order[i] as usize];
        let lim = Vec3A::splat(f32::MAX);
        let min = Vec3A::from(b.min).max(-lim).min(lim);
        let max = Vec3A::from(b.max).max(-lim).min(lim).max(min);
        // Then scaled by a power of two (exact): union areas of the scaled boxes cannot overflow or
        // underflow f32 at any scene scale, and their order is the unscaled one.
        let s = Vec3A::splat(self.scale);
        BoxA {
            min: min * s,
            max: max * s,
        }
    }
}

/// Distance of two clusters: surface area of their union box (half of it; the factor does not change
/// any comparison). Never NaN for the clamped boxes of [`Input::prim_box`] (at most infinite).
#[inline(always)]
fn dist(a: &BoxA, b: &BoxA) -> f32 {
    // The union of two non-empty boxes has no negative extent: no clamp needed (as in BoxA::half_area_scaled).
    let e = a.max.max(b.max) - a.min.min(b.min);
    e.x * e.y + e.y * e.z + e.z * e.x
}

/// Offset of row `i` in a packed lower-triangular matrix (pairs (i, j), j < i).
#[inline(always)]
fn row0(i: usize) -> usize {
    i * i.saturating_sub(1) / 2
}

const NONE: u32 = u32::MAX;

/// A live cluster set: clusters `s..` of the cluster arrays, its packed lower-triangular distance
/// matrix (positions relative to `s`) at `dm[m..]`.
#[derive(Clone, Copy, Debug)]
struct Set {
    s: usize,
    m: usize,
}

/// The live cluster sets of one task, in post order (a stack), and their distance matrices, stacked
/// the same way.
///
/// Each set's matrix is packed by relative position, so the matrix of a prefix of the set is a
/// prefix of the matrix: after "new cluster to the lower index, last into the higher one" a reduced
/// set's matrix is already compact, and a left sibling's matrix is the first rows of the united
/// set's matrix (thesis 3.2.2); the right sibling's rows only move up to make room for the cross
/// distances. Every set occupies a small contiguous block, which keeps the matrix in cache.
///
/// Invariant: within each set of at least two clusters, `nn[k]` is the position (relative to the
/// set) of k's nearest neighbour (lowest position among equally near ones) and `nd[k]` its
/// distance, so the result does not depend on how the set was assembled.
struct Clusters {
    /// Number of primitives: cluster ids below it are leaves (sorted position), the rest merges.
    n: u32,
    bx: Vec<BoxA>,
    id: Vec<u32>,
    nn: Vec<u32>,
    nd: Vec<f32>,
    /// Matrix storage; `dm_len` is the used part (growing it never clears memory: every entry of a
    /// set's matrix is written before it is read).
    dm: Vec<f32>,
    dm_len: usize,
    /// Merge `j` creates cluster `n + j` from its two children (lower position first).
    merges: Vec<[u32; 2]>,
    /// Scratch: clusters whose nearest neighbour was merged away.
    stale: Vec<u32>,
}

/// Offers `(j, d)` as nearest neighbour of `k`: keeps the minimum of (distance, position), which does
/// not depend on the order of the offers.
#[inline(always)]
fn offer(nn: &mut [u32], nd: &mut [f32], k: usize, j: usize, d: f32) {
    if d < nd[k] || (d == nd[k] && (j as u32) < nn[k]) {
        nd[k] = d;
        nn[k] = j as u32;
    }
}

/// Nearest neighbour of `k` among `0..e` from a set's packed matrix: row k, then column k.
#[inline]
fn rescan(dm: &[f32], k: usize, e: usize) -> (u32, f32) {
    let (mut bn, mut bd) = (NONE, f32::INFINITY);
    let row = &dm[row0(k)..row0(k) + k];
    for (j, &d) in row.iter().enumerate() {
        if d < bd || bn == NONE {
            (bn, bd) = (j as u32, d);
        }
    }
    let mut at = row0(k + 1) + k;
    for j in k + 1..e {
        let d = dm[at];
        at += j;
        if d < bd || bn == NONE {
            (bn, bd) = (j as u32, d);
        }
    }
    (bn, bd)
}

impl Clusters {
    fn new(n: u32) -> Self {
        Clusters {
            n,
            bx: Vec::new(),
            id: Vec::new(),
            nn: Vec::new(),
            nd: Vec::new(),
            dm: Vec::new(),
            dm_len: 0,
            merges: Vec::new(),
            stale: Vec::new(),
        }
    }

    #[inline]
    fn len(&self) -> usize {
        self.bx.len()
    }

    #[inline]
    fn set_matrix_len(&mut self, len: usize) {
        if self.dm.len() < len {
            self.dm.resize(len.max(2 * self.dm.len()), 0.0);
        }
        self.dm_len = len;
    }

    /// A constraint-tree leaf: one cluster per primitive, all pairwise distances.
    fn push_leaf(&mut self, inp: &Input, lo: usize, hi: usize) -> Set {
        let set = Set {
            s: self.len(),
            m: self.dm_len,
        };
        for i in lo..hi {
            self.bx.push(inp.prim_box(i));
            self.id.push(i as u32);
            self.nn.push(NONE);
            self.nd.push(f32::INFINITY);
        }
        let k = hi - lo;
        self.set_matrix_len(set.m + row0(k));
        let (bx, nn, nd) = (
            &self.bx[set.s..],
            &mut self.nn[set.s..],
            &mut self.nd[set.s..],
        );
        let dm = &mut self.dm[set.m..];
        for i in 1..k {
            let bi = bx[i];
            for j in 0..i {
                let d = dist(&bi, &bx[j]);
                dm[row0(i) + j] = d;
                offer(nn, nd, i, j, d);
                offer(nn, nd, j, i, d);
            }
        }
        set
    }

    /// Unites the sibling sets `l` and `r` (`r` the last one; thesis 3.2.2): only the cross
    /// distances are computed; each side's matrix part and nearest neighbours are reused.
    fn cross(&mut self, l: Set, r: Set) {
        let (a, b) = (r.s - l.s, self.len() - r.s);
        debug_assert_eq!(r.m, l.m + row0(a));
        debug_assert_eq!(self.dm_len, r.m + row0(b));
        self.set_matrix_len(l.m + row0(a + b));
        let (bx, nn, nd) = (&self.bx[l.s..], &mut self.nn[l.s..], &mut self.nd[l.s..]);
        let (lbx, rbx) = bx.split_at(a);
        let (lnn, rnn) = nn.split_at_mut(a);
        let (lnd, rnd) = nd.split_at_mut(a);
        let dm = &mut self.dm[l.m..];
        // Right rows from the last one down: row i moves from row0(a) + row0(i) to row0(a + i) + a
        // (forward by a * (i + 1)), so no row overwrites one that has not moved yet.
        for i in (0..b).rev() {
            let (src, dst) = (row0(a) + row0(i), row0(a + i));
            if i <= 8 {
                // Tiny rows (most of them): a loop beats a memmove call.
                for c in (0..i).rev() {
                    dm[dst + a + c] = dm[src + c];
                }
            } else {
                dm.copy_within(src..src + i, dst + a);
            }
            // Nearest neighbours keep the minimum of (distance, position), whatever the visit order.
            let bi = rbx[i];
            let ii = (a + i) as u32;
            let (mut bn, mut bd) = match rnn[i] {
                NONE => (NONE, f32::INFINITY),
                k => (k + a as u32, rnd[i]),
            };
            let row = &mut dm[dst..dst + a];
            for (j, (((bj, slot), jn), jd)) in lbx
                .iter()
                .zip(row)
                .zip(lnn.iter_mut())
                .zip(lnd.iter_mut())
                .enumerate()
            {
                let d = dist(&bi, bj);
                *slot = d;
                // Left positions are below every right one: on a tie the first j wins.
                if d < bd || (d == bd && bn >= a as u32) {
                    (bn, bd) = (j as u32, d);
                }
                // Right positions come in decreasing order here: compare them too.
                if d < *jd || (d == *jd && ii < *jn) {
                    (*jn, *jd) = (ii, d);
                }
            }
            rnn[i] = bn;
            rnd[i] = bd;
        }
    }

    /// Greedy clustering of `set` (the last set) until `target` clusters remain (Gu et al.'s
    /// CombineClusters). A merged cluster is never nearer to a third cluster than either of its
    /// parts, so only clusters whose neighbour was one of the merged pair need a rescan.
    fn reduce(&mut self, set: Set, target: usize) {
        let target = target.max(1);
        let mut e = self.len() - set.s;
        if e <= target {
            return;
        }
        let base = self.n;
        let Clusters {
            bx,
            id,
            nn,
            nd,
            dm,
            merges,
            stale,
            ..
        } = self;
        let (bx, id, nn, nd) = (
            &mut bx[set.s..],
            &mut id[set.s..],
            &mut nn[set.s..],
            &mut nd[set.s..],
        );
        let dm = &mut dm[set.m..];
        while e > target {
            // The pair: the cluster with the smallest nearest distance (lowest position on ties).
            let (mut a, mut best) = (0, nd[0]);
            for (i, &d) in nd[..e].iter().enumerate().skip(1) {
                if d < best {
                    (a, best) = (i, d);
                }
            }
            let b = nn[a] as usize;
            let (p, q) = (a.min(b), a.max(b));
            let last = e - 1;
            id[p] = {
                merges.push([id[p], id[q]]);
                base + merges.len() as u32 - 1
            };
            bx[p] = bx[p].union(&bx[q]);
            // The last cluster fills the hole at q (thesis 3.2.2), with its distances (row `last`,
            // which stays intact until the next merge).
            let rl = row0(last);
            let moved = q != last;
            if moved {
                bx[q] = bx[last];
                id[q] = id[last];
                nn[q] = nn[last];
                nd[q] = nd[last];
                // Row q (its entry for p is rewritten below), then column q.
                let (head, tail) = dm.split_at_mut(rl);
                head[row0(q)..row0(q) + q].copy_from_slice(&tail[..q]);
                let mut at = row0(q + 1) + q;
                for (k, &d) in tail.iter().enumerate().take(last).skip(q + 1) {
                    head[at] = d;
                    at += k;
                }
            }
            e = last;
            // One pass: the new cluster's distances (row p, then column p; never into row `last`)
            // and nearest neighbour, and every other cluster's neighbour kept up to date.
            let bp = bx[p];
            let (mut bn, mut bd) = (NONE, f32::INFINITY);
            let (rp, mut col) = (row0(p), row0(p + 1) + p);
            stale.clear();
            for k in 0..e {
                if k == p {
                    continue;
                }
                let d = dist(&bp, &bx[k]);
                if k < p {
                    dm[rp + k] = d;
                } else {
                    dm[col] = d;
                    col += k;
                }
                if d < bd || bn == NONE {
                    (bn, bd) = (k as u32, d);
                }
                let t = nn[k] as usize;
                if t == p || t == q {
                    // Its neighbour was merged (q, if moved, now holds another cluster): rescan
                    // once the new cluster's distances are all in.
                    stale.push(k as u32);
                    continue;
                }
                if t == last {
                    nn[k] = q as u32;
                }
                // Keep the lowest-position tie-break exact: the new cluster and the moved one may
                // tie with the current neighbour (they cannot be strictly nearer).
                offer(nn, nd, k, p, d);
                if moved && k != q {
                    offer(nn, nd, k, q, dm[rl + k]);
                }
            }
            nn[p] = bn;
            nd[p] = bd;
            for &k in stale.iter() {
                let k = k as usize;
                (nn[k], nd[k]) = rescan(dm, k, e);
            }
        }
        let e = set.s + e;
        self.bx.truncate(e);
        self.id.truncate(e);
        self.nn.truncate(e);
        self.nd.truncate(e);
        self.dm_len = set.m + row0(e - set.s);
    }

    /// Appends another task's single set after this one's sets, as if it had been built here:
    /// inner-node ids are shifted; positions are set-relative and its matrix is already packed.
    fn append(&mut self, r: Clusters) -> Set {
        let set = Set {
            s: self.len(),
            m: self.dm_len,
        };
        let (base, n) = (self.merges.len() as u32, self.n);
        let shift = |id: u32| if id >= n { id + base } else { id };
        self.bx.extend_from_slice(&r.bx);
        self.id.extend(r.id.iter().map(|&i| shift(i)));
        self.nn.extend_from_slice(&r.nn);
        self.nd.extend_from_slice(&r.nd);
        self.merges
            .extend(r.merges.iter().map(|&[a, b]| [shift(a), shift(b)]));
        self.set_matrix_len(set.m + r.dm_len);
        self.dm[set.m..set.m + r.dm_len].copy_from_slice(&r.dm[..r.dm_len]);
        set
    }
}

enum Task {
    Visit(usize, usize),
    /// Unite the two most recent sets, then reduce to `f(primitives)`.
    Combine(usize),
}

/// Builds the constraint subtree `lo..hi`, leaving its reduced set at the end of `ctx`. Forks with
/// `rayon::join` on large subtrees: the recursion depth is bounded by the constraint-tree depth above
/// [`PAR_MIN`] primitives (at most the code bits plus the middle splits, log2 n).
fn build_node(ctx: &mut Clusters, inp: &Input, lo: usize, hi: usize) -> Set {
    let mid = match inp.split(lo, hi) {
        Some(mid) if hi - lo >= PAR_MIN && rayon::current_num_threads() > 1 => mid,
        _ => return build_seq(ctx, inp, lo, hi),
    };
    let n = ctx.n;
    let (l, right) = rayon::join(
        || build_node(ctx, inp, lo, mid),
        || {
            let mut r = Clusters::new(n);
            r.merges.reserve_exact(hi - mid);
            build_node(&mut r, inp, mid, hi);
            r
        },
    );
    let r = ctx.append(right);
    ctx.cross(l, r);
    ctx.reduce(l, inp.target(hi - lo));
    l
}

/// Sequential post-order walk of the constraint subtree `lo..hi` with an explicit stack.
fn build_seq(ctx: &mut Clusters, inp: &Input, lo: usize, hi: usize) -> Set {
    let mut tasks = vec![Task::Visit(lo, hi)];
    let mut sets: Vec<Set> = Vec::with_capacity(64);
    let leaf_target = inp.target(inp.delta);
    while let Some(t) = tasks.pop() {
        match t {
            Task::Visit(lo, hi) => match inp.split(lo, hi) {
                None => {
                    let set = ctx.push_leaf(inp, lo, hi);
                    // Thesis 3.2.1: in the constraint-tree leaves, delta is the input of f.
                    ctx.reduce(set, leaf_target);
                    sets.push(set);
                }
                Some(mid) => {
                    tasks.push(Task::Combine(hi - lo));
                    tasks.push(Task::Visit(mid, hi));
                    tasks.push(Task::Visit(lo, mid));
                }
            },
            Task::Combine(size) => {
                let r = sets.pop().expect("right set");
                let l = sets.pop().expect("left set");
                ctx.cross(l, r);
                ctx.reduce(l, inp.target(size));
                sets.push(l);
            }
        }
    }
    debug_assert_eq!(sets.len(), 1);
    sets[0]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reduction_halves_delta() {
        assert_eq!(reduction(&AacConfig::HQ, 20), 10);
        assert_eq!(reduction(&AacConfig::FAST, 4), 2);
        assert_eq!(
            reduction(
                &AacConfig {
                    delta: 1,
                    epsilon: 0.0
                },
                1
            ),
            1
        );
        assert_eq!(
            reduction(
                &AacConfig {
                    delta: 2,
                    epsilon: 0.5
                },
                1000
            ),
            1
        );
        assert_eq!(
            reduction(
                &AacConfig {
                    delta: 4,
                    epsilon: f32::NAN
                },
                10
            ),
            1
        );
        // alpha = 0.4, c = 20^0.6 / 2: f(1e6) = 3.017 * 1e6^0.4 = 757.9.
        assert_eq!(reduction(&AacConfig::HQ, 1_000_000), 757);
        // Exact at delta whatever the float rounding of the two powers (f32 epsilon included).
        for delta in [2, 4, 6, 8, 10, 20, 32, 64] {
            for epsilon in [0.0, 0.1, 0.2, 0.3, 0.5] {
                assert_eq!(
                    reduction(&AacConfig { delta, epsilon }, delta as usize),
                    delta as usize / 2
                );
            }
        }
    }
}
