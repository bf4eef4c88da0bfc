//! The flat 32-byte-node BVH (the foundation's layout; Kilian 5.1's "basic BVH" is the same 256 bits
//! per node): the baseline every compressed layout is compared with.
use crate::Memory;
use bvhlab_bvh::{Bvh, CostParams, Node, Refs};
use bvhlab_geom::Triangle;
use bvhlab_params::Method;
use bvhlab_trace::{Ray, TraceStats};
use serde::{Deserialize, Serialize};

pub const METHOD: Method = Method::new(
    "bvh2",
    "the flat 32-byte-node BVH (the baseline every layout is compared with)",
    "Kilian 2021 5.1 (basic BVH)",
    &[],
);

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Bvh2 {
    pub bvh: Bvh,
}

impl Bvh2 {
    pub fn build(bvh: &Bvh) -> Bvh2 {
        Bvh2 { bvh: bvh.clone() }
    }

    pub fn memory(&self) -> Memory {
        let topology = (self.bvh.nodes.len() * std::mem::size_of::<Node>()) as u64;
        Memory {
            topology_bytes: topology,
            total_bytes: topology + self.bvh.prim_indices.len() as u64 * 4,
            nodes: self.bvh.nodes.len() as u64,
            chunks: 0,
            chunk_fill: 0.0,
            prim_refs: self.bvh.prim_indices.len() as u64,
        }
    }

    pub fn trace(&self, tris: &[Triangle], rays: &[Ray]) -> TraceStats {
        bvhlab_trace::trace(&self.bvh, tris, rays)
    }

    pub fn sah_cost(&self, cost: CostParams) -> f64 {
        bvhlab_bvh::metrics(&self.bvh, cost).sah_cost
    }

    pub fn validate(&self, tris: &[Triangle]) -> Result<(), String> {
        self.validate_refs(tris, Refs::Unique)
    }

    pub fn validate_refs(&self, tris: &[Triangle], refs: Refs) -> Result<(), String> {
        let boxes: Vec<_> = tris.iter().map(|t| t.bounds()).collect();
        bvhlab_bvh::validate_refs(&self.bvh, &boxes, refs)
    }
}
