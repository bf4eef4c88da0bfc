//! Incremental construction by insertion with global updates (Bittner, Hapala and Havran 2015;
//! thesis 3.5.1).
use crate::{Aabb, Bvh, CostParams};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IncConfig {
    /// Primitives inserted between two optimization passes (8000).
    pub batch: u32,
    /// Fraction of the cached (touched) inner nodes optimized after each batch (0.01).
    pub ofrac: f32,
    /// Coherence threshold R_max of eq. 13 (1.5): two consecutive primitives whose union's area is
    /// below R_max times the sum of their areas are clustered and inserted as one subtree.
    pub coh: f32,
    pub cost: CostParams,
}

impl Default for IncConfig {
    fn default() -> Self {
        IncConfig { batch: 8000, ofrac: 0.01, coh: 1.5, cost: CostParams::default() }
    }
}

/// Builds a BVH with one primitive per leaf, inserting primitives in input order.
pub fn build(boxes: &[Aabb], cfg: &IncConfig) -> Bvh {
    let _ = cfg;
    todo!("incremental helper ({} primitives)", boxes.len())
}
