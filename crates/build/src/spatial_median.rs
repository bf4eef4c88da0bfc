//! Spatial median (Kay and Kajiya 1986): split the largest-extent axis at its middle.
//!
//! The axis and the middle are taken from the node's *centroid* bounds, not its full bounds:
//! primitives are assigned to a side by their centroid, so only a plane inside the centroid bounds
//! can separate them. With node bounds, one large primitive can stretch the box so that every
//! centroid falls on one side, forcing needless fallbacks. (The thesis' Bonsai mini-tree selection,
//! section 3.3.2, likewise runs the spatial median "based on the centroids of the primitives".)
//! If the middle still leaves one side empty (all centroids equal, or adjacent floats), the node is
//! split at the object median, so construction always terminates.
use crate::primref::{make_refs, object_median, partition, PrimRef};
use crate::topdown::{build_nodes, Range};
use crate::TopDownConfig;
use bvhlab_bvh::{Aabb, Bvh, Vec3};

pub fn build(boxes: &[Aabb], centers: &[Vec3], cfg: &TopDownConfig) -> Bvh {
    let (mut refs, root) = make_refs(boxes, centers);
    let max_leaf = cfg.max_leaf();
    let nodes = build_nodes(refs.len(), root, |r| split(&mut refs, r, max_leaf));
    Bvh {
        nodes,
        prim_indices: refs.iter().map(|p| p.idx).collect(),
    }
}

/// The split decision for one node: `None` makes a leaf (primitive threshold only, no SAH test).
fn split(refs: &mut [PrimRef], r: &Range, max_leaf: usize) -> Option<(Range, Range)> {
    if r.len() <= max_leaf {
        return None;
    }
    let axis = r.cbounds.largest_axis();
    let (lo, hi) = (r.cbounds.min[axis], r.cbounds.max[axis]);
    // Halves first: the same float as 0.5 (lo + hi) but no overflow near f32::MAX.
    let mid = 0.5 * lo + 0.5 * hi;
    let (left, right) = partition(refs, r, |p| p.c[axis] < mid);
    if left.len() == 0 || right.len() == 0 {
        return Some(object_median(refs, r, axis));
    }
    Some((left, right))
}
