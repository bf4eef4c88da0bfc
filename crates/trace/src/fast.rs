//! The timed traversal path (issue 19 item 1): the same closest-hit search as [`crate::trace`],
//! built for speed, with the exact f64 test kept as the reference.
//!
//! - Triangles are copied once, before timing, into leaf-slot order ([`TriStore`]): a leaf reads
//!   `tris[first..first + count]` contiguously instead of going through `prim_indices`.
//! - The triangle test is a type parameter ([`TriTest`]): [`Watertight`] is the f32 test of Woop,
//!   Benthin and Wald 2013 ("Watertight Ray/Triangle Intersection", JCGT 2(1)) used for timing;
//!   [`Exact`] is [`crate::intersect_triangle`] (f64), the oracle's test, with which this traversal
//!   finds exactly brute force's hits.
//! - Counters are a const generic (`STATS`): the timed instantiation has no counting code at all.
//! - The box test uses the inverse direction and the near/far plane chosen once per ray by the
//!   direction's sign (Williams et al. 2005, "An efficient and robust ray-box intersection
//!   algorithm"), with the same conservative margin as [`crate::RayBox`] (Ize 2013). Rays with a zero
//!   direction component go through [`crate::RayBox::hit`], which handles them exactly.
//! - Near child first, a fixed stack ([`crate::Stack`], spilling only past 64 entries), no allocation
//!   per ray; rays run in parallel over rayon chunks with per-ray results (any thread count gives the
//!   same hits).
#[cfg(target_arch = "x86_64")]
use crate::pairs::pairs_one;
use crate::pairs::{Arena, Pairs};
use crate::packs::Tri4;
use crate::{accept, intersect_triangle, Hit, Ray, RayBox, Stack, TraceStats, SLAB_ROBUST};
use bvhlab_bvh::{Bvh, Node};
use bvhlab_geom::{Aabb, Triangle, Vec3};
use rayon::prelude::*;

/// One triangle in leaf-slot order: its three vertices (the watertight test needs the vertices,
/// not edges: Woop 2013 section 3 translates each vertex by the origin), its scene index and
/// whether it ends its leaf. 48 bytes with the alignment, so a triangle never straddles two cache
/// lines; `last` sits in what would be padding.
#[repr(C, align(16))]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WTri {
    pub v: [[f32; 3]; 3],
    pub prim: u32,
    /// Nonzero on the last triangle of a leaf ([`TriStore::with_leaves`]): a leaf test given the
    /// store from a leaf's first slot on stops at this mark (as Embree marks the last primitive of
    /// a leaf). The wide layouts now keep their leaves in packs ([`crate::packs`], the same mark
    /// as an END bit); bvh2 passes each leaf's exact slice and needs no mark.
    pub last: u32,
    /// Zero. Explicit so that the four-wide test's 16-byte loads read no padding.
    pub pad: u32,
}

/// Triangles of a BVH's leaves in slot order: `tris[i]` is scene triangle `prim_indices[i]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriStore {
    pub tris: Vec<WTri>,
}

impl TriStore {
    /// `prim_indices` mapped to their triangles. An index out of range (malformed input) becomes a
    /// degenerate triangle that is never hit, with its index kept so counters still see the test.
    pub fn new(prim_indices: &[u32], tris: &[Triangle]) -> TriStore {
        let tris = prim_indices
            .iter()
            .map(|&p| match tris.get(p as usize) {
                Some(t) => WTri {
                    v: t.v.map(|v| v.to_array()),
                    prim: p,
                    last: 0,
                    pad: 0,
                },
                None => WTri {
                    v: [[f32::NAN; 3]; 3],
                    prim: p,
                    last: 0,
                    pad: 0,
                },
            })
            .collect();
        TriStore { tris }
    }

    /// [`TriStore::new`] with the last slot of every leaf (`[first, count]` ranges of slots)
    /// marked. Ranges out of bounds or empty mark nothing (a malformed layout: its traversal then
    /// runs on to the next mark or the end, reading real triangles only).
    pub fn with_leaves(prim_indices: &[u32], tris: &[Triangle], leaves: &[[u32; 2]]) -> TriStore {
        let mut s = TriStore::new(prim_indices, tris);
        for &[first, count] in leaves {
            let end = first as usize + count as usize;
            if count > 0 && end <= s.tris.len() {
                s.tris[end - 1].last = 1;
            }
        }
        s
    }
}

/// A ray-triangle test over [`WTri`]: per-ray setup once, then one call per triangle returning the
/// hit distance (range-checked by [`accept`]).
pub trait TriTest: Sync {
    type Ray;
    /// `inv`: the inverse direction the box test computed already (saves divisions per ray).
    fn prepare(ray: &Ray, inv: &[f32; 3]) -> Self::Ray;
    /// [`Self::prepare`] compiled for AVX2 where a test has such a build (the same values).
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[inline(always)]
    unsafe fn prepare_avx2(ray: &Ray, inv: &[f32; 3]) -> Self::Ray {
        Self::prepare(ray, inv)
    }
    fn test(r: &Self::Ray, tri: &WTri) -> Option<f32>;
    /// Tests a leaf's triangles, `tris[0]` up to the first one marked [`WTri::last`] (or the end
    /// of `tris`), accepting hits into `best`; returns how many were tested. One at a time here;
    /// [`Watertight`] tests four at once.
    #[inline(always)]
    fn test_leaf(r: &Self::Ray, tris: &[WTri], best: &mut Hit) -> u32 {
        Exact::test_leaf_with(r, tris, best, Self::test)
    }
    /// [`Self::test_leaf`] compiled for AVX2 where a test has such a build (the same values: the
    /// same operations in the same order, only VEX-encoded, so no register copies; no FMA).
    ///
    /// # Safety
    /// The CPU must have AVX2 (callers check it once per trace, `is_x86_feature_detected`).
    #[inline(always)]
    unsafe fn test_leaf_avx2(r: &Self::Ray, tris: &[WTri], best: &mut Hit) -> u32 {
        Self::test_leaf(r, tris, best)
    }
    /// Tests a leaf stored in packs ([`crate::packs`]): `packs[0]` up to the lane marked
    /// [`crate::packs::END`]; returns how many triangles were tested. One at a time here;
    /// [`Watertight`] tests a pack at once.
    #[inline(always)]
    fn test_packs(r: &Self::Ray, packs: &[Tri4], best: &mut Hit) -> u32 {
        crate::packs::test_packs_with(r, packs, best, Self::test)
    }
    /// [`Self::test_packs`] compiled for AVX2 where a test has such a build (as
    /// [`Self::test_leaf_avx2`]).
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[inline(always)]
    unsafe fn test_packs_avx2(r: &Self::Ray, packs: &[Tri4], best: &mut Hit) -> u32 {
        Self::test_packs(r, packs, best)
    }
}

