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
    /// Half the surface area; 0 for empty boxes. SAH comparisons are scale-invariant, so the builders
    /// use half areas throughout and save a multiply per candidate.
    #[inline(always)]
    pub fn half_area(&self) -> f32 {
        let e = (self.max - self.min).max(Vec3A::ZERO);
        e.x * e.y + e.y * e.z + e.z * e.x
    }
    /// Largest-extent axis; ties go to the lower axis (as `Aabb::largest_axis`).
    #[inline]
    pub fn largest_axis(&self) -> usize {
        self.to_aabb().largest_axis()
    }
    #[inline]
    pub fn to_aabb(self) -> Aabb {
        Aabb {
            min: Vec3::from(self.min),
            max: Vec3::from(self.max),
        }
    }
}
