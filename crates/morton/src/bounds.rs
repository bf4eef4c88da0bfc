//! The quantization frame (Riemersma 3.3): scene bounds, centroid bounds, or the concise bounds of
//! eq. 15, plus the f64 view of the frame the coders use.
use crate::BoundsMode;
use bvhlab_geom::{Aabb, Vec3};
use rayon::prelude::*;

const MIN_LEN: usize = 1 << 14;

/// Union of the primitive boxes.
pub fn scene_bounds(boxes: &[Aabb]) -> Aabb {
    boxes
        .par_iter()
        .with_min_len(MIN_LEN)
        .fold(|| Aabb::EMPTY, |a, b| a.union(b))
        .reduce(|| Aabb::EMPTY, |a, b| a.union(&b))
}

/// Bounds of the centroids.
pub fn centroid_bounds(centers: &[Vec3]) -> Aabb {
    centers
        .par_iter()
        .with_min_len(MIN_LEN)
        .fold(
            || Aabb::EMPTY,
            |mut a, &c| {
                a.grow_point(c);
                a
            },
        )
        .reduce(|| Aabb::EMPTY, |a, b| a.union(&b))
}

/// Riemersma eq. 15: `difference = vmin(centroid_min - bounds_min, bounds_max - centroid_max)`,
/// concise = bounds shrunk by `difference` on both sides of each axis. The shrink is symmetric,
/// so the first (middle) split stays at the scene centre, and the result still contains every
/// centroid. Empty input gives the empty box.
pub fn concise_bounds(bounds: Aabb, centroids: Aabb) -> Aabb {
    if bounds.is_empty() || centroids.is_empty() {
        return Aabb::EMPTY;
    }
    let difference = (centroids.min - bounds.min).min(bounds.max - centroids.max);
    Aabb::new(bounds.min + difference, bounds.max - difference)
}

/// The frame of a bounds mode. Adding +0.0 turns -0.0 into +0.0: `min`/`max` of -0.0 and +0.0
/// may return either, so without it the frame's bytes could depend on the reduction order (the
/// thread count).
pub fn frame(boxes: &[Aabb], centers: &[Vec3], mode: BoundsMode) -> Aabb {
    let f = match mode {
        BoundsMode::Scene => scene_bounds(boxes),
        BoundsMode::Centroids => centroid_bounds(centers),
        BoundsMode::Concise => {
            let (b, c) = rayon::join(|| scene_bounds(boxes), || centroid_bounds(centers));
            concise_bounds(b, c)
        }
    };
    Aabb::new(f.min + Vec3::ZERO, f.max + Vec3::ZERO)
}

/// The frame in f64, ready for normalizing: `u = (p - min) * inv` is 0..1 inside the frame.
/// Zero, negative (empty) or non-finite extents get `inv = 0`, so no division by zero and every
/// point maps to 0 on that axis.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    pub min: [f64; 3],
    pub ext: [f64; 3],
    pub inv: [f64; 3],
    /// Length of the frame diagonal (0 if degenerate), for EMC's size normalization.
    pub diag: f64,
}

impl Frame {
    pub fn new(b: &Aabb) -> Self {
        let lo = b.min.as_dvec3().to_array();
        let hi = b.max.as_dvec3().to_array();
        let mut f = Frame { min: [0.0; 3], ext: [0.0; 3], inv: [0.0; 3], diag: 0.0 };
        for a in 0..3 {
            let e = hi[a] - lo[a];
            if lo[a].is_finite() && hi[a].is_finite() && e > 0.0 {
                f.min[a] = lo[a];
                f.ext[a] = e;
                f.inv[a] = 1.0 / e;
            } else if lo[a].is_finite() {
                f.min[a] = lo[a];
            }
        }
        f.diag = diag(f.ext);
        f
    }

    /// Normalized coordinates (0..1 inside the frame; clamping happens at quantization).
    #[inline]
    pub fn normalize(&self, p: Vec3) -> [f64; 3] {
        [
            (p.x as f64 - self.min[0]) * self.inv[0],
            (p.y as f64 - self.min[1]) * self.inv[1],
            (p.z as f64 - self.min[2]) * self.inv[2],
        ]
    }
}

/// Length of a diagonal with these extents (f64: extents near 1e30 would overflow f32 squares).
#[inline]
pub fn diag(e: [f64; 3]) -> f64 {
    (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt()
}

/// Diagonal of a primitive box; 0 for empty or non-finite boxes.
#[inline]
pub fn box_diag(b: &Aabb) -> f64 {
    let e = b.extent_f64(); // f64 subtraction: no overflow for boxes spanning +-3e38
    let d = diag([e.x.max(0.0), e.y.max(0.0), e.z.max(0.0)]);
    if d.is_finite() {
        d
    } else {
        0.0
    }
}

/// Normalized size `diag / frame_diag` (0 when the frame diagonal is 0).
#[inline]
pub fn size(b: &Aabb, frame_diag: f64) -> f64 {
    if frame_diag > 0.0 && frame_diag.is_finite() {
        box_diag(b) / frame_diag
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_has_no_negative_zero() {
        let boxes = [Aabb::from_point(Vec3::new(-0.0, 0.0, -0.0)), Aabb::from_point(Vec3::new(0.0, -0.0, 1.0))];
        let centers = [boxes[0].min, boxes[1].min];
        for mode in [BoundsMode::Scene, BoundsMode::Centroids, BoundsMode::Concise] {
            let f = frame(&boxes, &centers, mode);
            for v in [f.min, f.max] {
                assert!(v.to_array().iter().all(|x| !x.is_sign_negative()), "{mode:?}: {f:?}");
            }
        }
    }

    #[test]
    fn degenerate_frames() {
        let f = Frame::new(&Aabb::EMPTY);
        assert_eq!(f.inv, [0.0; 3]);
        assert_eq!(f.normalize(Vec3::new(1.0, 2.0, 3.0)), [0.0; 3]);
        let f = Frame::new(&Aabb::new(Vec3::new(0.0, 1.0, -1e30), Vec3::new(2.0, 1.0, 1e30)));
        assert_eq!(f.inv[1], 0.0);
        assert_eq!(f.normalize(Vec3::new(1.0, 1.0, 0.0)), [0.5, 0.0, 0.5]);
        assert!(f.diag.is_finite() && f.diag > 1e30);
    }
}