/// The reference: [`intersect_triangle`] in f64, bit-identical to brute force.
pub struct Exact;

impl TriTest for Exact {
    type Ray = (Vec3, Vec3);
    #[inline(always)]
    fn prepare(ray: &Ray, _: &[f32; 3]) -> (Vec3, Vec3) {
        (ray.origin, ray.dir)
    }
    #[inline(always)]
    fn test(r: &(Vec3, Vec3), tri: &WTri) -> Option<f32> {
        let t = Triangle {
            v: tri.v.map(Vec3::from_array),
        };
        intersect_triangle(r.0, r.1, &t)
    }
}

/// Per-ray data of the watertight test (Woop 2013 section 3, fig. 6): the dominant axis `kz` of
/// the direction, the other two (`kx`, `ky`, swapped when `dir[kz] < 0` to keep the winding) and
/// the shear constants that map the ray to +z.
#[derive(Clone, Copy, Debug)]
pub struct WoopRay {
    /// The origin permuted to (kx, ky, kz).
    pub(crate) org: [f32; 3],
    pub(crate) k: [usize; 3],
    pub(crate) s: [f32; 3],
}

impl WoopRay {
    #[inline(always)]
    pub fn new(origin: Vec3, dir: Vec3) -> WoopRay {
        let d = dir.to_array();
        WoopRay::with_inverse(origin, dir, &d.map(|d| 1.0 / d))
    }

    /// With `inv[k] = 1 / dir[k]` given: the shear constants are products with `1 / dir[kz]`
    /// instead of Woop's quotients (the test stays watertight: one set of constants per ray).
    #[inline(always)]
    pub fn with_inverse(origin: Vec3, dir: Vec3, inv: &[f32; 3]) -> WoopRay {
        // Branch-free axis choice: for random rays every branch here would be a coin flip.
        let a = dir.abs();
        let x_max = (a.x >= a.y) & (a.x >= a.z);
        let y_max = !x_max & (a.y >= a.z);
        let kz = (!x_max as usize) * (1 + !y_max as usize);
        let d = dir.to_array();
        let neg = (d[kz] < 0.0) as usize;
        // kx = kz + 1, ky = kz + 2 (mod 3), swapped when dir[kz] < 0 (keeps the winding).
        const KX: [[usize; 2]; 3] = [[1, 2], [2, 0], [0, 1]];
        const KY: [[usize; 2]; 3] = [[2, 1], [0, 2], [1, 0]];
        let (kx, ky) = (KX[kz][neg], KY[kz][neg]);
        let o = origin.to_array();
        let sz = inv[kz];
        let s = if sz.is_finite() {
            [d[kx] * sz, d[ky] * sz, sz]
        } else {
            // A subnormal largest component (an unnormalized tiny direction): divide.
            [d[kx] / d[kz], d[ky] / d[kz], 1.0 / d[kz]]
        };
        WoopRay {
            org: [o[kx], o[ky], o[kz]],
            k: [kx, ky, kz],
            s,
        }
    }
}

#[cfg(target_arch = "x86_64")]
impl WoopRay {
    /// [`Self::with_inverse`] for a caller compiled for AVX: the axes picked in registers by one
    /// `vpermilps` per vector instead of by indexing arrays through memory (callgrind on
    /// breakfast_room: about 45 instructions per ray, now about 25). The same values.
    ///
    /// # Safety
    /// The CPU must have AVX.
    #[inline(always)]
    pub unsafe fn with_inverse_avx(origin: Vec3, dir: Vec3, inv: &[f32; 3]) -> WoopRay {
        use std::arch::x86_64::*;
        // [kx, ky, kz] by kz * 2 + (dir[kz] < 0), as `with_inverse`'s tables.
        const K: [[usize; 3]; 6] = [[1, 2, 0], [2, 1, 0], [2, 0, 1], [0, 2, 1], [0, 1, 2], [1, 0, 2]];
        const CTL: [[i32; 4]; 6] = [[1, 2, 0, 3], [2, 1, 0, 3], [2, 0, 1, 3], [0, 2, 1, 3], [0, 1, 2, 3], [1, 0, 2, 3]];
        let a = dir.abs();
        let x_max = (a.x >= a.y) & (a.x >= a.z);
        let y_max = !x_max & (a.y >= a.z);
        let kz = (!x_max as usize) * (1 + !y_max as usize);
        unsafe {
            let d4 = _mm_setr_ps(dir.x, dir.y, dir.z, 0.0);
            let neg = (_mm_movemask_ps(_mm_cmplt_ps(d4, _mm_setzero_ps())) as usize >> kz) & 1;
            let c = kz * 2 + neg;
            let ctl = _mm_loadu_si128(CTL[c].as_ptr() as *const __m128i);
            let pd = _mm_permutevar_ps(d4, ctl);
            let po = _mm_permutevar_ps(_mm_setr_ps(origin.x, origin.y, origin.z, 0.0), ctl);
            let pi = _mm_permutevar_ps(_mm_setr_ps(inv[0], inv[1], inv[2], 0.0), ctl);
            let sz = _mm_permute_ps::<0b10_10_10_10>(pi);
            let s4 = if _mm_cvtss_f32(sz).is_finite() {
                _mm_blend_ps::<0b0100>(_mm_mul_ps(pd, sz), sz)
            } else {
                _mm_div_ps(_mm_blend_ps::<0b0100>(pd, _mm_set1_ps(1.0)), _mm_permute_ps::<0b10_10_10_10>(pd))
            };
            let (mut o, mut s) = ([0f32; 4], [0f32; 4]);
            _mm_storeu_ps(o.as_mut_ptr(), po);
            _mm_storeu_ps(s.as_mut_ptr(), s4);
            WoopRay {
                org: [o[0], o[1], o[2]],
                k: K[c],
                s: [s[0], s[1], s[2]],
            }
        }
    }
}

/// |det| range in which the f32 evaluation is trusted: outside it (coordinates beyond about 1e15
/// or below 1e-15, whose products overflow or lose digits to subnormals) the test is redone in f64,
/// like Woop 2013's fallback for an edge function exactly 0 (section 3.3). Keeps the fast path
/// scale-free (issue 15) at no cost for ordinary scenes.
pub(crate) const DET_MIN: f32 = 1e-30;
pub(crate) const DET_MAX: f32 = 1e30;

