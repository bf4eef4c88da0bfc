//! Parallel Locally-Ordered Clustering (Meister and Bittner 2018, thesis 3.6).
//!
//! Clusters start as the primitives in code order. Each iteration has three phases separated by
//! barriers (thesis 3.6.1): (a) every cluster finds its approximate nearest neighbour among the `r`
//! clusters on each side, the distance being the surface area of the union of the two boxes;
//! (b) mutual nearest neighbours merge, the lower index performs the merge and the new cluster
//! takes its place, the higher index becomes invalid; (c) the valid clusters are compacted into a
//! second buffer at positions given by an exclusive prefix scan, and the buffers are swapped.
//! Iterations repeat until one cluster is left.
//!
//! Determinism: each phase is a pure function of the previous buffer. The nearest neighbour is the
//! minimum of (distance, index) (equal distances: the smaller index wins, as the paper proposes),
//! which does not depend on evaluation order; new inner-node ids come from the same prefix scan as
//! the compaction (n + merges before this iteration + merges before this cluster in this
//! iteration), never from an atomic counter. So the output is bit-identical at any thread count.
use crate::bottomup::{finish, ClusterTree};
use crate::sorted::SortedCodes;
use bvhlab_bvh::{Aabb, Bvh, CostParams};
use bvhlab_params::{Kind, Method, ParamSpec, Params, Read};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

pub const METHOD: Method = Method::new(
    "ploc",
    "parallel locally-ordered clustering (Meister and Bittner 2018; thesis 3.6), then SAH compaction",
    "Meister and Bittner 2018; thesis 3.6",
    &[ParamSpec {
        name: "radius",
        default: "10",
        kind: Kind::UInt { min: 1, max: 1 << 16 },
        about: "nearest-neighbour search radius r (thesis table 6: 10, 25, 100)",
        in_label: true,
    }],
)
// 2: the same trees; the compaction reads the cluster tree (`build_compacted`, less memory, another
//    build time): build times re-measured.
.with_version(2);

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlocConfig {
    /// Nearest-neighbour search radius r (thesis table 6; PL1/PL2/PL3 = 10/25/100).
    pub radius: u32,
}

impl PlocConfig {
    /// From the canonical parameters of [`METHOD`].
    pub fn from_params(p: &Params) -> PlocConfig {
        PlocConfig { radius: p.typed("radius") }
    }
}

/// Clusters per parallel task (the neighbour search uses at least 8 r). Chunking never changes the
/// result (see the module comment), only the cost: each chunk of the neighbour search recomputes
/// the at most r(r+1)/2 distances across its left border, and 2048 clusters keep a chunk's working
/// set (about 50 KB) near L1.
const CHUNK: usize = 2048;

/// One primitive per leaf; the caller applies the SAH compaction.
pub fn build(boxes: &[Aabb], sorted: &SortedCodes, cfg: &PlocConfig) -> Bvh {
    build_in(boxes, sorted, cfg, None)
}

/// [`build`] followed by the SAH compaction (`bvhlab_bvh::collapse`), the same bytes, without the
/// uncompacted layout in memory.
pub fn build_compacted(boxes: &[Aabb], sorted: &SortedCodes, cfg: &PlocConfig, cost: CostParams) -> Bvh {
    build_in(boxes, sorted, cfg, Some(cost))
}

fn build_in(boxes: &[Aabb], sorted: &SortedCodes, cfg: &PlocConfig, cost: Option<CostParams>) -> Bvh {
    let n = sorted.len("ploc");
    if n == 0 {
        return Bvh::default();
    }
    let (children, root) = cluster(boxes, sorted.order, cfg.radius.max(1) as usize);
    let tree = ClusterTree { leaf_prims: sorted.order, children: &children, root };
    finish(boxes, &tree, cost)
}

// `a < b ? a : b` and `a > b ? a : b`: one `minps` / `maxps` each (Rust's `f32::min` adds NaN
// handling the hot loop does not need).
use bvhlab_geom::aabb::{fmax as mx, fmin as mn};

