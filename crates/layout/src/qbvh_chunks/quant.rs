//! Quantization (one dequantization for build, traversal, validation and SAH) and the node
//! info bit stream.

#[cfg(target_arch = "x86_64")]
use super::sse;
use bvhlab_geom::{Aabb, Vec3};

// ---------------------------------------------------------------------------------------------
// Quantization: ONE dequantization function, used by build, traversal, validation and SAH.
// ---------------------------------------------------------------------------------------------

/// A quantization frame per axis: `deq(k) = lo + k * step` for `k < max_key`, `hi` for `k =
/// max_key` (so key 0 is `lo` and the top key `hi` exactly, whatever the rounding). `step` is
/// `(hi - lo) / max_key`, computed without overflow for huge coordinates and 0 for a zero-extent
/// axis (no division by the extent anywhere).
#[derive(Clone, Copy, Debug)]
pub(super) struct Grid {
    lo: [f32; 3],
    hi: [f32; 3],
    step: [f32; 3],
}

impl Grid {
    #[inline(always)]
    pub(super) fn new(frame: &Aabb, inv_max: f32) -> Grid {
        let lo = frame.min.to_array();
        let hi = frame.max.to_array();
        let mut step = [0.0; 3];
        for a in 0..3 {
            let d = hi[a] - lo[a];
            step[a] = if d.is_finite() {
                d * inv_max
            } else {
                // Finite except for bits = 1 (inv_max = 1) across the whole f32 range; clamped
                // so that key 0 still gives `lo + 0 * step = lo` (there are no middle keys then).
                (hi[a] * inv_max - lo[a] * inv_max).min(f32::MAX)
            };
        }
        Grid { lo, hi, step }
    }

    #[inline(always)]
    pub(super) fn deq(&self, a: usize, k: u32, max_key: u32) -> f32 {
        deq_value(self.lo[a], self.step[a], self.hi[a], k, max_key)
    }

    /// Dequantized box of a key (min xyz, max xyz).
    #[inline(always)]
    pub(super) fn dequantize(&self, k: &[u32], max_key: u32) -> Aabb {
        Aabb {
            min: Vec3::new(
                self.deq(0, k[0], max_key),
                self.deq(1, k[1], max_key),
                self.deq(2, k[2], max_key),
            ),
            max: Vec3::new(
                self.deq(0, k[3], max_key),
                self.deq(1, k[4], max_key),
                self.deq(2, k[5], max_key),
            ),
        }
    }

    /// The boxes of two siblings at once (the same `deq_value` per coordinate, written as one
    /// 12-lane loop so that it vectorizes).
    #[inline(always)]
    pub(super) fn dequantize_pair(&self, k: &[u32; 12], max_key: u32) -> (Aabb, Aabb) {
        let mut o = [0.0f32; 12];
        for i in 0..12 {
            let a = i % 3;
            o[i] = deq_value(self.lo[a], self.step[a], self.hi[a], k[i], max_key);
        }
        let v = |j: usize| Vec3::new(o[j], o[j + 1], o[j + 2]);
        (Aabb::new(v(0), v(3)), Aabb::new(v(6), v(9)))
    }

    /// Largest key whose dequantized value is still <= `e` (0, i.e. `lo` exactly, when `e` is
    /// below the frame, NaN, or the axis has no extent). Kilian's floor (alg. 3) is not
    /// conservative under rounding; this checks the actual dequantized value and steps.
    fn key_min(&self, a: usize, e: f32, max_key: u32) -> u32 {
        let (lo, hi) = (self.lo[a], self.hi[a]);
        if !(e > lo && hi > lo) {
            return 0;
        }
        if e >= hi {
            return max_key;
        }
        let est = ((e as f64 - lo as f64) / (hi as f64 - lo as f64) * max_key as f64).floor();
        let mut k = if est.is_finite() {
            est.clamp(0.0, max_key as f64) as u32
        } else {
            0
        };
        while k > 0 && self.deq(a, k, max_key) > e {
            k -= 1;
        }
        while k < max_key && self.deq(a, k + 1, max_key) <= e {
            k += 1;
        }
        k
    }

    /// Smallest key whose dequantized value is still >= `e` (`max_key` when `e` is above the
    /// frame, NaN, or the axis has no extent).
    fn key_max(&self, a: usize, e: f32, max_key: u32) -> u32 {
        let (lo, hi) = (self.lo[a], self.hi[a]);
        if !(e < hi && hi > lo) {
            return max_key;
        }
        if e <= lo {
            return 0;
        }
        let est = ((e as f64 - lo as f64) / (hi as f64 - lo as f64) * max_key as f64).ceil();
        let mut k = if est.is_finite() {
            est.clamp(0.0, max_key as f64) as u32
        } else {
            max_key
        };
        while k < max_key && self.deq(a, k, max_key) < e {
            k += 1;
        }
        while k > 0 && self.deq(a, k - 1, max_key) >= e {
            k -= 1;
        }
        k
    }

