//! Kilian 5.2: quantized BVH in chunks (skeleton; implemented by the qbvh work item).
use crate::{LayoutSpec, Memory};
use bvhlab_bvh::{Bvh, CostParams};
use bvhlab_geom::Triangle;
use bvhlab_trace::{Ray, TraceStats};
use serde::{Deserialize, Serialize};

/// (name, default) of the parameters.
pub const PARAMS: &[(&str, &str)] = &[("bits", "8"), ("chunk_bytes", "64"), ("frame", "chunk")];

#[derive(Clone, Debug, PartialEq)]
pub struct Config {}

impl Config {
    pub fn from_spec(_spec: &LayoutSpec) -> Result<Config, String> {
        Ok(Config {})
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Qbvh {}

impl Qbvh {
    pub fn build(bvh: &Bvh, _cfg: &Config) -> Result<Qbvh, String> {
        let _ = bvh;
        Err("layout `qbvh` is not implemented yet".into())
    }
    pub fn memory(&self) -> Memory {
        Memory::default()
    }
    pub fn trace(&self, _tris: &[Triangle], rays: &[Ray]) -> TraceStats {
        bvhlab_trace::trace_with(rays, || (), |_, _| (bvhlab_trace::Hit::NONE, 0, 0))
    }
    pub fn sah_cost(&self, _cost: CostParams) -> f64 {
        0.0
    }
    pub fn validate(&self, _tris: &[Triangle]) -> Result<(), String> {
        Err("not implemented".into())
    }
}