/// Cluster boxes as six coordinate arrays (min x y z, max x y z), so the distance kernel runs over
/// consecutive clusters in SIMD lanes.
#[derive(Clone, Default)]
struct Boxes {
    c: [Vec<f32>; 6],
}

impl Boxes {
    fn with_len(n: usize) -> Boxes {
        Boxes {
            c: std::array::from_fn(|_| vec![0.0; n]),
        }
    }
}

/// The merges of PLOC over primitives in code order: returns `children` of a cluster tree whose
/// leaf `k` is the k-th primitive in code order and whose inner node `n + m` is the m-th merge,
/// and the root id.
fn cluster(boxes: &[Aabb], order: &[u32], r: usize) -> (Vec<[u32; 2]>, u32) {
    let n = order.len();
    let mut children = vec![[0u32; 2]; n.saturating_sub(1)];
    if n < 2 {
        return (children, 0);
    }
    let s = crate::simd_box::pow2_normalizer(boxes);
    let simd = avx2_available();
    // Large radii get larger chunks, so the recomputed border pairs stay a small share.
    let nn_chunk = CHUNK.max(r.saturating_mul(8));
    // The two cluster buffers (boxes and node ids), swapped after every iteration.
    let mut cur = Boxes::with_len(n);
    {
        let [a, b, c, d, e, f] = &mut cur.c;
        (a, b, c, d, e, f, order)
            .into_par_iter()
            .with_min_len(CHUNK)
            .for_each(|(a, b, c, d, e, f, &p)| {
                let bx = &boxes[p as usize];
                (*a, *b, *c) = (bx.min.x * s, bx.min.y * s, bx.min.z * s);
                (*d, *e, *f) = (bx.max.x * s, bx.max.y * s, bx.max.z * s);
            });
    }
    let mut cur_id: Vec<u32> = (0..n as u32).collect();
    // merges done so far = next free inner-node slot; c = current cluster count.
    let (mut merged, mut c) = premerge_runs(&mut cur, &mut cur_id, &mut children);
    // Zeroed allocations (calloc): their pages are touched by the parallel writes, not here.
    let mut next = Boxes::with_len(c);
    let mut next_id = vec![0u32; c];
    let mut nn = vec![0u32; n];
    // Per-chunk (kept clusters, merges).
    let mut counts: Vec<(usize, usize)> = Vec::with_capacity(n.div_ceil(CHUNK));
    while c > 1 {
        let cl: [&[f32]; 6] = std::array::from_fn(|a| &cur.c[a][..c]);
        let ids = &cur_id[..c];
        // (a) Nearest neighbours.
        nn[..c]
            .par_chunks_mut(nn_chunk)
            .enumerate()
            .for_each(|(k, out)| nearest(&cl, k * nn_chunk, out, r, simd));
        let nn = &nn[..c];
        // (b) + (c): per chunk the clusters it keeps and the merges it performs, their exclusive
        // prefix sums (positions in the new buffer, inner-node ids), then the writes.
        counts.clear();
        nn.par_chunks(CHUNK)
            .enumerate()
            .map(|(k, part)| {
                let (mut keep, mut merge) = (0, 0);
                for (o, &j) in part.iter().enumerate() {
                    let i = (k * CHUNK + o) as u32;
                    let mutual = nn[j as usize] == i;
                    keep += (!mutual || i < j) as usize;
                    merge += (mutual && i < j) as usize;
                }
                (keep, merge)
            })
            .collect_into_vec(&mut counts);
        // Split the output buffers into the disjoint slices each chunk writes (no unsafe needed).
        let (mut keep_at, mut merge_at) = (0usize, merged);
        let mut tasks = Vec::with_capacity(counts.len());
        {
            let mut dst: [&mut [f32]; 6] = next.c.each_mut().map(|v| &mut v[..]);
            let mut dst_id = &mut next_id[..];
            let mut ch = &mut children[merged..];
            for (k, &(keep, merge)) in counts.iter().enumerate() {
                let part: [&mut [f32]; 6] = std::array::from_fn(|a| {
                    let (x, rest) = std::mem::take(&mut dst[a]).split_at_mut(keep);
                    dst[a] = rest;
                    x
                });
                let (b, rest) = std::mem::take(&mut dst_id).split_at_mut(keep);
                dst_id = rest;
                let (m, rest) = std::mem::take(&mut ch).split_at_mut(merge);
                ch = rest;
                tasks.push((k, part, b, m, merge_at));
                keep_at += keep;
                merge_at += merge;
            }
        }
        tasks
            .into_par_iter()
            .for_each(|(k, dst, dst_id, ch, first_merge)| {
                // Branch-free: whether a cluster merges is a coin flip to the branch predictor. Each
                // cluster is written at w (united with its partner when it performs a merge; with
                // itself otherwise) and w only advances when it stays valid, so an invalid one is
                // overwritten by the next. The `w < len` guards are almost always true.
                let (mut w, mut m) = (0usize, 0usize);
                let (len, mlen) = (dst_id.len(), ch.len());
                for i in k * CHUNK..(k * CHUNK + CHUNK).min(c) {
                    let j = nn[i] as usize;
                    let mutual = nn[j] as usize == i;
                    let keep = !mutual || i < j;
                    let merge = mutual && i < j;
                    let p = if merge { j } else { i };
                    if w < len {
                        // The lower index merges; the new cluster takes its place (thesis 3.6.1).
                        for a in 0..3 {
                            dst[a][w] = mn(cl[a][i], cl[a][p]);
                            dst[a + 3][w] = mx(cl[a + 3][i], cl[a + 3][p]);
                        }
                        dst_id[w] = if merge {
                            (n + first_merge + m) as u32
                        } else {
                            ids[i]
                        };
                    }
                    if m < mlen {
                        ch[m] = [ids[i], ids[p]];
                    }
                    w += keep as usize;
                    m += merge as usize;
                }
                debug_assert_eq!((w, m), (len, mlen));
            });
        // Mutual pairs always exist (the pair minimizing (distance, lower index, higher index) over
        // all candidate pairs is one), so every iteration makes progress. Checked in release too:
        // a broken invariant must not become an endless loop.
        assert!(
            merge_at > merged,
            "ploc: an iteration without a mutual pair"
        );
        merged = merge_at;
        c = keep_at;
        std::mem::swap(&mut cur, &mut next);
        std::mem::swap(&mut cur_id, &mut next_id);
    }
    debug_assert_eq!(merged, n - 1);
    (children, cur_id[0])
}

