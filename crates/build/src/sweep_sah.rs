//! Full-sweep SAH over all three axes with the presorted O(n log n) scheme (Frantal 2019 3.3.1).
use crate::TopDownConfig;
use bvhlab_bvh::{Aabb, Bvh, Vec3};

pub fn build(boxes: &[Aabb], centers: &[Vec3], cfg: &TopDownConfig) -> Bvh {
    let _ = (boxes, centers, cfg);
    todo!()
}
