//! SSE4.1 version of the pair test. Lane layout of every vector: (x, y, z, x); the duplicated x
//! lane does not change a min/max reduction. Every lane computes exactly the scalar float
//! operations of `deq_value`, `Grid::new` and `RayBox::hit` (mulps/addps are the same IEEE
//! operations, minps/maxps are the same `a < b ? a : b` selections, and the reduction order does
//! not matter without NaNs, which cannot occur with finite boxes and the finite inverse
//! direction), so both paths give bit-identical hits, steps and tests. Rays with a zero direction
//! component call `RayBox::hit` itself (it tests such an axis by the origin's position).

use super::quant::{KeyReader, Packed};
use super::traverse::Lanes;
use bvhlab_geom::Aabb;
use bvhlab_trace::{Ray, SLAB_ROBUST};
use std::arch::x86_64::*;

#[derive(Clone, Copy)]
pub struct G {
    lo: __m128,
    step: __m128,
    hi: __m128,
}

#[derive(Clone, Copy)]
pub struct Box2 {
    min: __m128,
    max: __m128,
}

impl Box2 {
    #[inline(always)]
    unsafe fn aabb(&self) -> Aabb {
        let (mut a, mut b) = ([0.0f32; 4], [0.0f32; 4]);
        _mm_storeu_ps(a.as_mut_ptr(), self.min);
        _mm_storeu_ps(b.as_mut_ptr(), self.max);
        Aabb::new(
            bvhlab_geom::Vec3::new(a[0], a[1], a[2]),
            bvhlab_geom::Vec3::new(b[0], b[1], b[2]),
        )
    }
}

impl Default for Box2 {
    #[inline(always)]
    fn default() -> Self {
        // SAFETY: SSE is baseline on x86_64.
        unsafe {
            Box2 {
                min: _mm_setzero_ps(),
                max: _mm_setzero_ps(),
            }
        }
    }
}

pub struct Sse {
    /// A direction component is zero: `RayBox::hit` treats that axis specially (by the
    /// origin's position), so such rays use it on the dequantized boxes.
    parallel: bool,
    rb: bvhlab_trace::RayBox,
    o: __m128,
    inv: __m128,
    max_key: __m128i,
    inv_max: __m128,
}

#[inline(always)]
unsafe fn xyzx(x: f32, y: f32, z: f32) -> __m128 {
    _mm_setr_ps(x, y, z, x)
}

impl Sse {
    #[inline(always)]
    pub unsafe fn new(ray: &Ray, max_key: u32) -> Sse {
        let rb = bvhlab_trace::RayBox::new(ray);
        Sse {
            parallel: ray.dir.x == 0.0 || ray.dir.y == 0.0 || ray.dir.z == 0.0,
            o: xyzx(rb.origin.x, rb.origin.y, rb.origin.z),
            inv: xyzx(rb.inv_dir.x, rb.inv_dir.y, rb.inv_dir.z),
            max_key: _mm_set1_epi32(max_key as i32),
            inv_max: _mm_set1_ps(1.0 / max_key as f32),
            rb,
        }
    }

    /// `Grid::new`, four lanes.
    #[inline(always)]
    unsafe fn grid(&self, lo: __m128, hi: __m128) -> G {
        let d = _mm_sub_ps(hi, lo);
        let abs = _mm_andnot_ps(_mm_set1_ps(-0.0), d);
        let finite = _mm_cmplt_ps(abs, _mm_set1_ps(f32::INFINITY));
        let far = _mm_min_ps(
            _mm_sub_ps(_mm_mul_ps(hi, self.inv_max), _mm_mul_ps(lo, self.inv_max)),
            _mm_set1_ps(f32::MAX),
        );
        let step = _mm_blendv_ps(far, _mm_mul_ps(d, self.inv_max), finite);
        G { lo, step, hi }
    }

    /// `deq_value`, four lanes.
    #[inline(always)]
    unsafe fn deq(&self, g: &G, k: __m128i) -> __m128 {
        let v = _mm_add_ps(g.lo, _mm_mul_ps(_mm_cvtepi32_ps(k), g.step));
        let top = _mm_castsi128_ps(_mm_cmpeq_epi32(k, self.max_key));
        _mm_blendv_ps(v, g.hi, top)
    }
}

