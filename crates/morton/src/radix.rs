//! Parallel stable radix sort of (code, primitive index) pairs (thesis 2.3.4: linear BVHs reduce
//! construction to a radix sort; Gu et al. and Karras sort with a parallel radix sort).
//!
//! Only the bits that differ between keys are sorted: `mask = OR_i (k_i XOR k_0)`; all-equal keys
//! cost nothing, and runs of constant bits are skipped.
//!
//! Small inputs (<= 32 Ki keys): one sequential LSD with 8-bit digits.
//! Large inputs: one parallel pass on the most significant varying digit (up to 11 bits, sized so
//! buckets hold about 4 Ki keys and fit the cache), then every bucket is LSD-sorted on its own
//! varying bits (8-bit digits, all histograms from one read), in parallel over buckets. Main
//! memory is scattered over once instead of once per digit: a plain parallel LSD with 11-bit
//! digits took 2.2 s for 10 M random 64-bit keys on the team machine, this takes well under 1 s
//! (`examples/radix_bench.rs`). Buckets above 256 Ki keys (a dense object beside a far outlier)
//! get parallel LSD passes of up to `DIGIT_BITS` bits.
//!
//! A parallel pass: per-chunk digit histograms, exclusive prefix sums in (digit, chunk) order,
//! then every chunk scatters to its own disjoint output ranges. Every pass is stable, so the result
//! is the unique stable order (ties keep input = index order) whatever the chunking: identical
//! output at any thread count.
use rayon::prelude::*;

/// Widest digit of the parallel passes over main memory (first pass, and buckets too large for
/// the cache): 11 bits (2048 buckets) needs 6 passes for 64 varying bits instead of 8.
pub const DIGIT_BITS: u32 = 11;

/// Below this many keys per thread a pass runs on one chunk: splitting costs more than it saves.
const MIN_CHUNK: usize = 1 << 14;
/// Up to this many keys the whole sort is one sequential in-cache LSD.
const SMALL: usize = 1 << 15;
/// Target bucket size of the first (most significant digit) pass: 4096 (key, index) pairs are
/// 48 KiB, so the per-bucket LSD passes run in L1/L2 instead of scattering over main memory.
const CACHE_BUCKET: usize = 1 << 12;
/// Widest first-pass digit.
const MSD_BITS: u32 = 11;
/// Buckets with at least this many keys use 11-bit in-cache digits (fewer passes), smaller ones 8.
const SEQ_WIDE: usize = 1 << 11;
/// Buckets larger than this are sorted with the parallel LSD passes.
const BIG_BUCKET: usize = 1 << 18;

/// Sorts `codes` ascending together with their indices `0..n`; ties stay in index order.
/// Returns `(sorted codes, order)` where `order[i]` is the original index of `sorted[i]`.
pub fn sort_with_index(codes: Vec<u64>) -> (Vec<u64>, Vec<u32>) {
    sort_impl(codes, None, DIGIT_BITS)
}

/// Stable sort of `keys` carrying `vals` (same length). Returns the sorted pair of vectors.
pub fn sort_pairs(keys: Vec<u64>, vals: Vec<u32>) -> (Vec<u64>, Vec<u32>) {
    assert_eq!(keys.len(), vals.len(), "radix::sort_pairs: keys and values differ in length");
    sort_impl(keys, Some(vals), DIGIT_BITS)
}

/// The passes `(shift, width)` needed to sort keys whose varying bits are `mask`.
pub fn digit_plan(mask: u64, digit_bits: u32) -> Vec<(u32, u32)> {
    let mut plan = Vec::new();
    let mut m = mask;
    while m != 0 {
        let lo = m.trailing_zeros();
        let w = digit_bits.min(64 - lo);
        plan.push((lo, w));
        m &= !(low_mask(w) << lo);
    }
    plan
}

#[inline]
fn low_mask(w: u32) -> u64 {
    if w >= 64 {
        u64::MAX
    } else {
        (1u64 << w) - 1
    }
}

