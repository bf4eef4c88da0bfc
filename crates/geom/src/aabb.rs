use glam::Vec3;
use serde::{Deserialize, Serialize};

/// `a < b ? a : b`: one `minss`/`minps` in slab tests and box unions of hot loops (`f32::min` adds
/// NaN handling they do not need: a NaN input only makes a later `near <= far` false, a miss).
#[inline(always)]
pub fn fmin(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

/// `a > b ? a : b`: see [`fmin`].
#[inline(always)]
pub fn fmax(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// Axis-aligned bounding box. The empty box has min = +inf, max = -inf so that `grow` needs no branch.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Aabb {
    pub min: Vec3,
    pub max: Vec3,
}

impl Default for Aabb {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl Aabb {
    pub const EMPTY: Aabb = Aabb { min: Vec3::splat(f32::INFINITY), max: Vec3::splat(f32::NEG_INFINITY) };

    #[inline]
    pub fn new(min: Vec3, max: Vec3) -> Self {
        Self { min, max }
    }
    #[inline]
    pub fn from_point(p: Vec3) -> Self {
        Self { min: p, max: p }
    }
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x || self.min.y > self.max.y || self.min.z > self.max.z
    }
    #[inline]
    pub fn grow_point(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    #[inline]
    pub fn grow(&mut self, b: &Aabb) {
        self.min = self.min.min(b.min);
        self.max = self.max.max(b.max);
    }
    #[inline]
    pub fn union(&self, b: &Aabb) -> Aabb {
        Aabb { min: self.min.min(b.min), max: self.max.max(b.max) }
    }
    /// Largest distance from the box centre to any of `points` (0 for none): the radius of the
    /// sphere random rays start on (thesis 4.4). In f64: squared f32 lengths underflow below 1e-19
    /// and overflow above 1e19 (issue 15).
    pub fn enclosing_radius(&self, points: impl IntoIterator<Item = Vec3>) -> f32 {
        let c = self.center().as_dvec3();
        points
            .into_iter()
            .map(|p| (p.as_dvec3() - c).length() as f32)
            .fold(0.0f32, f32::max)
    }
    #[inline]
    pub fn extent(&self) -> Vec3 {
        self.max - self.min
    }
    /// The centre, computed as `min/2 + max/2`: the same float as `(min + max)/2` for normal
    /// numbers (halving is exact), but it cannot overflow for boxes near f32::MAX (issue 15).
    #[inline]
    pub fn center(&self) -> Vec3 {
        self.min * 0.5 + self.max * 0.5
    }
    /// The extent in f64: `max - min` cannot overflow there (f32 boxes spanning -3e38..3e38).
    #[inline]
    pub fn extent_f64(&self) -> glam::DVec3 {
        self.max.as_dvec3() - self.min.as_dvec3()
    }
    /// Surface area in f64; 0 for the empty box (so empty bins add nothing to SAH sums).
    ///
    /// Why f64 everywhere (issue 15, scale invariance): a product of two f32 is exact in f64 and the
    /// f64 range (1e±308) holds the square of any finite f32, so areas neither overflow (coordinates
    /// from 1e17 up made every f32 split cost infinite) nor underflow (below 1e-19 f32 areas vanish),
    /// and scaling a scene by 2^k scales every area by exactly 4^k: the same comparisons, the same tree.
    #[inline]
    pub fn area(&self) -> f64 {
        let e = self.extent_f64();
        if e.x < 0.0 || e.y < 0.0 || e.z < 0.0 {
            return 0.0;
        }
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    }
    /// Same as [`Aabb::area`] (kept for call sites that say which precision they rely on).
    #[inline]
    pub fn area_f64(&self) -> f64 {
        self.area()
    }
    /// Index (0, 1, 2) of the axis with the largest extent; ties go to the lower axis. Extents in
    /// f64, so that two axes spanning more than f32::MAX still compare.
    #[inline]
    pub fn largest_axis(&self) -> usize {
        let e = self.extent_f64();
        if e.x >= e.y && e.x >= e.z {
            0
        } else if e.y >= e.z {
            1
        } else {
            2
        }
    }
    #[inline]
    pub fn contains(&self, b: &Aabb) -> bool {
        self.min.cmple(b.min).all() && self.max.cmpge(b.max).all()
    }
}
