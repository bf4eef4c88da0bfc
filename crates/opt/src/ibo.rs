//! Insertion-based optimization (Bittner, Hapala and Havran 2013; thesis 3.4).
use crate::{Bvh, CostParams, Optimized};

/// Node inefficiency measure used to pick the nodes of a pass (Bittner 2013 section 3.4, thesis
/// eq. 9-12), or uniform random sampling.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Measure {
    Sum,
    Min,
    Area,
    Comb,
    Random,
}

impl Measure {
    pub fn parse(s: &str) -> Option<Measure> {
        Some(match s {
            "sum" => Measure::Sum,
            "min" => Measure::Min,
            "area" => Measure::Area,
            "comb" => Measure::Comb,
            "random" => Measure::Random,
            _ => return None,
        })
    }
    pub fn as_str(&self) -> &'static str {
        match self {
            Measure::Sum => "sum",
            Measure::Min => "min",
            Measure::Area => "area",
            Measure::Comb => "comb",
            Measure::Random => "random",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IboConfig {
    pub measure: Measure,
    /// Fraction of the inner nodes updated per pass (k = 1% in Bittner 2013).
    pub frac: f32,
    /// Stop after this many passes without improving the best cost (p_T = 10).
    pub pt: u32,
    /// Switch from the measure to random sampling after this many passes without improvement
    /// (p_R = 5, p_R <= p_T). 0 disables the switch.
    pub pr: u32,
    /// 0 = no limit.
    pub max_passes: u32,
    /// 0 = no limit.
    pub max_seconds: f64,
    /// Return the best tree seen instead of the last (the thesis' oscillation, 5.2.1).
    pub keep_best: bool,
    /// Seed of random sampling.
    pub seed: u64,
    pub cost: CostParams,
}

impl Default for IboConfig {
    fn default() -> Self {
        IboConfig {
            measure: Measure::Comb,
            frac: 0.01,
            pt: 10,
            pr: 5,
            max_passes: 0,
            max_seconds: 0.0,
            keep_best: true,
            seed: 1,
            cost: CostParams::default(),
        }
    }
}

/// Optimizes `bvh` (any builder's output, any leaf sizes: leaves move as units).
pub fn optimize(bvh: &Bvh, cfg: &IboConfig) -> Optimized {
    let _ = cfg;
    todo!("ibo helper: Bittner 2013 insertion-based optimization ({} nodes)", bvh.nodes.len())
}
