//! A SIMD-friendly box used inside the builders' hot loops (glam `Vec3A`: min/max are one SSE op).
use bvhlab_bvh::Aabb;
use glam::{Vec3, Vec3A};

#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct BoxA {
    pub min: Vec3A,
    pub max: Vec3A,
}

impl BoxA {
    pub const EMPTY: BoxA = BoxA {
        min: Vec3A::splat(f32::INFINITY),
        max: Vec3A::splat(f32::NEG_INFINITY),
    };

    #[inline(always)]
    pub fn grow(&mut self, min: Vec3A, max: Vec3A) {
        self.min = self.min.min(min);
        self.max = self.max.max(max);
    }
    #[inline(always)]
    pub fn grow_point(&mut self, p: Vec3A) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    #[inline(always)]
    pub fn union(&self, o: &BoxA) -> BoxA {
        BoxA {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }
    /// Half the surface area of the box times `s` (a power of two from [`pow2_normalizer`] that
    /// brings every coordinate of the build into [-1, 1]), in f32. The full sweep's hot loop: the
    /// scaled areas are at most 12, so they and their cost sums (times primitive counts) cannot
    /// overflow, and they only underflow for extents below 2^-63 of the largest coordinate (areas
    /// relative to the scene); scaling by a power of two is exact, so the trees are scale-invariant,
    /// and the sweep keeps its f32 speed (f64 areas and costs cost the full sweep 20-28 %).
    #[inline(always)]
    pub fn half_area_scaled(&self, s: Vec3A) -> f32 {
        let e = (self.max * s - self.min * s).max(Vec3A::ZERO);
        e.x * e.y + e.y * e.z + e.z * e.x
    }
    /// Largest-extent axis; ties go to the lower axis (as `Aabb::largest_axis`).
    #[inline]
    pub fn largest_axis(&self) -> usize {
        self.to_aabb().largest_axis()
    }
    /// Largest extent over the three axes, in f64 (cannot overflow).
    #[inline]
    pub fn max_extent_f64(&self) -> f64 {
        self.to_aabb().extent_f64().max_element()
    }
    #[inline]
    pub fn to_aabb(self) -> Aabb {
        Aabb {
            min: Vec3::from(self.min),
            max: Vec3::from(self.max),
        }
    }
}

/// Power-of-two factor `s` that brings the largest finite coordinate magnitude of `boxes` into
/// [0.5, 1) (1 when there is none, or it is 0). The f32 distance kernels of PLOC and AAC
/// (union half areas) multiply every coordinate by it first: their products then neither overflow
/// (scenes from 1e17 up) nor underflow (below 1e-19). Scaling by a power of two is exact, so a scene
/// and the same scene times 2^k get identical scaled coordinates, hence identical trees (issue 15).
/// The exponent is read from the float's bits, not from a rounded `log2`.
pub(crate) fn pow2_normalizer(boxes: &[Aabb]) -> f32 {
    use rayon::prelude::*;
    let m = boxes
        .par_iter()
        .with_min_len(4096)
        .map(|b| b.min.abs().max(b.max.abs()).max_element())
        .filter(|m| m.is_finite())
        .reduce(|| 0.0f32, f32::max);
    pow2_for_max(m)
}

/// [`pow2_normalizer`] for a known largest finite coordinate magnitude `m`.
pub(crate) fn pow2_for_max(m: f32) -> f32 {
    if m == 0.0 || !m.is_finite() {
        return 1.0;
    }
    // m = f 2^e with f in [0.5, 1): s = 2^-e (in f64, so that e up to 149 for subnormal m fits;
    // the result is clamped to f32's normal powers of two).
    let (mut f, mut e) = (m as f64, 0i32);
    while f >= 1.0 {
        f *= 0.5;
        e += 1;
    }
    while f < 0.5 {
        f *= 2.0;
        e -= 1;
    }
    (2f64.powi(-e.clamp(-127, 126))) as f32
}