/// Shortest run of identical boxes that [`premerge_runs`] merges up front.
pub(crate) const RUN: usize = 64;

/// Safeguard (not in the paper): every run of at least [`RUN`] consecutive clusters with
/// bit-identical boxes becomes one cluster, a balanced tree over the run, before the first
/// iteration. Among identical boxes every distance ties, and the paper's tie rule (smaller index)
/// makes all of them point to the leftmost one in reach, so the literal algorithm merges one pair
/// of the run per iteration: quadratic time (20k duplicates of one triangle took 5 s, 871k would
/// take hours). Any binary tree over identical boxes has the same SAH cost, and the compaction
/// makes it one leaf anyway. Merges are numbered run by run, pairs left to right, round by round.
/// Returns (merges made, clusters left); buffers are compacted in place.
fn premerge_runs(cl: &mut Boxes, ids: &mut [u32], children: &mut [[u32; 2]]) -> (usize, usize) {
    let n = ids.len();
    let same =
        |c: &Boxes, i: usize, j: usize| (0..6).all(|a| c.c[a][i].to_bits() == c.c[a][j].to_bits());
    // Runs (start, length) that start in each chunk; a chunk may read past its end to finish one.
    let runs: Vec<(usize, usize)> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .flat_map_iter(|k| {
            let mut out = Vec::new();
            let mut i = k * CHUNK;
            let end = (i + CHUNK).min(n);
            // A run that started in an earlier chunk belongs to that chunk.
            while i < end && i > 0 && same(cl, i, i - 1) {
                i += 1;
            }
            while i < end {
                let mut j = i + 1;
                while j < n && same(cl, i, j) {
                    j += 1;
                }
                if j - i >= RUN {
                    out.push((i, j - i));
                }
                i = j;
            }
            out
        })
        .collect();
    if runs.is_empty() {
        return (0, n);
    }
    let mut merged = 0;
    let mut level: Vec<u32> = Vec::new();
    let mut next: Vec<u32> = Vec::new();
    for &(start, len) in &runs {
        level.clear();
        level.extend_from_slice(&ids[start..start + len]);
        while level.len() > 1 {
            next.clear();
            for pair in level.chunks(2) {
                if let [a, b] = *pair {
                    children[merged] = [a, b];
                    next.push((n + merged) as u32);
                    merged += 1;
                } else {
                    next.push(pair[0]);
                }
            }
            std::mem::swap(&mut level, &mut next);
        }
        ids[start] = level[0];
    }
    // Compaction: each run keeps its first slot (same box, the run's root id).
    let (mut w, mut i) = (0, 0);
    let copy = |cl: &mut Boxes, ids: &mut [u32], i: usize, w: &mut usize| {
        for a in 0..6 {
            cl.c[a][*w] = cl.c[a][i];
        }
        ids[*w] = ids[i];
        *w += 1;
    };
    for &(start, len) in &runs {
        while i <= start {
            copy(cl, ids, i, &mut w);
            i += 1;
        }
        i = start + len;
    }
    while i < n {
        copy(cl, ids, i, &mut w);
        i += 1;
    }
    (merged, w)
}