/// Woop, Benthin and Wald 2013, fig. 6, without backface culling. Watertight: an edge shared by two
/// triangles gives both the same edge function (up to sign), so no ray passes between them.
/// Returns t (positive-range check left to [`accept`]).
#[inline(always)]
pub fn intersect_watertight(r: &WoopRay, tri: &WTri) -> Option<f32> {
    let [kx, ky, kz] = r.k;
    let [sx, sy, sz] = r.s;
    let [ox, oy, oz] = r.org;
    let v = &tri.v;
    // Vertices relative to the origin, read straight from memory in the ray's axis order
    // (indexing a vector held in registers would go through the stack).
    let (az, bz, cz) = (v[0][kz] - oz, v[1][kz] - oz, v[2][kz] - oz);
    // Shear (eq. 3): vertices in the ray's frame, where the ray is the +z axis through (0, 0).
    let (ax, ay) = ((v[0][kx] - ox) - sx * az, (v[0][ky] - oy) - sy * az);
    let (bx, by) = ((v[1][kx] - ox) - sx * bz, (v[1][ky] - oy) - sy * bz);
    let (cx, cy) = ((v[2][kx] - ox) - sx * cz, (v[2][ky] - oy) - sy * cz);
    // Scaled barycentrics as 2D edge functions (section 3.2).
    let u = cx * by - cy * bx;
    let v = ax * cy - ay * cx;
    let w = bx * ay - by * ax;
    let det = u + v + w;
    // An edge function exactly 0 (the ray on an edge) or a det outside the trusted range
    // (including NaN and inf) is decided in f64 (section 3.3).
    if u == 0.0 || v == 0.0 || w == 0.0 || !(det.abs() >= DET_MIN && det.abs() <= DET_MAX) {
        return intersect_watertight_f64(r, tri);
    }
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return None;
    }
    let t = u * (sz * az) + v * (sz * bz) + w * (sz * cz);
    Some(t / det)
}

/// [`intersect_watertight`] in f64 (the inputs convert exactly): the rare fallback.
#[cold]
#[inline(never)]
fn intersect_watertight_f64(r: &WoopRay, tri: &WTri) -> Option<f32> {
    // Component j (0 = kx, 1 = ky, 2 = kz) of vertex i relative to the origin.
    let d = |i: usize, j: usize| tri.v[i][r.k[j]] as f64 - r.org[j] as f64;
    let (sx, sy, sz) = (r.s[0] as f64, r.s[1] as f64, r.s[2] as f64);
    let sh = |i: usize| (d(i, 0) - sx * d(i, 2), d(i, 1) - sy * d(i, 2));
    let ((ax, ay), (bx, by), (cx, cy)) = (sh(0), sh(1), sh(2));
    let u = cx * by - cy * bx;
    let v = ax * cy - ay * cx;
    let w = bx * ay - by * ax;
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return None;
    }
    let det = u + v + w;
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let t = (u * d(0, 2) + v * d(1, 2) + w * d(2, 2)) * sz / det;
    Some(t as f32)
}

/// The timed test: [`intersect_watertight`].
pub struct Watertight;

impl TriTest for Watertight {
    type Ray = WoopRay;
    #[inline(always)]
    fn prepare(ray: &Ray, inv: &[f32; 3]) -> WoopRay {
        WoopRay::with_inverse(ray.origin, ray.dir, inv)
    }
    #[inline(always)]
    unsafe fn prepare_avx2(ray: &Ray, inv: &[f32; 3]) -> WoopRay {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the caller guarantees AVX2 (so AVX).
        return unsafe { WoopRay::with_inverse_avx(ray.origin, ray.dir, inv) };
        #[cfg(not(target_arch = "x86_64"))]
        WoopRay::with_inverse(ray.origin, ray.dir, inv)
    }
    #[inline(always)]
    fn test(r: &WoopRay, tri: &WTri) -> Option<f32> {
        intersect_watertight(r, tri)
    }
    /// Four triangles per SSE test where four are in memory (a leaf's triangles are consecutive;
    /// lanes past its last one are masked), the rest one by one. Same values as [`Self::test`].
    #[inline(always)]
    fn test_leaf(r: &WoopRay, tris: &[WTri], best: &mut Hit) -> u32 {
        #[cfg(target_arch = "x86_64")]
        return by_axis_order!(leaf4, r, tris, best);
        #[cfg(not(target_arch = "x86_64"))]
        Exact::test_leaf_with(r, tris, best, intersect_watertight)
    }
    #[inline(always)]
    unsafe fn test_leaf_avx2(r: &WoopRay, tris: &[WTri], best: &mut Hit) -> u32 {
        // SAFETY: the caller guarantees AVX2.
        #[cfg(target_arch = "x86_64")]
        return unsafe { by_axis_order!(leaf4_avx2, r, tris, best) };
        #[cfg(not(target_arch = "x86_64"))]
        Exact::test_leaf_with(r, tris, best, intersect_watertight)
    }
    #[inline(always)]
    fn test_packs(r: &WoopRay, packs: &[Tri4], best: &mut Hit) -> u32 {
        #[cfg(target_arch = "x86_64")]
        return crate::packs::watertight_packs_sse(r, packs, best);
        #[cfg(not(target_arch = "x86_64"))]
        crate::packs::test_packs_with(r, packs, best, intersect_watertight)
    }
    /// Inlined into the caller (the wide traversals' AVX2 builds), so it is compiled for AVX2
    /// with it, and the ray's data stay in its registers: as a call of its own, the leaf test's
    /// entry and exit cost 16 instructions per leaf and the walk spilled around it (callgrind on
    /// breakfast_room: -6 % instructions inlined).
    #[inline(always)]
    unsafe fn test_packs_avx2(r: &WoopRay, packs: &[Tri4], best: &mut Hit) -> u32 {
        #[cfg(target_arch = "x86_64")]
        return crate::packs::watertight_packs(r, packs, best);
        #[cfg(not(target_arch = "x86_64"))]
        crate::packs::test_packs_with(r, packs, best, intersect_watertight)
    }
}

/// Calls the instance of leaf test `$f` for the ray's axis order (Woop et al. 2013: kz its largest
/// direction component, kx and ky the others, swapped when that component is negative; all six
/// orders occur): with the order a constant, the four-wide test picks its columns from registers
/// instead of indexing an array of them through the stack (measured: the spills and a failed
/// store-to-load forwarding were the leaf test's hottest spots).
#[cfg(target_arch = "x86_64")]
macro_rules! by_axis_order {
    ($f:ident, $r:expr, $tris:expr, $best:expr) => {
        match $r.k {
            [0, 1, 2] => $f::<0, 1, 2>($r, $tris, $best),
            [1, 0, 2] => $f::<1, 0, 2>($r, $tris, $best),
            [1, 2, 0] => $f::<1, 2, 0>($r, $tris, $best),
            [2, 1, 0] => $f::<2, 1, 0>($r, $tris, $best),
            [2, 0, 1] => $f::<2, 0, 1>($r, $tris, $best),
            [0, 2, 1] => $f::<0, 2, 1>($r, $tris, $best),
            _ => Exact::test_leaf_with($r, $tris, $best, intersect_watertight),
        }
    };
}
#[cfg(target_arch = "x86_64")]
use by_axis_order;

