use glam::Vec3;
use serde::{Deserialize, Serialize};

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
    #[inline]
    pub fn extent(&self) -> Vec3 {
        self.max - self.min
    }
    #[inline]
    pub fn center(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }
    /// Surface area; 0 for the empty box (so empty bins add nothing to SAH sums).
    #[inline]
    pub fn area(&self) -> f32 {
        let e = self.max - self.min;
        if e.x < 0.0 || e.y < 0.0 || e.z < 0.0 {
            return 0.0;
        }
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    }
    /// Surface area in f64, for metrics sums over millions of nodes.
    #[inline]
    pub fn area_f64(&self) -> f64 {
        let e = (self.max - self.min).as_dvec3();
        if e.x < 0.0 || e.y < 0.0 || e.z < 0.0 {
            return 0.0;
        }
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    }
    /// Index (0, 1, 2) of the axis with the largest extent; ties go to the lower axis.
    #[inline]
    pub fn largest_axis(&self) -> usize {
        let e = self.extent();
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
