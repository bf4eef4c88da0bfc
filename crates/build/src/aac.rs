//! Approximate Agglomerative Clustering (Gu et al. 2013, thesis 3.2). SKELETON: implemented by the
//! AAC work.
use crate::sorted::SortedCodes;
use bvhlab_bvh::{Aabb, Bvh};
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AacConfig {
    /// Constraint-tree leaf threshold delta (thesis table 2).
    pub delta: u32,
    /// Reduction-function exponent term epsilon (thesis table 2).
    pub epsilon: f32,
}

impl AacConfig {
    /// High Quality: delta = 20, epsilon = 0.1 (thesis table 2, "AHQ").
    pub const HQ: AacConfig = AacConfig { delta: 20, epsilon: 0.1 };
    /// High Performance ("fast", "ALQ"): delta = 4, epsilon = 0.2.
    pub const FAST: AacConfig = AacConfig { delta: 4, epsilon: 0.2 };
}

/// One primitive per leaf; the caller applies the SAH compaction.
pub fn build(boxes: &[Aabb], sorted: &SortedCodes, cfg: &AacConfig) -> Bvh {
    let _ = (boxes, sorted, cfg);
    unimplemented!("aac: not yet implemented")
}