/// [`Watertight::test_leaf`] for a ray whose axis order `r.k` is `[KX, KY, KZ]`.
#[cfg(target_arch = "x86_64")]
#[inline(never)]
fn leaf4<const KX: usize, const KY: usize, const KZ: usize>(
    r: &WoopRay,
    tris: &[WTri],
    best: &mut Hit,
) -> u32 {
    leaf4_body::<KX, KY, KZ>(r, tris, best)
}

/// [`leaf4`] compiled for AVX2 (the wide traversals' AVX2 path): three-operand instructions
/// instead of SSE's register copies, the same operations otherwise (no FMA), so the same hits.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[inline(never)]
#[target_feature(enable = "avx2")]
unsafe fn leaf4_avx2<const KX: usize, const KY: usize, const KZ: usize>(
    r: &WoopRay,
    tris: &[WTri],
    best: &mut Hit,
) -> u32 {
    leaf4_body::<KX, KY, KZ>(r, tris, best)
}

#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn leaf4_body<const KX: usize, const KY: usize, const KZ: usize>(
    r: &WoopRay,
    tris: &[WTri],
    best: &mut Hit,
) -> u32 {
    debug_assert_eq!(r.k, [KX, KY, KZ]);
    let mut n = 0;
    let mut rest = tris;
    while let Some(q) = rest.first_chunk::<4>() {
        // SAFETY: SSE is in the x86-64 baseline.
        let (lanes, end) = unsafe { watertight4::<KX, KY, KZ>(r, q, best) };
        n += lanes;
        if end {
            return n;
        }
        rest = &rest[4..];
    }
    n + Exact::test_leaf_with(r, rest, best, intersect_watertight)
}

impl Exact {
    /// The one-at-a-time leaf loop with the test `f`.
    #[inline(always)]
    fn test_leaf_with<R>(
        r: &R,
        tris: &[WTri],
        best: &mut Hit,
        f: impl Fn(&R, &WTri) -> Option<f32>,
    ) -> u32 {
        let mut n = 0;
        for tri in tris {
            n += 1;
            if let Some(t) = f(r, tri) {
                accept(t, tri.prim, best);
            }
            if tri.last != 0 {
                break;
            }
        }
        n
    }
}

/// [`intersect_watertight`] on four triangles at once (SSE): `q` up to its first triangle marked
/// last (lanes after it belong to the next leaf and are masked), hits accepted into `best`; returns
/// the number of triangles tested and whether the leaf ended. The same f32 operations in the same
/// order per lane, so the same hits; a lane that needs the f64 fallback (an edge function 0, |det|
/// out of range) goes through the scalar test.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn watertight4<const KX: usize, const KY: usize, const KZ: usize>(
    r: &WoopRay,
    q: &[WTri; 4],
    best: &mut Hit,
) -> (u32, bool) {
    use std::arch::x86_64::*;
    unsafe {
        // Columns of four 4-float rows: rows[j] = floats o..o + 4 of triangle j.
        let cols = |o: usize| {
            // From the whole record (48 bytes, `repr(C)`): floats 8..12 run past `v` into `prim`,
            // `last` and `pad`.
            let row = |j: usize| _mm_loadu_ps((&q[j] as *const WTri as *const f32).add(o));
            let (r0, r1, r2, r3) = (row(0), row(1), row(2), row(3));
            let (t0, t1) = (_mm_unpacklo_ps(r0, r1), _mm_unpacklo_ps(r2, r3));
            let (t2, t3) = (_mm_unpackhi_ps(r0, r1), _mm_unpackhi_ps(r2, r3));
            [
                _mm_movelh_ps(t0, t1),
                _mm_movehl_ps(t1, t0),
                _mm_movelh_ps(t2, t3),
                _mm_movehl_ps(t3, t2),
            ]
        };
        // Floats 0..12 of a WTri are v0.xyz, v1.xyz, v2.xyz, prim, last and pad (as bits).
        let [x0, y0, z0, x1] = cols(0);
        let [y1, z1, x2, y2] = cols(4);
        let [z2, _, last, _] = cols(8);
        // The lanes up to the first marked last (compared as integers: no branch per lane).
        let ends = _mm_movemask_ps(_mm_castsi128_ps(_mm_cmpeq_epi32(
            _mm_castps_si128(last),
            _mm_setzero_si128(),
        ))) ^ 0xf;
        let lanes = if ends == 0 {
            4
        } else {
            ends.trailing_zeros() + 1
        };
        let v = [[x0, y0, z0], [x1, y1, z1], [x2, y2, z2]];
        let valid = (1i32 << lanes) - 1;
        let done = (lanes, ends != 0);
        // Columns picked by the constant axis order (from registers).
        let axes = [KX, KY, KZ];
        woop4(r, |i, j| v[i][axes[j]], valid, |l| q[l].prim, |l| q[l], best);
        done
    }
}