    /// The tightest conservative key of `b` (a box inside the frame; outside parts are clamped
    /// to the frame, which `validate` then reports).
    pub(super) fn quantize(&self, b: &Aabb, max_key: u32) -> [u32; 6] {
        let (mn, mx) = (b.min.to_array(), b.max.to_array());
        let mut k = [0u32; 6];
        for a in 0..3 {
            k[a] = self.key_min(a, mn[a], max_key);
            k[a + 3] = self.key_max(a, mx[a], max_key);
        }
        k
    }
}

/// THE dequantization (build, traversal, validation and SAH all go through here): key 0 gives `lo`
/// exactly (`lo + 0 * step`, `step` finite), the top key `hi` exactly; keys are at most 16 bits,
/// so the i32 conversion is exact (and one instruction, unlike u32).
#[inline(always)]
pub(super) fn deq_value(lo: f32, step: f32, hi: f32, k: u32, max_key: u32) -> f32 {
    let v = lo + (k as i32) as f32 * step;
    if k >= max_key {
        hi
    } else {
        v
    }
}

// ---------------------------------------------------------------------------------------------
// Node info bit stream.
// ---------------------------------------------------------------------------------------------

pub(super) fn write_key(keys: &mut [u8], bits: u32, node: usize, k: &[u32; 6]) {
    for (c, &v) in k.iter().enumerate() {
        let p = (node * 6 + c) * bits as usize;
        for b in 0..bits as usize {
            if v >> b & 1 == 1 {
                let q = p + b;
                keys[q / 8] |= 1 << (q % 8);
            }
        }
    }
}

/// Reads the 12 key coordinates of two sibling nodes `g`, `g + 1`.
pub(super) trait KeyReader: Copy + Send + Sync {
    fn pair(&self, keys: &[u8], g: usize) -> [u32; 12];
    /// The pair as SSE key vectors (see `sse::from_u32`).
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn pair_sse(&self, keys: &[u8], g: usize) -> [std::arch::x86_64::__m128i; 4] {
        sse::from_u32(&self.pair(keys, g))
    }
}

/// bits = 8: one byte per coordinate, the two siblings' keys are 12 consecutive bytes.
#[derive(Clone, Copy)]
pub(super) struct Bytes8;

impl KeyReader for Bytes8 {
    #[inline(always)]
    fn pair(&self, keys: &[u8], g: usize) -> [u32; 12] {
        let s: &[u8; 12] = keys[6 * g..6 * g + 12].try_into().unwrap();
        s.map(|b| b as u32)
    }
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn pair_sse(&self, keys: &[u8], g: usize) -> [std::arch::x86_64::__m128i; 4] {
        sse::from_bytes(keys[6 * g..6 * g + 12].try_into().unwrap())
    }
}

/// Any `bits`: each coordinate spans at most 16 bits, read as a little-endian u32 window that
/// starts at the coordinate's byte (shift <= 7), clamped to the stream end (then the shift grows
/// but `shift + bits <= 32` still holds because the coordinate ends inside the stream).
#[derive(Clone, Copy)]
pub(super) struct Packed {
    pub(super) bits: u32,
}

impl Packed {
    #[inline(always)]
    fn get(&self, keys: &[u8], p: usize) -> u32 {
        let mask = (1u32 << self.bits) - 1;
        if keys.len() >= 4 {
            let start = (p >> 3).min(keys.len() - 4);
            let w = u32::from_le_bytes(keys[start..start + 4].try_into().unwrap());
            (w >> (p - 8 * start)) & mask
        } else {
            let mut w = 0u32;
            for (i, &b) in keys.iter().enumerate() {
                w |= (b as u32) << (8 * i);
            }
            (w >> p) & mask
        }
    }
}

impl KeyReader for Packed {
    #[inline(always)]
    fn pair(&self, keys: &[u8], g: usize) -> [u32; 12] {
        // Three coordinates (3 * bits <= 48 bits) plus a shift <= 7 fit one unaligned u64
        // window: four window reads per pair; the stream's last bytes are read coordinate by
        // coordinate.
        let b = self.bits as usize;
        let mask = (1u64 << b) - 1;
        let mut out = [0u32; 12];
        for h in 0..4 {
            let p = (6 * g + 3 * h) * b;
            let byte = p >> 3;
            if byte + 8 <= keys.len() {
                let w = u64::from_le_bytes(keys[byte..byte + 8].try_into().unwrap()) >> (p & 7);
                out[3 * h] = (w & mask) as u32;
                out[3 * h + 1] = (w >> b & mask) as u32;
                out[3 * h + 2] = (w >> (2 * b) & mask) as u32;
            } else {
                for c in 0..3 {
                    out[3 * h + c] = self.get(keys, p + c * b);
                }
            }
        }
        out
    }
}