/// Nearest neighbours of clusters `base .. base + out.len()` among the `r` clusters on each side.
///
/// Every pair distance is computed once and updates both ends: for each offset k = 1..=r, pairs
/// (i, i + k) over consecutive i (SIMD lanes). The best right neighbour of i takes a candidate only
/// when strictly closer (offsets grow, so equal distances keep the smaller index); the best left
/// neighbour of j = i + k takes it when closer or equal (offsets grow, so the index i shrinks).
/// Then a left candidate wins ties against a right one: overall, equal distances go to the smaller
/// index (Meister and Bittner 2018), whatever the chunking. Pairs with an end left of `base` are
/// recomputed here (at most r(r+1)/2) so that chunks are independent.
fn nearest(cl: &[&[f32]; 6], base: usize, out: &mut [u32], r: usize, simd: bool) {
    let c = cl[0].len();
    let lo = base.saturating_sub(r);
    let hi = base + out.len(); // exclusive
    let top = (hi + r).min(c); // candidates up to top - 1
                               // Best right neighbour (distance, index) of i in lo..hi; best left neighbour of j in lo..top.
    let mut rd = vec![f32::INFINITY; hi - lo];
    let mut rj = vec![0u32; hi - lo];
    let mut ld = vec![f32::INFINITY; top - lo];
    let mut lj = vec![0u32; top - lo];
    for k in 1..=r.min(c - 1 - lo) {
        let m = hi.min(c - k) - lo; // pairs (i, i + k) for i in lo..lo + m
        let a: [&[f32]; 6] = std::array::from_fn(|x| &cl[x][lo..lo + m]);
        let b: [&[f32]; 6] = std::array::from_fn(|x| &cl[x][lo + k..lo + k + m]);
        pass(
            a,
            b,
            &mut rd[..m],
            &mut rj[..m],
            &mut ld[k..k + m],
            &mut lj[k..k + m],
            lo as u32,
            k as u32,
            simd,
        );
    }
    for (x, o) in out.iter_mut().enumerate() {
        let i = base + x - lo;
        *o = if ld[i] <= rd[i] { lj[i] } else { rj[i] };
    }
}

