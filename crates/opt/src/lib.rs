//! BVH optimization after construction, one method per module, named after the papers:
//!
//! - [`ibo`]: insertion-based optimization (Bittner, Hapala and Havran 2013; thesis 3.4);
//! - [`kensler`]: tree rotations with hill climbing or simulated annealing (Kensler 2008, as Bittner
//!   2013 uses it as a reference);
//! - [`search`]: the branch-and-bound insertion search both share with the incremental builder
//!   (`bvhlab_builders::incremental`, Bittner, Hapala and Havran 2015; thesis 3.5.1).
//!
//! All work on [`bvhlab_bvh::dyntree::DynTree`] (explicit child links plus a parent array) and hand back a flat
//! [`Bvh`]. They are plain sequential functions: the same input and parameters give the same tree
//! bytes on every run and thread count (random choices come from a seeded [`SplitMix64`]), except
//! when a `max_seconds` cap stops a run, which the result says ([`Stop::MaxSeconds`]).
pub mod ibo;
pub mod kensler;
pub mod search;

pub use bvhlab_bvh::{Aabb, Bvh, CostParams};
pub use bvhlab_geom::rng::SplitMix64;
use bvhlab_params::{Kind, ParamSpec};
use serde::{Deserialize, Serialize};

/// Parameters every optimizer shares (`IboConfig` and `KenslerConfig` fields of the same names).
pub const MAX_PASSES: ParamSpec = ParamSpec {
    name: "max_passes",
    default: "0",
    kind: Kind::UInt { min: 0, max: u32::MAX },
    about: "stop after this many passes (0 = no limit)",
    in_label: false,
};

pub const MAX_SECONDS: ParamSpec = ParamSpec {
    name: "max_seconds",
    default: "0",
    kind: Kind::NonNegativeFloat,
    about: "stop after this many seconds (0 = no limit); a run stopped by it depends on machine speed",
    in_label: false,
};

pub const BUDGET: ParamSpec = ParamSpec {
    name: "budget",
    default: "auto",
    kind: Kind::Choice(&["auto", "off"]),
    about: "auto: stop after a pass budget derived from the tree size (ibo: 25 updates per inner node; \
            kensler: 16 log2(nodes) + 64 passes), optimize_stop = pass_budget; off: no budget",
    in_label: false,
};

pub const KEEP_BEST: ParamSpec = ParamSpec {
    name: "keep_best",
    default: "true",
    kind: Kind::Choice(&["true", "false"]),
    about: "return the best tree seen, not the last (fixes the oscillation of thesis 5.2.1)",
    in_label: false,
};

pub const SEED: ParamSpec = ParamSpec {
    name: "seed",
    default: "1",
    kind: Kind::UInt { min: 0, max: u32::MAX },
    about: "seed of the random choices",
    in_label: false,
};

/// One optimization pass (Bittner 2013: a batch of k updated nodes; Kensler: one sweep over the
/// tree). Pass 0 is the input tree before any change (`seconds` 0, `moved` 0).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PassRecord {
    pub pass: u32,
    /// Wall-clock seconds since the optimizer started, at the end of this pass.
    pub seconds: f64,
    /// SAH cost (thesis eq. 4, the optimizer's c_T / c_I) of the tree after this pass.
    pub sah_cost: f64,
    /// Nodes whose position changed in this pass (ibo: reinsertions that moved a subtree; Kensler:
    /// rotations applied).
    pub moved: u64,
    /// How nodes were chosen: the measure (`comb`, `sum`, ...), `random` after the p_R switch, or
    /// the Kensler mode (`hc`, `sa`).
    pub phase: String,
}

/// Why an optimizer stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Stop {
    /// The method's own termination (ibo: p_T / p_R passes without improvement, or the thesis
    /// schedule's check without improvement in its last stage; hill climbing: a
    /// pass without an improving rotation; annealing: the schedule ended).
    Converged,
    MaxPasses,
    /// Stopped by the time cap: the result depends on machine speed (not reproducible bit for bit).
    MaxSeconds,
    /// Stopped by the default pass budget derived from the tree size (issue 15: pathological
    /// scenes must not run unbounded); deterministic, unlike `MaxSeconds`.
    PassBudget,
}

impl Stop {
    pub fn as_str(&self) -> &'static str {
        match self {
            Stop::Converged => "converged",
            Stop::MaxPasses => "max_passes",
            Stop::MaxSeconds => "max_seconds",
            Stop::PassBudget => "pass_budget",
        }
    }
}

/// An optimizer's result: the tree it returns (the best seen with `keep_best`, else the last), its
/// pass-by-pass trace, and why it stopped.
#[derive(Clone, Debug, PartialEq)]
pub struct Optimized {
    pub bvh: Bvh,
    pub trace: Vec<PassRecord>,
    pub stop: Stop,
    /// Pass whose tree was returned.
    pub returned_pass: u32,
}