/// The four-lane core of the watertight test (Woop et al. 2013, fig. 6) shared by the AoS leaf test
/// ([`watertight4`]) and the packs ([`crate::packs`]): `row(i, j)` gives coordinate `r.k[j]` of
/// vertex `i` of the four triangles. The same f32 operations in the same order per lane as
/// [`intersect_watertight`], so the same values. The lanes of `valid` that hit are accepted into
/// `best` with scene index `prim(l)` ([`accept`] checks the ray's range); those that need the
/// one-triangle test's f64 fallback (an edge function 0, |det| untrusted) go through it with
/// `tri(l)`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) unsafe fn woop4(
    r: &WoopRay,
    row: impl Fn(usize, usize) -> std::arch::x86_64::__m128,
    valid: i32,
    prim: impl Fn(usize) -> u32,
    tri: impl Fn(usize) -> WTri,
    best: &mut Hit,
) {
    use std::arch::x86_64::*;
    unsafe {
        let set = _mm_set1_ps;
        let (ox, oy, oz) = (set(r.org[0]), set(r.org[1]), set(r.org[2]));
        let (sx, sy) = (set(r.s[0]), set(r.s[1]));
        // Every vertex coordinate as origin minus vertex, the negation of the scalar test's
        // vertex minus origin (so the row is the subtrahend, which AVX takes from memory), and
        // so are the sheared coordinates: IEEE rounding is symmetric, so each is the exact
        // negation of the scalar test's value, the edge functions' products (two negated
        // factors) and det are the same bits, and t is the same with -sz.
        let (az, bz, cz) = (_mm_sub_ps(oz, row(0, 2)), _mm_sub_ps(oz, row(1, 2)), _mm_sub_ps(oz, row(2, 2)));
        let sh = |i: usize, z: __m128| {
            (
                _mm_sub_ps(_mm_sub_ps(ox, row(i, 0)), _mm_mul_ps(sx, z)),
                _mm_sub_ps(_mm_sub_ps(oy, row(i, 1)), _mm_mul_ps(sy, z)),
            )
        };
        let ((ax, ay), (bx, by), (cx, cy)) = (sh(0, az), sh(1, bz), sh(2, cz));
        let u = _mm_sub_ps(_mm_mul_ps(cx, by), _mm_mul_ps(cy, bx));
        let vv = _mm_sub_ps(_mm_mul_ps(ax, cy), _mm_mul_ps(ay, cx));
        let w = _mm_sub_ps(_mm_mul_ps(bx, ay), _mm_mul_ps(by, ax));
        let det = _mm_add_ps(_mm_add_ps(u, vv), w);
        let zero = _mm_setzero_ps();
        let on_edge = _mm_or_ps(_mm_or_ps(_mm_cmpeq_ps(u, zero), _mm_cmpeq_ps(vv, zero)), _mm_cmpeq_ps(w, zero));
        // |det| outside [DET_MIN, DET_MAX] (or NaN) as one unsigned comparison of its bits:
        // |det| - DET_MIN > DET_MAX - DET_MIN, unsigned, is that signed after flipping the sign bits.
        let abits = _mm_and_si128(_mm_castps_si128(det), _mm_set1_epi32(i32::MAX));
        let flip = |b: u32| b.wrapping_sub(DET_MIN.to_bits()) ^ (1 << 31);
        let untrusted = _mm_cmpgt_epi32(
            _mm_add_epi32(abits, _mm_set1_epi32(flip(0) as i32)),
            _mm_set1_epi32(flip(DET_MAX.to_bits()) as i32),
        );
        let fall = _mm_or_ps(on_edge, _mm_castsi128_ps(untrusted));
        let fallback = _mm_movemask_ps(fall) & valid;
        // Mixed signs miss. Outside `fallback` no edge function is 0 or NaN (a NaN makes det
        // NaN), so mixed is a sign bit that differs from u's.
        let mixed = _mm_or_ps(_mm_xor_ps(u, vv), _mm_xor_ps(u, w));
        let mut cand = !_mm_movemask_ps(_mm_or_ps(mixed, fall)) & valid;
        if cand != 0 {
            let nsz = set(-r.s[2]);
            let t = _mm_add_ps(
                _mm_add_ps(_mm_mul_ps(u, _mm_mul_ps(nsz, az)), _mm_mul_ps(vv, _mm_mul_ps(nsz, bz))),
                _mm_mul_ps(w, _mm_mul_ps(nsz, cz)),
            );
            let mut ts = [0f32; 4];
            _mm_storeu_ps(ts.as_mut_ptr(), _mm_div_ps(t, det));
            while cand != 0 {
                let l = cand.trailing_zeros() as usize;
                cand &= cand - 1;
                accept(ts[l], prim(l), best);
            }
        }
        let mut fb = fallback;
        while fb != 0 {
            let l = fb.trailing_zeros() as usize;
            fb &= fb - 1;
            let t = tri(l);
            if let Some(d) = intersect_watertight(r, &t) {
                accept(d, t.prim, best);
            }
        }
    }
}

/// Per-ray box-test data: origin, inverse direction and the direction's octant, which gives per
/// axis which of the six box coordinates (`[min.x, min.y, min.z, max.x, max.y, max.z]`) is the
/// near plane ([`SlabRay::planes`]).
#[derive(Clone, Copy, Debug)]
pub struct SlabRay {
    pub origin: [f32; 3],
    pub inv: [f32; 3],
    /// Bit `a`: the direction is negative along axis `a` (the near plane is the box's max).
    pub oct: u32,
    /// Some inverse direction component is not finite or is zero (a zero, subnormal or infinite
    /// direction component, or NaN): use [`RayBox::hit`] instead (exact for such rays).
    pub parallel: bool,
}

/// Rows of the near and far plane per axis among a box's `[min.x, min.y, min.z, max.x, max.y,
/// max.z]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Planes {
    pub near: [usize; 3],
    pub far: [usize; 3],
}

impl Planes {
    /// The planes of octant `oct` (bit `a` set: negative along `a`, the near plane is the max).
    #[inline(always)]
    pub const fn of(oct: u32) -> Planes {
        let n = [(oct & 1) as usize * 3, (oct >> 1 & 1) as usize * 3, (oct >> 2 & 1) as usize * 3];
        Planes {
            near: [n[0], 1 + n[1], 2 + n[2]],
            far: [3 - n[0], 4 - n[1], 5 - n[2]],
        }
    }
}

impl SlabRay {
    /// The ray's near and far plane rows.
    #[inline(always)]
    pub fn planes(&self) -> Planes {
        Planes::of(self.oct)
    }

    #[inline(always)]
    pub fn new(ray: &Ray) -> SlabRay {
        let d = ray.dir;
        // One SSE division and sign mask (this runs once per ray: written with scalars and array
        // maps it compiled to about 50 instructions, callgrind on breakfast_room).
        #[cfg(target_arch = "x86_64")]
        // SAFETY: SSE is in the x86-64 baseline.
        let (inv, oct, ok) = unsafe {
            use std::arch::x86_64::*;
            let i4 = _mm_div_ps(_mm_set1_ps(1.0), _mm_setr_ps(d.x, d.y, d.z, 1.0));
            let a = _mm_andnot_ps(_mm_set1_ps(-0.0), i4);
            let ok = _mm_and_ps(_mm_cmplt_ps(a, _mm_set1_ps(f32::INFINITY)), _mm_cmpgt_ps(a, _mm_setzero_ps()));
            let mut inv = [0f32; 4];
            _mm_storeu_ps(inv.as_mut_ptr(), i4);
            ([inv[0], inv[1], inv[2]], _mm_movemask_ps(i4) as u32 & 7, _mm_movemask_ps(ok) == 0xf)
        };
        #[cfg(not(target_arch = "x86_64"))]
        let (inv, oct, ok) = {
            let inv = [1.0 / d.x, 1.0 / d.y, 1.0 / d.z];
            let ok = inv.iter().all(|i| i.is_finite() && *i != 0.0);
            let oct = (0..3).map(|a| (inv[a].is_sign_negative() as u32) << a).sum();
            (inv, oct, ok)
        };
        // For the rays that use it (finite nonzero inverse) the sign bit is `inv < 0`.
        SlabRay {
            origin: ray.origin.to_array(),
            inv,
            oct,
            // A zero (or subnormal) component has no finite inverse: (bound - origin) * inf is NaN
            // on a slab plane; an infinite one has inverse 0, and (inf bound - origin) * 0 is NaN.
            // Such rays take `RayBox::hit`; every other ray's products are NaN-free.
            parallel: !ok,
        }
    }

