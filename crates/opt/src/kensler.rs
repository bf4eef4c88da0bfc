//! Tree rotations (Kensler 2008) with hill climbing or simulated annealing, the reference method
//! of Bittner 2013 (tables 2-5).
use crate::{Bvh, CostParams, Optimized};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KenslerConfig {
    /// false: hill climbing (only improving rotations); true: simulated annealing.
    pub anneal: bool,
    /// Annealing start temperature (see the module for its unit).
    pub t0: f64,
    /// Annealing: temperature factor per pass, in (0, 1).
    pub cooling: f64,
    /// 0 = no limit.
    pub max_passes: u32,
    /// 0 = no limit.
    pub max_seconds: f64,
    pub keep_best: bool,
    pub seed: u64,
    pub cost: CostParams,
}

pub fn optimize(bvh: &Bvh, cfg: &KenslerConfig) -> Optimized {
    let _ = cfg;
    todo!("kensler helper ({} nodes)", bvh.nodes.len())
}