impl Lanes for Sse {
    type G = G;
    type B = Box2;
    #[inline(always)]
    fn grid_aabb(&self, f: &Aabb) -> G {
        unsafe {
            self.grid(
                xyzx(f.min.x, f.min.y, f.min.z),
                xyzx(f.max.x, f.max.y, f.max.z),
            )
        }
    }
    #[inline(always)]
    fn grid_box(&self, f: &Box2) -> G {
        unsafe { self.grid(f.min, f.max) }
    }
    #[inline(always)]
    fn test_pair<K: KeyReader>(
        &self,
        g: &G,
        kr: K,
        keys: &[u8],
        i: usize,
        tmax: f32,
    ) -> (Option<f32>, Option<f32>, Box2, Box2) {
        unsafe {
            let [k0n, k0x, k1n, k1x] = kr.pair_sse(keys, i);
            let b0 = Box2 {
                min: self.deq(g, k0n),
                max: self.deq(g, k0x),
            };
            let b1 = Box2 {
                min: self.deq(g, k1n),
                max: self.deq(g, k1x),
            };
            if self.parallel {
                let (a0, a1) = (b0.aabb(), b1.aabb());
                return (self.rb.hit(&a0, tmax), self.rb.hit(&a1, tmax), b0, b1);
            }
            // RayBox::hit for both boxes.
            let slab = |b: &Box2| {
                let t0 = _mm_mul_ps(_mm_sub_ps(b.min, self.o), self.inv);
                let t1 = _mm_mul_ps(_mm_sub_ps(b.max, self.o), self.inv);
                (_mm_min_ps(t0, t1), _mm_max_ps(t0, t1))
            };
            let (n0, f0) = slab(&b0);
            let (n1, f1) = slab(&b1);
            // Lanes (box0, box1): near = max(x, y, z, 0), far = min(x, y, z, tmax).
            let nl = _mm_unpacklo_ps(n0, n1); // x0 x1 y0 y1
            let nh = _mm_unpackhi_ps(n0, n1); // z0 z1 x0 x1
            let near = _mm_max_ps(
                _mm_max_ps(nl, _mm_movehl_ps(nl, nl)),
                _mm_max_ps(nh, _mm_setzero_ps()),
            );
            let fl = _mm_unpacklo_ps(f0, f1);
            let fh = _mm_unpackhi_ps(f0, f1);
            let far = _mm_mul_ps(
                _mm_min_ps(
                    _mm_min_ps(fl, _mm_movehl_ps(fl, fl)),
                    _mm_min_ps(fh, _mm_set1_ps(tmax)),
                ),
                _mm_set1_ps(SLAB_ROBUST),
            );
            let m = _mm_movemask_ps(_mm_cmple_ps(near, far));
            let mut t = [0.0f32; 4];
            _mm_storeu_ps(t.as_mut_ptr(), near);
            (
                (m & 1 != 0).then_some(t[0]),
                (m & 2 != 0).then_some(t[1]),
                b0,
                b1,
            )
        }
    }
}

/// (min, max, min, max) key vectors of a sibling pair, lanes (x, y, z, x), from the 12
/// coordinates in stream order.
#[inline(always)]
pub unsafe fn from_u32(k: &[u32; 12]) -> [__m128i; 4] {
    let v =
        |j: usize| _mm_setr_epi32(k[j] as i32, k[j + 1] as i32, k[j + 2] as i32, k[j] as i32);
    [v(0), v(3), v(6), v(9)]
}

/// Byte shuffles and per-lane multipliers that turn an unaligned u64 window of the key stream
/// into one key vector (lanes x, y, z, x of three consecutive coordinates): lane j takes the 3
/// bytes holding its coordinate, `* 2^(7 - r)` then `>> 7` shifts each lane right by its own
/// residual r (SSE4.1 has no per-lane variable shift), then the mask. Indexed by [half of a
/// byte the pair starts at (odd bits only)][vector h = coordinates 3h..3h + 3 of the pair].
pub struct PackedTables {
    shuf: [[__m128i; 4]; 2],
    mul: [[__m128i; 4]; 2],
    mask: __m128i,
}

