//! The flat binary BVH every stage produces and consumes, its structural validation, the thesis
//! metrics (Frantal 2019 eq. 4 and section 4.4) and SAH compaction (Bittner 2013 section 3.6).

pub mod collapse;
pub mod dyntree;
pub mod focus;
pub mod metrics;
pub mod validate;

pub use bvhlab_geom::{Aabb, Vec3};
pub use metrics::{metrics, CostParams, Metrics};
pub use validate::{validate, validate_refs, validate_split, Refs};
use serde::{Deserialize, Serialize};

/// A 32-byte node: 24 bytes of box, then two u32.
/// Inner node: `count == 0`, children are `nodes[first]` and `nodes[first + 1]` (left, right).
/// Leaf: `count > 0`, primitives are `prim_indices[first .. first + count]`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Node {
    pub bounds: Aabb,
    pub first: u32,
    pub count: u32,
}

const _: () = assert!(std::mem::size_of::<Node>() == 32);

impl Node {
    #[inline]
    pub fn is_leaf(&self) -> bool {
        self.count > 0
    }
    #[inline]
    pub fn leaf(bounds: Aabb, first: u32, count: u32) -> Node {
        debug_assert!(count > 0);
        Node { bounds, first, count }
    }
    #[inline]
    pub fn inner(bounds: Aabb, left: u32) -> Node {
        Node { bounds, first: left, count: 0 }
    }
}

/// Binary BVH in flat arrays. The root is `nodes[0]`; siblings are adjacent (left, right).
/// `prim_indices` maps leaf slots to scene triangle indices.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Bvh {
    pub nodes: Vec<Node>,
    pub prim_indices: Vec<u32>,
}

impl Bvh {
    pub fn root(&self) -> &Node {
        &self.nodes[0]
    }
    /// Bytes of the structure as stored: nodes plus the index array.
    pub fn bytes(&self) -> u64 {
        (self.nodes.len() * std::mem::size_of::<Node>() + self.prim_indices.len() * 4) as u64
    }
    /// Canonical little-endian bytes (nodes then indices) for hashing: `bvh_hash` = blake3 of this.
    pub fn canonical_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.bytes() as usize + 16);
        out.extend_from_slice(&(self.nodes.len() as u64).to_le_bytes());
        for n in &self.nodes {
            for v in [n.bounds.min, n.bounds.max] {
                for c in v.to_array() {
                    out.extend_from_slice(&c.to_bits().to_le_bytes());
                }
            }
            out.extend_from_slice(&n.first.to_le_bytes());
            out.extend_from_slice(&n.count.to_le_bytes());
        }
        out.extend_from_slice(&(self.prim_indices.len() as u64).to_le_bytes());
        for i in &self.prim_indices {
            out.extend_from_slice(&i.to_le_bytes());
        }
        out
    }
}