    /// Whether [`Self::hit`] finds an entry, in one SSE pass (the per-ray root test of the
    /// timed paths): the same products, combined in the same order by `maxps` / `minps`, which
    /// are `fmax` / `fmin` exactly (the second operand when either is NaN), so the same answer.
    #[inline(always)]
    pub fn enters(&self, b: &Aabb, tmax: f32) -> bool {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: SSE is in the x86-64 baseline.
        unsafe {
            use std::arch::x86_64::*;
            let (o, i) = (self.origin, self.inv);
            // Lane 3 carries the clamps: a near plane 0 and a far plane tmax (origin 0, inverse 1).
            let o4 = _mm_setr_ps(o[0], o[1], o[2], 0.0);
            let i4 = _mm_setr_ps(i[0], i[1], i[2], 1.0);
            let lo = _mm_setr_ps(b.min.x, b.min.y, b.min.z, 0.0);
            let hi = _mm_setr_ps(b.max.x, b.max.y, b.max.z, tmax);
            let neg = _mm_cmplt_ps(i4, _mm_setzero_ps());
            let np = _mm_or_ps(_mm_and_ps(neg, hi), _mm_andnot_ps(neg, lo));
            let fp = _mm_or_ps(_mm_and_ps(neg, lo), _mm_andnot_ps(neg, hi));
            let tn = _mm_mul_ps(_mm_sub_ps(np, o4), i4);
            let tf = _mm_mul_ps(_mm_sub_ps(fp, o4), i4);
            // fmax(fmax(x, y), fmax(z, 0)) as `hit`: pairs first, then the two pairs.
            let n2 = _mm_max_ps(tn, _mm_shuffle_ps::<0b10_11_00_01>(tn, tn));
            let near = _mm_max_ss(n2, _mm_movehl_ps(n2, n2));
            let f2 = _mm_min_ps(tf, _mm_shuffle_ps::<0b10_11_00_01>(tf, tf));
            let far = _mm_min_ss(f2, _mm_movehl_ps(f2, f2));
            _mm_cvtss_f32(near) <= _mm_cvtss_f32(far) * SLAB_ROBUST
        }
        #[cfg(not(target_arch = "x86_64"))]
        self.hit(b, tmax).is_some()
    }

    #[inline(always)]
    pub fn hit(&self, b: &Aabb, tmax: f32) -> Option<f32> {
        let (o, i) = (self.origin, self.inv);
        let pick = |neg: bool, lo: f32, hi: f32| if neg { (hi, lo) } else { (lo, hi) };
        let (nx, fx) = pick(self.oct & 1 != 0, b.min.x, b.max.x);
        let (ny, fy) = pick(self.oct & 2 != 0, b.min.y, b.max.y);
        let (nz, fz) = pick(self.oct & 4 != 0, b.min.z, b.max.z);
        let near = fmax(
            fmax((nx - o[0]) * i[0], (ny - o[1]) * i[1]),
            fmax((nz - o[2]) * i[2], 0.0),
        );
        let far = fmin(
            fmin((fx - o[0]) * i[0], (fy - o[1]) * i[1]),
            fmin((fz - o[2]) * i[2], tmax),
        ) * SLAB_ROBUST;
        if near <= far {
            Some(near)
        } else {
            None
        }
    }
}

#[inline(always)]
fn fmin(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}
#[inline(always)]
fn fmax(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// A box test chosen per ray: the sign-selected slab test, or [`RayBox`] for parallel rays.
trait BoxTest {
    fn hit(&self, b: &Aabb, tmax: f32) -> Option<f32>;
}
impl BoxTest for SlabRay {
    #[inline(always)]
    fn hit(&self, b: &Aabb, tmax: f32) -> Option<f32> {
        SlabRay::hit(self, b, tmax)
    }
}
impl BoxTest for RayBox {
    #[inline(always)]
    fn hit(&self, b: &Aabb, tmax: f32) -> Option<f32> {
        RayBox::hit(self, b, tmax)
    }
}

/// A worker's stacks on bvh2's timed path: the flat traversal's and the child pairs'.
#[cfg(target_arch = "x86_64")]
type PairStacks = (Stack, Stack<(u32, u32, f32)>);

/// A binary BVH prepared for the timed path: its inner nodes as child pairs ([`crate::pairs`]: both
/// child boxes in one 64-byte line, tested with one SSE pass; the same bytes as the flat nodes, 32
/// per node), the flat nodes for the rays the pairs do not take, and its triangles in slot order.
pub struct FastBvh2<'a> {
    nodes: &'a [Node],
    /// The triangles, unless the arena holds them.
    store: TriStore,
    /// The inner nodes as child pairs and the triangles after them in one arena (the timed path's
    /// layout, x86-64 only: an SSE test), unless the root is a leaf or the tree is malformed.
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    pairs: Option<Arena>,
}

