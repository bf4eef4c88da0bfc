//! Kilian 4.1: basic octree (skeleton; implemented by the octree work item).
use crate::{LayoutSpec, Memory};
use bvhlab_bvh::CostParams;
use bvhlab_geom::Triangle;
use bvhlab_trace::{Ray, TraceStats};
use serde::{Deserialize, Serialize};

/// (name, default) of the parameters.
pub const PARAMS: &[(&str, &str)] = &[
    ("max_depth", "24"),
    ("mult_threshold", "2.0"),
    ("prim_threshold", "20"),
];

#[derive(Clone, Debug, PartialEq)]
pub struct Config {}

impl Config {
    pub fn from_spec(_spec: &LayoutSpec) -> Result<Config, String> {
        Ok(Config {})
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Octree {}

impl Octree {
    pub fn build(tris: &[Triangle], _cfg: &Config) -> Result<Octree, String> {
        let _ = tris;
        Err("layout `octree` is not implemented yet".into())
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
