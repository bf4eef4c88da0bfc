//! Structural validation: the invariants every builder, optimizer and layout must keep.
use crate::Bvh;
use bvhlab_geom::Aabb;

/// Checks that every one of `prim_boxes.len()` primitives is referenced exactly once, every node is
/// reachable from the root exactly once (acyclic, no sharing, no orphans), children's boxes lie
/// inside their parent's, and every leaf's box contains its primitives' boxes.
/// Returns a description of the first violation.
pub fn validate(bvh: &Bvh, prim_boxes: &[Aabb]) -> Result<(), String> {
    let _ = (bvh, prim_boxes);
    todo!()
}