fn varying_bits(keys: &[u64]) -> u64 {
    match keys.first() {
        None => 0,
        Some(&k0) => keys.par_iter().with_min_len(MIN_CHUNK).map(|&k| k ^ k0).reduce(|| 0, |a, b| a | b),
    }
}

fn identity(n: usize) -> Vec<u32> {
    (0..n as u32).into_par_iter().with_min_len(MIN_CHUNK).collect()
}

fn ceil_log2(x: usize) -> u32 {
    usize::BITS - x.saturating_sub(1).leading_zeros()
}

fn sort_impl(keys: Vec<u64>, vals: Option<Vec<u32>>, digit_bits: u32) -> (Vec<u64>, Vec<u32>) {
    let n = keys.len();
    assert!(n <= u32::MAX as usize, "radix sort: more than 2^32 primitives");
    let mask = varying_bits(&keys);
    if mask == 0 {
        // All keys equal (or n <= 1): the stable order is the input order.
        return (keys, vals.unwrap_or_else(|| identity(n)));
    }
    if n <= SMALL {
        let (mut keys, mut vals) = (keys, vals.unwrap_or_else(|| identity(n)));
        let (mut sk, mut sv) = (vec![0u64; n], vec![0u32; n]);
        lsd_seq(&mut keys, &mut vals, &mut sk, &mut sv);
        return (keys, vals);
    }
    // One parallel pass on the most significant varying bits, sized so that the buckets fit the
    // cache (about CACHE_BUCKET keys each on uniform input); then every bucket is LSD-sorted on its
    // own remaining varying bits, in parallel over buckets. Both steps are stable.
    let hi = 63 - mask.leading_zeros();
    let lo = mask.trailing_zeros();
    let w1 = ceil_log2(n / CACHE_BUCKET).clamp(1, MSD_BITS).min(hi - lo + 1);
    let shift1 = hi + 1 - w1;
    let chunk_len = chunk_len(n);
    // Zeroed in parallel: the first touch of fresh pages (page faults) is a large part of a pass.
    let (mut tk, mut tv) = rayon::join(|| zeroed::<u64>(n), || zeroed::<u32>(n));
    let starts = pass(&keys, vals.as_deref(), &mut tk, &mut tv, shift1, w1, chunk_len);
    if mask & low_mask(shift1) == 0 {
        return (tk, tv);
    }
    // The input buffers are free now: their bucket-aligned slices are the key scratch.
    let mut scratch_k = keys;
    let mut jobs = Vec::new();
    {
        let (mut rk, mut rv, mut rs) = (tk.as_mut_slice(), tv.as_mut_slice(), scratch_k.as_mut_slice());
        for w in starts.windows(2) {
            let len = w[1] - w[0];
            let (k, k2) = std::mem::take(&mut rk).split_at_mut(len);
            let (v, v2) = std::mem::take(&mut rv).split_at_mut(len);
            let (s, s2) = std::mem::take(&mut rs).split_at_mut(len);
            (rk, rv, rs) = (k2, v2, s2);
            if len > 1 {
                jobs.push((k, v, s));
            }
        }
    }
    jobs.into_par_iter().for_each_init(Vec::<u32>::new, |sv, (k, v, sk)| {
        if sv.len() < k.len() {
            sv.resize(k.len(), 0);
        }
        let sv = &mut sv[..k.len()];
        if k.len() > BIG_BUCKET {
            lsd_par(k, v, sk, sv, digit_bits);
        } else {
            lsd_seq(k, v, sk, sv);
        }
    });
    drop(scratch_k);
    (tk, tv)
}

fn zeroed<T: Default + Send + Copy>(n: usize) -> Vec<T> {
    (0..n).into_par_iter().with_min_len(1 << 16).map(|_| T::default()).collect()
}

