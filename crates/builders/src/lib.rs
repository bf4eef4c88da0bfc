//! BVH builders. Each is a plain function over primitive boxes and centres (never triangles, files
//! or caches), one method per module, named after the papers.
//!
//! The top-down builders share one iterative driver ([`topdown`]): a builder only supplies the split
//! decision for a primitive range (leaf or two child ranges), the driver owns the node array and the
//! explicit task stack. Tasks are independent sub-ranges, which is what the parallel binned SAH
//! (`binned_sah::build_parallel`, thesis 3.1.2) hands to threads below its horizontal phase.
//!
//! The bottom-up builders (lbvh, aac, ploc) take primitives already sorted by the encode stage's
//! codes ([`SortedCodes`]) and emit a cluster tree that [`bottomup::to_bvh`] lays out.
//!
//! Bonsai ([`bonsai`], thesis 3.3) is a two-level builder: spatial-median primitive sets, a
//! full-sweep SAH mini tree per set (in parallel), optional pruning, and a full-sweep SAH top tree
//! over the mini-tree roots weighted by their primitive counts (`sweep_sah::build_weighted`).
//!
//! The incremental builder ([`incremental`], Bittner, Hapala and Havran 2015; thesis 3.5.1) inserts
//! primitives one by one into a [`bvhlab_bvh::dyntree::DynTree`] with the insertion search and
//! reinsertion it shares with the optimizer `bvhlab_opt::ibo`.

pub mod aac;
pub mod binned_sah;
pub mod bonsai;
pub mod bottomup;
pub mod incremental;
pub mod lbvh;
pub mod ploc;
pub(crate) mod primref;
pub(crate) mod simd_box;
pub mod sbvh;
pub mod spatial_median;
pub mod sorted;
pub mod sweep_sah;
pub(crate) mod topdown;

pub use sorted::SortedCodes;

use bvhlab_bvh::CostParams;
use bvhlab_params::{Kind, ParamSpec};
use serde::{Deserialize, Serialize};

/// [`TopDownConfig::leaf`] as a parameter of the top-down builders.
pub const LEAF: ParamSpec = ParamSpec {
    name: "leaf",
    default: "2",
    kind: Kind::UInt { min: 1, max: 1 << 16 },
    about: "primitive threshold: nodes with at most this many triangles become leaves (thesis 2.3.1)",
    in_label: false,
};

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
        Self {
            leaf: 2,
            cost: CostParams::default(),
        }
    }
}

impl TopDownConfig {
    /// Effective primitive threshold; 0 is treated as 1 (a leaf always holds at least one primitive).
    #[inline]
    pub(crate) fn max_leaf(&self) -> usize {
        self.leaf.max(1) as usize
    }
    /// `leaf <= 1` forces single-primitive leaves: no SAH leaf test, no early termination.
    #[inline]
    pub(crate) fn forced_single(&self) -> bool {
        self.leaf <= 1
    }
    /// The SAH leaf-vs-split test of thesis eq. 2 and 3, multiplied through by SA(N) so that a node
    /// with zero surface area (all-point boxes) needs no division: leaf iff
    /// `c_I * n < c_T + c_I * (SA_L n_L + SA_R n_R) / SA_N`, i.e. only when the leaf is strictly
    /// cheaper (thesis 2.2.2 and 2.3.1: "if the expected cost of a leaf is lower"). Equal costs
    /// split, as the SAH compaction (`bvhlab_bvh::collapse`, thesis 3.4.4 / Bittner 3.6: collapse
    /// when the leaf is lower) keeps such a subtree: one tie rule, so compacting a freshly built
    /// tree changes nothing, also on zero-area (degenerate) nodes where both costs are 0.
    /// `split_sum` is `SA_L n_L + SA_R n_R` with the same (half-)area scale as `node_area`.
    #[inline]
    pub(crate) fn sah_prefers_leaf(&self, n: usize, node_area: f64, split_sum: f64) -> bool {
        let (c_t, c_i) = (self.cost.c_t as f64, self.cost.c_i as f64);
        c_i * n as f64 * node_area < c_t * node_area + c_i * split_sum
    }
}