impl<'a> FastBvh2<'a> {
    /// O(triangles): copies the triangles into slot order (done before timing).
    pub fn new(bvh: &'a Bvh, tris: &[Triangle]) -> FastBvh2<'a> {
        let mut store = TriStore::new(&bvh.prim_indices, tris);
        let pairs = if cfg!(target_arch = "x86_64") {
            Pairs::new(&bvh.nodes).and_then(|p| Arena::new(&p, &store.tris))
        } else {
            None
        };
        if pairs.is_some() {
            // The arena holds the triangles; the flat traversal reads them there (see `tris`).
            store.tris = Vec::new();
        }
        FastBvh2 { nodes: &bvh.nodes, store, pairs }
    }

    /// The triangles in slot order: the arena's when there is one, else the store's.
    fn tris(&self) -> &[WTri] {
        match &self.pairs {
            Some(a) => a.tris(),
            None => &self.store.tris,
        }
    }

    /// Closest hits with the watertight f32 test, no counters: the timed path. Rays with a finite
    /// origin and direction and no zero direction component traverse the child pairs
    /// ([`crate::pairs`]), the others (and every ray of a tree without pairs) the flat nodes; the
    /// same hits either way.
    pub fn hits(&self, rays: &[Ray]) -> Vec<Hit> {
        #[cfg(target_arch = "x86_64")]
        if let Some(p) = &self.pairs {
            // The pairs and the leaf test in their AVX2 build where the CPU has it: the same hits in
            // fewer instructions (callgrind, dragon: 1,097 -> 940 per ray; 1-2 % faster; the arena's
            // offsets then 940 -> 818 and 5-9 % faster, docs/decisions.md).
            let avx2 = std::is_x86_feature_detected!("avx2");
            let mut hits = vec![Hit::NONE; rays.len()];
            hits.par_chunks_mut(CHUNK)
                .zip(rays.par_chunks(CHUNK))
                .for_each_init(
                    || (Stack::new(), Stack::new()),
                    |stacks, (h, r)| {
                        if avx2 {
                            // SAFETY: AVX2 was detected.
                            unsafe { self.pairs_chunk_avx2(p, r, h, stacks) }
                        } else {
                            self.pairs_chunk::<false>(p, r, h, stacks)
                        }
                    },
                );
            return hits;
        }
        self.hits_flat(rays)
    }

    /// [`Self::hits`] on a chunk of rays with the child pairs. `AVX2`: compiled for AVX2 (only
    /// through [`Self::pairs_chunk_avx2`]) and the leaf test's AVX2 build: the same operations
    /// VEX-encoded (three operands, no register copies; no FMA), so the same hits.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn pairs_chunk<const AVX2: bool>(&self, p: &Arena, rays: &[Ray], hits: &mut [Hit], stacks: &mut PairStacks) {
        let nodes = self.nodes;
        let (flat, paired) = stacks;
        for (h, ray) in hits.iter_mut().zip(rays) {
            let sr = SlabRay::new(ray);
            // Non-finite origins or directions can make a product NaN, where the pairs' min / max
            // and the flat test's plane choice differ.
            let finite = ray.origin.is_finite() && ray.dir.is_finite();
            *h = if sr.parallel || !finite {
                self.one::<Watertight, false>(ray, flat).0
            } else if ray.tmax.is_nan()
                || ray.tmax <= 0.0
                || nodes[0].bounds.is_empty()
                || !sr.enters(&nodes[0].bounds, ray.tmax)
            {
                Hit::NONE
            } else {
                pairs_one::<Watertight, AVX2>(p, ray, sr.inv, paired)
            };
        }
    }

    /// [`Self::pairs_chunk`] compiled for AVX2.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn pairs_chunk_avx2(&self, p: &Arena, rays: &[Ray], hits: &mut [Hit], stacks: &mut PairStacks) {
        self.pairs_chunk::<true>(p, rays, hits, stacks)
    }

    /// [`Self::hits`] on the flat 32-byte nodes for every ray (what the timed path was before the
    /// child pairs; kept to compare the two layouts in one benchmark).
    pub fn hits_flat(&self, rays: &[Ray]) -> Vec<Hit> {
        par_hits(rays, |stack, ray| {
            self.one::<Watertight, false>(ray, stack).0
        })
    }

    /// Hits and counters with the test `T` (untimed: the counting instantiation).
    pub fn trace<T: TriTest>(&self, rays: &[Ray]) -> TraceStats {
        crate::trace_with(rays, Stack::new, |stack, ray| {
            self.one::<T, true>(ray, stack)
        })
    }

    #[inline(always)]
    fn one<T: TriTest, const STATS: bool>(&self, ray: &Ray, stack: &mut Stack) -> (Hit, u32, u32) {
        let sr = SlabRay::new(ray);
        if sr.parallel {
            bvh2_one::<T, RayBox, STATS>(
                self.nodes,
                self.tris(),
                ray,
                &RayBox::new(ray),
                sr.inv,
                stack,
            )
        } else {
            bvh2_one::<T, SlabRay, STATS>(self.nodes, self.tris(), ray, &sr, sr.inv, stack)
        }
    }
}

/// Runs `one` over all rays in parallel (rayon chunks, a stack per task), hits only.
pub fn par_hits<F>(rays: &[Ray], one: F) -> Vec<Hit>
where
    F: Fn(&mut Stack, &Ray) -> Hit + Sync + Send,
{
    let mut hits = vec![Hit::NONE; rays.len()];
    hits.par_chunks_mut(CHUNK)
        .zip(rays.par_chunks(CHUNK))
        .for_each_init(Stack::new, |stack, (h, r)| {
            for (h, r) in h.iter_mut().zip(r) {
                *h = one(stack, r);
            }
        });
    hits
}

/// Rays per rayon task (as in `trace_with`).
const CHUNK: usize = 1024;

/// `crate::traverse::trace_one` with the triangles in slot order, a generic box and triangle test
/// and optional counters; same visiting order and culling rule (so `Exact` finds the same hits).
#[inline(always)]
fn bvh2_one<T: TriTest, B: BoxTest, const STATS: bool>(
    nodes: &[Node],
    tris: &[WTri],
    ray: &Ray,
    rb: &B,
    inv: [f32; 3],
    stack: &mut Stack,
) -> (Hit, u32, u32) {
    let mut best = Hit::within(ray.tmax);
    let (mut steps, mut tests) = (0u32, 0u32);
    let Some(root) = nodes.first() else {
        return (Hit::NONE, 0, 0);
    };
    if ray.tmax.is_nan()
        || ray.tmax <= 0.0
        || root.bounds.is_empty()
        || rb.hit(&root.bounds, best.t).is_none()
    {
        return (Hit::NONE, 0, 0);
    }
    // Prepared at the first leaf: many rays never reach one.
    let mut tr: Option<T::Ray> = None;
    stack.clear();
    let mut cur = 0u32;
    // A valid tree enters each node at most once per ray; the bound stops a cycle in a malformed one.
    let mut budget = nodes.len();
    loop {
        if budget == 0 {
            break;
        }
        budget -= 1;
        if STATS {
            steps += 1;
        }
        let node = &nodes[cur as usize];
        if node.count > 0 {
            let first = (node.first as usize).min(tris.len());
            let end = first.saturating_add(node.count as usize).min(tris.len());
            let tr = &*tr.get_or_insert_with(|| T::prepare(ray, &inv));
            for tri in &tris[first..end] {
                if STATS {
                    tests += 1;
                }
                if let Some(t) = T::test(tr, tri) {
                    accept(t, tri.prim, &mut best);
                }
            }
        } else {
            let l = node.first as usize;
            if let (Some(ln), Some(rn)) = (nodes.get(l), nodes.get(l.wrapping_add(1))) {
                let hl = rb.hit(&ln.bounds, best.t);
                let hr = rb.hit(&rn.bounds, best.t);
                match (hl, hr) {
                    (Some(tl), Some(tr)) => {
                        if tr < tl {
                            stack.push((l as u32, tl));
                            cur = l as u32 + 1;
                        } else {
                            stack.push((l as u32 + 1, tr));
                            cur = l as u32;
                        }
                        continue;
                    }
                    (Some(_), None) => {
                        cur = l as u32;
                        continue;
                    }
                    (None, Some(_)) => {
                        cur = l as u32 + 1;
                        continue;
                    }
                    (None, None) => {}
                }
            }
        }
        // Pop until a node whose entry is not beyond the closest hit (margin as in `trace_one`).
        match stack.pop_within(best.t * SLAB_ROBUST) {
            Some((n, _)) => cur = n,
            None => break,
        }
    }
    let hit = best.found();
    (hit, steps, tests)
}