fn chunk_len(n: usize) -> usize {
    let chunks = (n / MIN_CHUNK).clamp(1, rayon::current_num_threads().max(1));
    n.div_ceil(chunks)
}

/// Sequential LSD on the varying bits of `k` (in cache), 8-bit digits; `sk`, `sv` are scratch of
/// the same length. The result ends in `k`, `v`. All digit histograms come from one read (a
/// permutation does not change them).
fn lsd_seq(k: &mut [u64], v: &mut [u32], sk: &mut [u64], sv: &mut [u32]) {
    if k.len() >= SEQ_WIDE {
        lsd_seq_w::<11, 2048>(k, v, sk, sv)
    } else {
        lsd_seq_w::<8, 256>(k, v, sk, sv)
    }
}

/// `lsd_seq` with `W`-bit digits (`R = 2^W` buckets).
fn lsd_seq_w<const W: u32, const R: usize>(k: &mut [u64], v: &mut [u32], sk: &mut [u64], sv: &mut [u32]) {
    let k0 = k[0];
    let mask = k.iter().fold(0, |m, &x| m | (x ^ k0));
    let dmask = (R - 1) as u64;
    let mut plan = [0u32; 8];
    let mut passes = 0;
    let mut m = mask;
    while m != 0 {
        let lo = m.trailing_zeros();
        plan[passes] = lo;
        passes += 1;
        m &= !(dmask.checked_shl(lo).unwrap_or(0));
    }
    let plan = &plan[..passes];
    let mut hist = [[0u32; R]; 8];
    for &x in k.iter() {
        for (h, &shift) in hist.iter_mut().zip(plan) {
            h[((x >> shift) & dmask) as usize] += 1;
        }
    }
    let mut in_scratch = false;
    for (h, &shift) in hist.iter_mut().zip(plan) {
        let mut sum = 0;
        for o in h.iter_mut() {
            let c = *o;
            *o = sum;
            sum += c;
        }
        if in_scratch {
            scatter_seq(sk, sv, k, v, shift, h);
        } else {
            scatter_seq(k, v, sk, sv, shift, h);
        }
        in_scratch = !in_scratch;
    }
    if in_scratch {
        k.copy_from_slice(sk);
        v.copy_from_slice(sv);
    }
}

#[inline]
fn scatter_seq<const R: usize>(
    src_k: &[u64],
    src_v: &[u32],
    dst_k: &mut [u64],
    dst_v: &mut [u32],
    shift: u32,
    off: &mut [u32; R],
) {
    let dmask = (R - 1) as u64;
    let (dst_k, dst_v) = (&mut dst_k[..src_k.len()], &mut dst_v[..src_k.len()]);
    for (&x, &val) in src_k.iter().zip(src_v) {
        let d = ((x >> shift) & dmask) as usize;
        let o = off[d] as usize;
        off[d] += 1;
        dst_k[o] = x;
        dst_v[o] = val;
    }
}

/// Parallel LSD of one large slice (a bucket holding much of the input, e.g. a dense object with
/// a far outlier), ping-ponging with the scratch; the result ends in `k`, `v`.
fn lsd_par(k: &mut [u64], v: &mut [u32], sk: &mut [u64], sv: &mut [u32], digit_bits: u32) {
    let mask = varying_bits(k);
    let cl = chunk_len(k.len());
    let mut in_scratch = false;
    for (shift, width) in digit_plan(mask, digit_bits) {
        if in_scratch {
            pass(sk, Some(sv), k, v, shift, width, cl);
        } else {
            pass(k, Some(v), sk, sv, shift, width, cl);
        }
        in_scratch = !in_scratch;
    }
    if in_scratch {
        k.par_chunks_mut(MIN_CHUNK).zip(sk.par_chunks(MIN_CHUNK)).for_each(|(d, s)| d.copy_from_slice(s));
        v.par_chunks_mut(MIN_CHUNK).zip(sv.par_chunks(MIN_CHUNK)).for_each(|(d, s)| d.copy_from_slice(s));
    }
}