/// One offset of [`nearest`]: distances of the pairs (a[t], b[t]) = (i0 + t, i0 + t + k). The
/// AVX2 kernel takes 8 pairs per step; the scalar loop does the rest (or everything without AVX2).
/// Both use the same IEEE operations in the same order (no FMA), so they give identical bits.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn pass(
    a: [&[f32]; 6],
    b: [&[f32]; 6],
    rd: &mut [f32],
    rj: &mut [u32],
    ld: &mut [f32],
    lj: &mut [u32],
    i0: u32,
    k: u32,
    simd: bool,
) {
    let m = rd.len();
    let a: [&[f32]; 6] = a.map(|s| &s[..m]);
    let b: [&[f32]; 6] = b.map(|s| &s[..m]);
    let (rj, ld, lj) = (&mut rj[..m], &mut ld[..m], &mut lj[..m]);
    let mut start = 0;
    #[cfg(target_arch = "x86_64")]
    if simd {
        // SAFETY: `simd` is only true when the CPU has AVX2 (`avx2_available`); every slice has
        // length m and the kernel reads and writes indices < m only.
        start = unsafe { pass_avx2(&a, &b, rd, rj, ld, lj, i0, k) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = simd;
    for t in start..m {
        let ex = mx(a[3][t], b[3][t]) - mn(a[0][t], b[0][t]);
        let ey = mx(a[4][t], b[4][t]) - mn(a[1][t], b[1][t]);
        let ez = mx(a[5][t], b[5][t]) - mn(a[2][t], b[2][t]);
        // Half the surface area of the union. Clamping to f32::MAX maps NaN and infinity (only
        // from non-finite input boxes) to one finite value: distances stay totally ordered, so
        // mutual pairs still exist, and every candidate beats the initial infinity.
        let d = mn(ex * ey + ey * ez + ez * ex, f32::MAX);
        let i = i0 + t as u32;
        if d < rd[t] {
            rd[t] = d;
            rj[t] = i + k;
        }
        if d <= ld[t] {
            ld[t] = d;
            lj[t] = i;
        }
    }
}

/// Whether [`pass_avx2`] may run (checked once per build; the result does not depend on it).
fn avx2_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The scalar loop of [`pass`] on 8 pairs at a time; returns how many pairs it did (m rounded
/// down to a multiple of 8). `_mm256_min_ps(x, y)` is `x < y ? x : y` like [`mn`], and the
/// comparisons are ordered, so NaN and ties behave exactly as in the scalar loop. Indices travel as
/// f32 bit patterns through `blendv`, which only moves bits.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
unsafe fn pass_avx2(
    a: &[&[f32]; 6],
    b: &[&[f32]; 6],
    rd: &mut [f32],
    rj: &mut [u32],
    ld: &mut [f32],
    lj: &mut [u32],
    i0: u32,
    k: u32,
) -> usize {
    use std::arch::x86_64::*;
    let m = rd.len();
    debug_assert!(
        a.iter().chain(b).all(|s| s.len() == m) && rj.len() == m && ld.len() == m && lj.len() == m
    );
    let big = _mm256_set1_ps(f32::MAX);
    let i0 = i0 as i32;
    let mut iv = _mm256_setr_epi32(i0, i0 + 1, i0 + 2, i0 + 3, i0 + 4, i0 + 5, i0 + 6, i0 + 7);
    let kv = _mm256_set1_epi32(k as i32);
    let eight = _mm256_set1_epi32(8);
    let (pa, pb) = (a.map(|s| s.as_ptr()), b.map(|s| s.as_ptr()));
    let (prd, pld) = (rd.as_mut_ptr(), ld.as_mut_ptr());
    let (prj, plj) = (rj.as_mut_ptr() as *mut f32, lj.as_mut_ptr() as *mut f32);
    let mut t = 0;
    while t + 8 <= m {
        let l = |p: *const f32| _mm256_loadu_ps(p.add(t));
        let ex = _mm256_sub_ps(
            _mm256_max_ps(l(pa[3]), l(pb[3])),
            _mm256_min_ps(l(pa[0]), l(pb[0])),
        );
        let ey = _mm256_sub_ps(
            _mm256_max_ps(l(pa[4]), l(pb[4])),
            _mm256_min_ps(l(pa[1]), l(pb[1])),
        );
        let ez = _mm256_sub_ps(
            _mm256_max_ps(l(pa[5]), l(pb[5])),
            _mm256_min_ps(l(pa[2]), l(pb[2])),
        );
        let sum = _mm256_add_ps(_mm256_mul_ps(ex, ey), _mm256_mul_ps(ey, ez));
        let d = _mm256_min_ps(_mm256_add_ps(sum, _mm256_mul_ps(ez, ex)), big);
        // Best right neighbour of i: strictly closer.
        let r0 = _mm256_loadu_ps(prd.add(t));
        let c = _mm256_cmp_ps::<_CMP_LT_OQ>(d, r0);
        _mm256_storeu_ps(prd.add(t), _mm256_blendv_ps(r0, d, c));
        let j = _mm256_castsi256_ps(_mm256_add_epi32(iv, kv));
        _mm256_storeu_ps(
            prj.add(t),
            _mm256_blendv_ps(_mm256_loadu_ps(prj.add(t)), j, c),
        );
        // Best left neighbour of i + k: closer or equal.
        let l0 = _mm256_loadu_ps(pld.add(t));
        let c = _mm256_cmp_ps::<_CMP_LE_OQ>(d, l0);
        _mm256_storeu_ps(pld.add(t), _mm256_blendv_ps(l0, d, c));
        let i = _mm256_castsi256_ps(iv);
        _mm256_storeu_ps(
            plj.add(t),
            _mm256_blendv_ps(_mm256_loadu_ps(plj.add(t)), i, c),
        );
        iv = _mm256_add_epi32(iv, eight);
        t += 8;
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The AVX2 kernel and the scalar loop find the same neighbours, ties and NaN included.
    #[test]
    fn simd_and_scalar_agree() {
        if !avx2_available() {
            return;
        }
        let mut r = bvhlab_geom::rng::SplitMix64(3);
        let n = 3000;
        let mut c: [Vec<f32>; 6] = Default::default();
        for i in 0..n {
            // Coarse values: many exact distance ties. Some NaN and infinite coordinates.
            let p: [f32; 3] = std::array::from_fn(|_| (r.next_u64() % 8) as f32);
            let e: [f32; 3] = std::array::from_fn(|_| (r.next_u64() % 3) as f32);
            for a in 0..3 {
                c[a].push(p[a]);
                c[a + 3].push(p[a] + e[a]);
            }
            if i % 97 == 5 {
                c[1][i] = f32::NAN;
            }
            if i % 89 == 7 {
                c[5][i] = f32::INFINITY;
            }
        }
        let cl: [&[f32]; 6] = std::array::from_fn(|a| &c[a][..]);
        for radius in [1, 7, 16, 40] {
            for chunk in [64, 1000, n] {
                let run = |simd| {
                    let mut nn = vec![0u32; n];
                    for (k, out) in nn.chunks_mut(chunk).enumerate() {
                        nearest(&cl, k * chunk, out, radius, simd);
                    }
                    nn
                };
                let scalar = run(false);
                assert_eq!(scalar, run(true), "r={radius} chunk={chunk}");
                // Chunking does not change the result either.
                let mut whole = vec![0u32; n];
                nearest(&cl, 0, &mut whole, radius, false);
                assert_eq!(scalar, whole, "r={radius} chunk={chunk}");
            }
        }
    }
}