/// The tolerance of the f32 path against the exact one, per ray: the same triangle; or both hit
/// and `t` agrees within `1e-5` relative (two triangles within f32 rounding of each other along
/// the ray: shared edges, coplanar overlaps); or one side misses and the other's hit is within f32
/// rounding of an edge of its triangle (f64 barycentric coordinate below `1e-5`: the ray grazes an
/// edge, where f32 and f64 may decide differently). Returns why not, if not.
pub fn agrees(tris: &[Triangle], ray: &Ray, fast: &Hit, exact: &Hit) -> Result<(), String> {
    const T_TOL: f32 = 1e-5;
    const EDGE_TOL: f64 = 1e-5;
    if fast.prim == exact.prim {
        return Ok(());
    }
    if fast.is_hit() && exact.is_hit() {
        if (fast.t - exact.t).abs() <= T_TOL * exact.t.abs() {
            return Ok(());
        }
        return Err(format!(
            "fast {fast:?} and exact {exact:?} differ beyond t tolerance"
        ));
    }
    let h = if fast.is_hit() { fast } else { exact };
    match tris.get(h.prim as usize).and_then(|t| min_barycentric(ray, t)) {
        Some(b) if b <= EDGE_TOL => Ok(()),
        b => Err(format!(
            "fast {fast:?}, exact {exact:?}: hit/miss disagree away from an edge (min barycentric {b:?})"
        )),
    }
}

/// Smallest barycentric coordinate (f64, Möller-Trumbore) of the ray's hit on `tri`'s plane.
fn min_barycentric(ray: &Ray, tri: &Triangle) -> Option<f64> {
    let [v0, v1, v2] = tri.v.map(|v| v.as_dvec3());
    let (o, d) = (ray.origin.as_dvec3(), ray.dir.as_dvec3());
    let (e1, e2) = (v1 - v0, v2 - v0);
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 || !det.is_finite() {
        return Some(0.0);
    }
    let s = o - v0;
    let u = s.dot(p) / det;
    let v = d.dot(s.cross(e1)) / det;
    Some(u.abs().min(v.abs()).min((1.0 - u - v).abs()))
}

/// Checks `fast` hits against `exact` hits ray by ray ([`agrees`]); at most `max_edge_cases` rays
/// may be hit/miss disagreements at an edge (different triangles at the same t are ties, not
/// counted). Returns the number of rays whose triangle differs at all.
pub fn check_agreement(
    tris: &[Triangle],
    rays: &[Ray],
    fast: &[Hit],
    exact: &[Hit],
    max_edge_cases: usize,
) -> Result<usize, String> {
    if fast.len() != rays.len() || exact.len() != rays.len() {
        return Err("hit counts differ from the ray count".into());
    }
    let (mut differ, mut edge) = (0, 0);
    for (i, ((r, f), e)) in rays.iter().zip(fast).zip(exact).enumerate() {
        if f.prim != e.prim {
            differ += 1;
            edge += (f.is_hit() != e.is_hit()) as usize;
            agrees(tris, r, f, e).map_err(|m| format!("ray {i}: {m}"))?;
        }
    }
    if edge > max_edge_cases {
        return Err(format!(
            "{edge} rays hit on one side only (at most {max_edge_cases} allowed)"
        ));
    }
    Ok(differ)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// bvh2's timed path in its AVX2 build and its baseline build find the same hits, bit for bit
    /// (the same operations, only VEX-encoded), on a scene with leaves of both kinds.
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn pairs_avx2_build_equals_the_baseline_build() {
        if !std::is_x86_feature_detected!("avx2") {
            return;
        }
        let scene = bvhlab_geom::load_scene("gen:hairball:n=3000").unwrap();
        let tris = &scene.triangles;
        let (boxes, centers) = scene.boxes_and_centers();
        // Leaves of up to 8 triangles: below and above the four-wide leaf test's 4.
        let cfg = bvhlab_builders::TopDownConfig { leaf: 8, ..Default::default() };
        let bvh = bvhlab_builders::binned_sah::build(&boxes, &centers, 16, &cfg);
        let f = FastBvh2::new(&bvh, tris);
        assert!(bvh.nodes.iter().any(|n| n.count >= 4) && bvh.nodes.iter().any(|n| n.count > 0 && n.count < 4));
        let p = f.pairs.as_ref().expect("pairs");
        let b = bvh.nodes[0].bounds;
        let rays = crate::random_rays(&b, 0.5 * b.extent_f64().length() as f32, 20_000, 3);
        let (mut a, mut v) = (vec![Hit::NONE; rays.len()], vec![Hit::NONE; rays.len()]);
        let mut stacks = (Stack::new(), Stack::new());
        f.pairs_chunk::<false>(p, &rays, &mut a, &mut stacks);
        // SAFETY: AVX2 was detected.
        unsafe { f.pairs_chunk_avx2(p, &rays, &mut v, &mut stacks) };
        assert!(a.iter().filter(|h| h.is_hit()).count() > 1000, "the rays hit the scene");
        let bits = |h: &[Hit]| h.iter().map(|h| (h.prim, h.t.to_bits())).collect::<Vec<_>>();
        assert_eq!(bits(&a), bits(&v));
        assert_eq!(f.hits(&rays), v);
    }

    /// The AVX build of the watertight ray setup gives `with_inverse`'s values bit for bit: every
    /// axis order, ties between components, zeros of both signs, subnormal, infinite and NaN.
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn woop_setup_avx_equals_the_scalar_one() {
        if !std::is_x86_feature_detected!("avx2") {
            return;
        }
        let vals = [0.0f32, -0.0, 1.0, -1.0, 0.5, -2.0, 3.0, 1e-40, -1e-40, f32::INFINITY, f32::NEG_INFINITY, f32::NAN, 1e30];
        let bits = |r: &WoopRay| (r.org.map(f32::to_bits), r.k, r.s.map(f32::to_bits));
        for &x in &vals {
            for &y in &vals {
                for &z in &vals {
                    let (o, d) = (Vec3::new(0.25, -7.0, 1e3), Vec3::new(x, y, z));
                    let inv = [1.0 / x, 1.0 / y, 1.0 / z];
                    // SAFETY: AVX2 was detected.
                    let avx = unsafe { WoopRay::with_inverse_avx(o, d, &inv) };
                    assert_eq!(bits(&avx), bits(&WoopRay::with_inverse(o, d, &inv)), "{d:?}");
                }
            }
        }
    }
}
