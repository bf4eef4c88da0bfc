//! Parallel Locally-Ordered Clustering (Meister and Bittner 2018, thesis 3.6). SKELETON: implemented by
//! the bottom-up builders work.
use crate::sorted::SortedCodes;
use bvhlab_bvh::{Aabb, Bvh};
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlocConfig {
    /// Nearest-neighbour search radius r (thesis table 6; PL1/PL2/PL3 = 10/25/100).
    pub radius: u32,
}

/// One primitive per leaf; the caller applies the SAH compaction.
pub fn build(boxes: &[Aabb], sorted: &SortedCodes, cfg: &PlocConfig) -> Bvh {
    let _ = (boxes, sorted, cfg);
    unimplemented!("ploc: not yet implemented")
}