/// A raw pointer shared by the scatter tasks; every task writes a disjoint set of indices.
struct SyncPtr<T>(*mut T);
unsafe impl<T: Send> Sync for SyncPtr<T> {}
unsafe impl<T: Send> Send for SyncPtr<T> {}
impl<T> SyncPtr<T> {
    #[inline]
    fn get(&self) -> *mut T {
        self.0
    }
}

fn pass(
    src_k: &[u64],
    src_v: Option<&[u32]>,
    dst_k: &mut [u64],
    dst_v: &mut [u32],
    shift: u32,
    width: u32,
    chunk_len: usize,
) -> Vec<usize> {
    let n = src_k.len();
    debug_assert!(dst_k.len() == n && dst_v.len() == n);
    let radix = 1usize << width;
    let dmask = low_mask(width);
    let hists: Vec<Vec<u32>> = src_k
        .par_chunks(chunk_len)
        .map(|c| {
            let (shift, dmask) = (shift, dmask);
            let mut h = vec![0u32; radix];
            for &k in c {
                h[((k >> shift) & dmask) as usize] += 1;
            }
            h
        })
        .collect();
    // Exclusive prefix sums in (digit, chunk) order: chunk c's elements with digit d go after
    // all smaller digits and after the same digit of chunks before c (stability).
    let mut offsets = vec![vec![0usize; radix]; hists.len()];
    let mut starts = vec![0usize; radix + 1];
    let mut sum = 0usize;
    for d in 0..radix {
        starts[d] = sum;
        for (c, h) in hists.iter().enumerate() {
            offsets[c][d] = sum;
            sum += h[d] as usize;
        }
    }
    debug_assert_eq!(sum, n);
    starts[radix] = n;

    let kp = SyncPtr(dst_k.as_mut_ptr());
    let vp = SyncPtr(dst_v.as_mut_ptr());
    src_k.par_chunks(chunk_len).zip(offsets.into_par_iter()).enumerate().for_each(|(ci, (c, mut off))| {
        // Locals, so the compiler keeps them in registers: the raw-pointer stores below could
        // otherwise alias anything reached through a reference.
        let (shift, dmask) = (shift, dmask);
        let base = ci * chunk_len;
        let (kp, vp) = (kp.get(), vp.get());
        let off = off.as_mut_slice();
        match src_v {
            Some(v) => {
                let v = &v[base..base + c.len()];
                for (&k, &val) in c.iter().zip(v) {
                    let d = ((k >> shift) & dmask) as usize;
                    let o = off[d];
                    off[d] = o + 1;
                    // SAFETY: `o` walks this chunk's private range of the output for digit `d`;
                    // the ranges of all (digit, chunk) pairs partition 0..n.
                    unsafe {
                        kp.add(o).write(k);
                        vp.add(o).write(val);
                    }
                }
            }
            None => {
                for (j, &k) in c.iter().enumerate() {
                    let d = ((k >> shift) & dmask) as usize;
                    let o = off[d];
                    off[d] = o + 1;
                    // SAFETY: as above.
                    unsafe {
                        kp.add(o).write(k);
                        vp.add(o).write((base + j) as u32);
                    }
                }
            }
        }
    });
    starts
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_skips_constant_bits() {
        assert!(digit_plan(0, 8).is_empty());
        assert_eq!(digit_plan(u64::MAX, 8).len(), 8);
        assert_eq!(digit_plan(u64::MAX, 11), vec![(0, 11), (11, 11), (22, 11), (33, 11), (44, 11), (55, 9)]);
        // Two varying bits far apart: two narrow passes, the constant run between them skipped.
        assert_eq!(digit_plan((1 << 3) | (1 << 40), 11), vec![(3, 11), (40, 11)]);
        assert_eq!(digit_plan((1u64 << 30) - 1, 11).len(), 3);
    }
}
