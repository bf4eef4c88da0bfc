//! Spatial median (Kay and Kajiya 1986): split the largest-extent axis at its middle.
//!
//! Two frames ([`Frame`]). `Centroids` (the default) takes the axis and the middle from the node's
//! *centroid* bounds: primitives are assigned to a side by their centroid, so only a plane inside
//! the centroid bounds can separate them; with node bounds, one large primitive can stretch the box
//! so that every centroid falls on one side, forcing needless fallbacks. (The thesis' Bonsai
//! mini-tree selection, section 3.3.2, likewise runs the spatial median "based on the centroids of
//! the primitives".) `Node` is Kay and Kajiya's plane: the middle of the node's bounding box along
//! its largest axis, which is the start tree of Bittner 2013 tables 3 and 5.
//! In both frames, if the middle leaves one side empty (all centroids equal, adjacent floats, or
//! with `Node` every centroid on one side of the box middle), the node is split at the object
//! median along the same axis, so construction always terminates.
use crate::primref::{make_refs, object_median, partition, with_refs, Ref};
use crate::topdown::{build_nodes, Range};
use crate::{TopDownConfig, LEAF};
use bvhlab_bvh::{Aabb, Bvh, Vec3};
use bvhlab_params::{Kind, Method, ParamSpec};

pub const METHOD: Method = Method::new(
    "spatial-median",
    "split the largest axis at its middle (Kay and Kajiya 1986; thesis 3.2)",
    "Kay and Kajiya 1986; thesis 3.2",
    &[
        LEAF,
        ParamSpec {
            name: "frame",
            default: "centroids",
            kind: Kind::Choice(&["centroids", "node"]),
            about: "box whose largest axis is halved: the node's centroid bounds (bvhlab's default: \
                    only a plane inside them separates centroids) or the node's bounding box \
                    (Kay and Kajiya 1986, the start tree of Bittner 2013 tables 3 and 5); an empty \
                    side falls back to the object median",
            in_label: false,
        },
    ],
)
// 2: the same trees; the centroid on the split axis read as scalars (see `Ref::c_axis`): times
//    re-measured.
.with_version(2);

/// Whose bounding box the split plane halves.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Frame {
    /// The bounds of the node's primitive centroids (bvhlab's default).
    #[default]
    Centroids,
    /// The node's bounding box (Kay and Kajiya 1986; Bittner 2013's spatial median).
    Node,
}

impl Frame {
    pub fn parse(s: &str) -> Option<Frame> {
        Some(match s {
            "centroids" => Frame::Centroids,
            "node" => Frame::Node,
            _ => return None,
        })
    }
    pub fn as_str(&self) -> &'static str {
        match self {
            Frame::Centroids => "centroids",
            Frame::Node => "node",
        }
    }
}

impl std::str::FromStr for Frame {
    type Err = ();
    fn from_str(s: &str) -> Result<Frame, ()> {
        Frame::parse(s).ok_or(())
    }
}

/// The spatial median over the centroid bounds ([`Frame::Centroids`]).
pub fn build(boxes: &[Aabb], centers: &[Vec3], cfg: &TopDownConfig) -> Bvh {
    build_in(boxes, centers, cfg, Frame::Centroids)
}

/// The spatial median splitting the middle of `frame`'s box.
pub fn build_in(boxes: &[Aabb], centers: &[Vec3], cfg: &TopDownConfig, frame: Frame) -> Bvh {
    with_refs!(boxes, centers, false, build_refs(boxes, centers, cfg, frame))
}

pub(crate) fn build_refs<R: Ref>(boxes: &[Aabb], centers: &[Vec3], cfg: &TopDownConfig, frame: Frame) -> Bvh {
    let (mut refs, root) = make_refs::<R>(boxes, centers);
    let max_leaf = cfg.max_leaf();
    let nodes = build_nodes(refs.len(), root, |r| split(&mut refs, r, max_leaf, frame));
    Bvh {
        nodes,
        prim_indices: refs.iter().map(|p| p.idx()).collect(),
    }
}

/// The split decision for one node: `None` makes a leaf (primitive threshold only, no SAH test).
fn split<R: Ref>(refs: &mut [R], r: &Range, max_leaf: usize, frame: Frame) -> Option<(Range, Range)> {
    if r.len() <= max_leaf {
        return None;
    }
    let b = match frame {
        Frame::Centroids => &r.cbounds,
        Frame::Node => &r.bounds,
    };
    let axis = b.largest_axis();
    let (lo, hi) = (b.min[axis], b.max[axis]);
    // Halves first: the same float as 0.5 (lo + hi) but no overflow near f32::MAX.
    let mid = 0.5 * lo + 0.5 * hi;
    let (left, right) = partition(refs, r, |p| p.c_axis(axis) < mid);
    if left.len() == 0 || right.len() == 0 {
        return Some(object_median(refs, r, axis));
    }
    Some((left, right))
}
