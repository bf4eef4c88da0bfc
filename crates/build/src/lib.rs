//! BVH builders. Each is a plain function over primitive boxes and centres (never triangles, files
//! or caches), one method per module, named after the papers.

pub mod binned_sah;
pub mod spatial_median;
pub mod sweep_sah;

use bvhlab_bvh::CostParams;
use serde::{Deserialize, Serialize};

/// Settings shared by the top-down builders.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TopDownConfig {
    /// Primitive threshold (thesis 2.3.1): a node with at most this many primitives becomes a leaf.
    /// `1` forces single-triangle leaves and disables the SAH leaf-vs-split test.
    pub leaf: u32,
    /// SAH constants for the leaf-vs-split test.
    pub cost: CostParams,
}

impl Default for TopDownConfig {
    fn default() -> Self {
        Self { leaf: 2, cost: CostParams::default() }
    }
}
