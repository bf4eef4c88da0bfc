//! Spatial median (Kay and Kajiya 1986): split the largest-extent axis at its middle.
use crate::TopDownConfig;
use bvhlab_bvh::{Aabb, Bvh, Vec3};

pub fn build(boxes: &[Aabb], centers: &[Vec3], cfg: &TopDownConfig) -> Bvh {
    let _ = (boxes, centers, cfg);
    todo!()
}
