//! Binned SAH (Wald 2007) as Frantal 2019 section 3.1.1 implements it.
use crate::TopDownConfig;
use bvhlab_bvh::{Aabb, Bvh, Vec3};

pub fn build(boxes: &[Aabb], centers: &[Vec3], bins: u32, cfg: &TopDownConfig) -> Bvh {
    let _ = (boxes, centers, bins, cfg);
    todo!()
}