impl PackedTables {
    pub fn new(bits: u32) -> PackedTables {
        let b = bits as usize;
        let mut shuf = [[[0x80u8; 16]; 4]; 2];
        let mut mul = [[[0u32; 4]; 4]; 2];
        for (par, (sh, mu)) in shuf.iter_mut().zip(mul.iter_mut()).enumerate() {
            for h in 0..4 {
                let p = 4 * par + 3 * h * b; // window starts at byte p >> 3
                for (j, c) in [0usize, 1, 2, 0].into_iter().enumerate() {
                    let off = (p & 7) + c * b;
                    for q in 0..3 {
                        sh[h][4 * j + q] = ((off >> 3) + q) as u8;
                    }
                    mu[h][j] = 1 << (7 - (off & 7));
                }
            }
        }
        // SAFETY: plain SSE2 loads of local arrays.
        unsafe {
            let ld = |a: &[u8; 16]| _mm_loadu_si128(a.as_ptr() as *const __m128i);
            let ldm = |a: &[u32; 4]| _mm_loadu_si128(a.as_ptr() as *const __m128i);
            PackedTables {
                shuf: [0, 1].map(|i| std::array::from_fn(|h| ld(&shuf[i][h]))),
                mul: [0, 1].map(|i| std::array::from_fn(|h| ldm(&mul[i][h]))),
                mask: _mm_set1_epi32(((1u32 << bits) - 1) as i32),
            }
        }
    }
}

/// `Packed` with the SSE key path.
#[derive(Clone, Copy)]
pub struct PackedSse<'a> {
    pub bits: u32,
    pub t: &'a PackedTables,
}

// SAFETY: the tables are plain data, only read.
unsafe impl Send for PackedTables {}
unsafe impl Sync for PackedTables {}

impl KeyReader for PackedSse<'_> {
    #[inline(always)]
    fn pair(&self, keys: &[u8], g: usize) -> [u32; 12] {
        Packed { bits: self.bits }.pair(keys, g)
    }
    #[inline(always)]
    unsafe fn pair_sse(&self, keys: &[u8], g: usize) -> [__m128i; 4] {
        let b = self.bits as usize;
        let p0 = 6 * g * b; // g is even: p0 % 8 is 0 or 4
        let par = (p0 >> 2) & 1;
        let t = self.t;
        #[inline(always)]
        unsafe fn one(
            t: &PackedTables,
            keys: &[u8],
            p: usize,
            par: usize,
            h: usize,
        ) -> __m128i {
            let byte = p >> 3;
            let w = if byte + 8 <= keys.len() {
                u64::from_le_bytes(keys[byte..byte + 8].try_into().unwrap())
            } else {
                let mut a = [0u8; 8];
                let tail = &keys[byte.min(keys.len())..];
                a[..tail.len()].copy_from_slice(tail);
                u64::from_le_bytes(a)
            };
            let v = _mm_shuffle_epi8(_mm_cvtsi64_si128(w as i64), t.shuf[par][h]);
            let v = _mm_srli_epi32(_mm_mullo_epi32(v, t.mul[par][h]), 7);
            _mm_and_si128(v, t.mask)
        }
        [
            one(t, keys, p0, par, 0),
            one(t, keys, p0 + 3 * b, par, 1),
            one(t, keys, p0 + 6 * b, par, 2),
            one(t, keys, p0 + 9 * b, par, 3),
        ]
    }
}

/// The same from 12 key bytes (bits = 8), with one byte shuffle per vector.
#[inline(always)]
pub unsafe fn from_bytes(b: &[u8; 12]) -> [__m128i; 4] {
    let lo = u64::from_le_bytes(b[..8].try_into().unwrap());
    let hi = u32::from_le_bytes(b[8..].try_into().unwrap());
    let x = _mm_set_epi64x(hi as i64, lo as i64);
    let z = -128i8; // pshufb: high bit set = zero byte
    let sh = |j: i8| _mm_setr_epi8(j, z, z, z, j + 1, z, z, z, j + 2, z, z, z, j, z, z, z);
    [
        _mm_shuffle_epi8(x, sh(0)),
        _mm_shuffle_epi8(x, sh(3)),
        _mm_shuffle_epi8(x, sh(6)),
        _mm_shuffle_epi8(x, sh(9)),
    ]
}
