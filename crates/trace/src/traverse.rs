//! Closest-hit traversal, near child first, counting traversal steps (inner nodes visited) and
//! ray-triangle intersection tests per ray.
use crate::Ray;
use bvhlab_bvh::Bvh;
use bvhlab_geom::Triangle;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Hit {
    /// Distance along the ray; `f32::INFINITY` when nothing was hit.
    pub t: f32,
    /// Scene triangle index; `u32::MAX` when nothing was hit.
    pub prim: u32,
}

impl Hit {
    pub const NONE: Hit = Hit { t: f32::INFINITY, prim: u32::MAX };
    pub fn is_hit(&self) -> bool {
        self.prim != u32::MAX
    }
}

/// Per-ray results and totals of one trace.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct TraceStats {
    pub hits: Vec<Hit>,
    /// Traversal steps per ray: nodes whose box test was performed (thesis table 15 convention).
    pub steps: Vec<u32>,
    /// Ray-triangle intersection tests per ray.
    pub intersections: Vec<u32>,
    pub total_steps: u64,
    pub total_intersections: u64,
    pub hit_count: u64,
}

/// Traces every ray (in parallel with rayon; results are per-ray so independent of thread count).
pub fn trace(bvh: &Bvh, tris: &[Triangle], rays: &[Ray]) -> TraceStats {
    let _ = (bvh, tris, rays);
    todo!()
}

/// The oracle: closest hit of each ray against every triangle.
pub fn brute_force(tris: &[Triangle], rays: &[Ray]) -> Vec<Hit> {
    let _ = (tris, rays);
    todo!()
}
