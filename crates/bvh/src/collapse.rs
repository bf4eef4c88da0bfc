//! SAH compaction (subtree collapse), Bittner et al. 2013 section 3.6, Frantal 2019 section 3.4.4.
use crate::{Bvh, CostParams};

/// Post-order: replace a subtree by a leaf holding all its primitives when the leaf's cost
/// c_I * SA * t is not above the subtree's SAH cost. Works on any BVH; returns a compacted copy
/// whose nodes are renumbered depth-first.
pub fn collapse(bvh: &Bvh, cost: CostParams) -> Bvh {
    let _ = (bvh, cost);
    todo!()
}
