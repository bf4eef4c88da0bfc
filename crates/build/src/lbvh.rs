//! LBVH: Karras 2012 binary radix tree over sorted codes (thesis 2.3.4). SKELETON: implemented by the
//! bottom-up builders work.
use crate::sorted::SortedCodes;
use bvhlab_bvh::{Aabb, Bvh};

/// One primitive per leaf; the caller applies the SAH compaction.
pub fn build(boxes: &[Aabb], sorted: &SortedCodes) -> Bvh {
    let _ = (boxes, sorted);
    unimplemented!("lbvh: not yet implemented")
}
