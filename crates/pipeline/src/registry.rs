//! Builder and encoder names -> function + parameter schema (defaults, validation). Cost constants
//! c_t / c_i are parameters of every builder: they drive the SAH leaf-vs-split test (thesis 2.3.1),
//! the compaction and the metrics (thesis eq. 4), so they are part of the build key.
//!
//! Bottom-up builders (lbvh, aac, ploc) take primitives sorted by code from the encode stage; their
//! chains name an encoder (default `morton`). Parameters of a chain are routed by name: a name the
//! builder has goes to the builder, a name the encoder has goes to the encoder (the two schemas share
//! no names), anything else is an input error listing both.
use crate::error::{Error, Result};
use bvhlab_builders::aac::AacConfig;
use bvhlab_builders::{SortedCodes, TopDownConfig};
use bvhlab_bvh::{Aabb, Bvh, CostParams, Vec3};
use bvhlab_morton::{AutoFor, Bits, BoundsMode, CellFrame, EncodeConfig, Scheme};
use std::collections::BTreeMap;

#[derive(Clone, Copy, Debug)]
pub enum Kind {
    /// Integer in `min..=max`.
    UInt { min: u32, max: u32 },
    /// Finite float > 0.
    PositiveFloat,
    /// Finite float >= 0.
    NonNegativeFloat,
    /// One of a fixed set of words.
    Choice(&'static [&'static str]),
    /// `auto` (resolved for the consuming builder, e.g. `auto:aac`) or an integer in `min..=max`.
    AutoOrUInt { min: u32, max: u32 },
}

#[derive(Clone, Debug)]
pub struct ParamSpec {
    pub name: &'static str,
    pub default: &'static str,
    pub kind: Kind,
    pub about: &'static str,
    /// Shown in the chain label even at its default (e.g. `bins`); others only when changed.
    pub in_label: bool,
}

/// Parameters resolved against a schema: canonical strings (defaults included) plus typed cost.
#[derive(Clone, Debug, PartialEq)]
pub struct Resolved {
    pub builder: String,
    /// Builder-specific parameters only (e.g. `bins`, `leaf`), canonical.
    pub params: BTreeMap<String, String>,
    pub cost: CostParams,
}

/// A canonical parameter parsed as `T` (its default value when absent: the schema filled every
/// parameter in, so that happens only for names the schema does not have).
fn typed<T: std::str::FromStr + Default>(params: &BTreeMap<String, String>, name: &str) -> T {
    params
        .get(name)
        .and_then(|v| v.parse().ok())
        .unwrap_or_default()
}

impl Resolved {
    pub fn u32(&self, name: &str) -> u32 {
        typed(&self.params, name)
    }
    pub fn f32(&self, name: &str) -> f32 {
        typed(&self.params, name)
    }
    pub fn flag(&self, name: &str) -> bool {
        typed(&self.params, name)
    }
    pub fn config(&self) -> TopDownConfig {
        TopDownConfig {
            leaf: self.u32("leaf"),
            cost: self.cost,
        }
    }
    pub fn aac_config(&self) -> AacConfig {
        AacConfig {
            delta: self.u32("delta"),
            epsilon: self.f32("epsilon"),
        }
    }
    /// Builder parameters plus `c_t`, `c_i`: what keys the build stage.
    pub fn key_params(&self) -> BTreeMap<String, String> {
        let mut p = self.params.clone();
        p.insert("c_t".into(), fmt_f32(self.cost.c_t));
        p.insert("c_i".into(), fmt_f32(self.cost.c_i));
        p
    }
}

/// An encoder with its parameters resolved for one builder.
#[derive(Clone, Debug, PartialEq)]
pub struct ResolvedEncoder {
    pub encoder: String,
    /// Canonical parameters, defaults included; `bits=auto` is stored as `auto:<builder>`, because
    /// each builder's paper picks its own code length.
    pub params: BTreeMap<String, String>,
    pub config: EncodeConfig,
    /// Occupation grid's in-cell frame (`grid_frame`): the cell (Riemersma 3.2.2) or, as bvhlab's
    /// extension, the tight centroid bounds inside the cell.
    pub cell_frame: CellFrame,
}

impl Registry {
    /// Display label: `binned-sah bins=16`, plus parameters changed from their defaults.
    pub fn label(&self, r: &Resolved) -> String {
        let mut parts = vec![r.builder.clone()];
        if let Ok(info) = self.get(&r.builder) {
            match info.label {
                Some(f) => parts = vec![f(r)],
                None => {
                    for spec in &info.params {
                        let v = r.params.get(spec.name).cloned().unwrap_or_default();
                        if spec.in_label || v != spec.default {
                            parts.push(format!("{}={v}", spec.name));
                        }
                    }
                }
            }
        }
        let d = CostParams::default();
        if r.cost.c_t != d.c_t {
            parts.push(format!("c_t={}", fmt_f32(r.cost.c_t)));
        }
        if r.cost.c_i != d.c_i {
            parts.push(format!("c_i={}", fmt_f32(r.cost.c_i)));
        }
        parts.join(" ")
    }

    /// Encoder label: `emc64-var bounds=concise` (parameters changed from their defaults; `bits`
    /// only when fixed).
    pub fn encoder_label(&self, e: &ResolvedEncoder) -> String {
        let mut parts = vec![e.encoder.clone()];
        if let Ok(info) = self.encoder(&e.encoder) {
            for spec in &info.params {
                // Parameters dropped as meaningless (grid_frame without a grid) are not shown.
                let Some(v) = e.params.get(spec.name).cloned() else {
                    continue;
                };
                let is_default =
                    v == spec.default || (spec.default == "auto" && v.starts_with("auto"));
                if spec.in_label || !is_default {
                    parts.push(format!("{}={v}", spec.name));
                }
            }
        }
        parts.join(" ")
    }
}

/// Boxes, centres, and (for bottom-up builders) the primitives sorted by code.
pub type BuildFn = fn(&[Aabb], &[Vec3], Option<&SortedCodes>, &Resolved) -> Bvh;
/// Cross-parameter resolution after defaults are filled (e.g. AAC presets): gets the user-given
/// parameters and the canonical ones, may rewrite the latter; `Err` is the reason.
pub type FinishFn =
    fn(&BTreeMap<String, String>, &mut BTreeMap<String, String>) -> Result<(), String>;
/// Custom builder label (without cost constants).
pub type LabelFn = fn(&Resolved) -> String;

#[derive(Clone)]
pub struct BuilderInfo {
    pub name: &'static str,
    /// Implementation version: bump it when a change of this method changes what it produces.
    /// Part of its stage's key from 2 on (`method_version`), so only its nodes (and what is
    /// downstream of them) are recomputed.
    pub version: u32,
    pub about: &'static str,
    pub params: Vec<ParamSpec>,
    pub run: BuildFn,
    /// `Some`: the builder consumes sorted codes from the encode stage; an encoder's `bits=auto`
    /// resolves to this builder's code length.
    pub codes: Option<AutoFor>,
    /// The builder returns single-primitive leaves and is followed by the SAH compaction
    /// (`bvhlab_bvh::collapse`, thesis 3.8 / Bittner 3.6) inside the timed build: the thesis counts
    /// the compaction as part of AAC / PLOC construction.
    pub collapse: bool,
    pub finish: Option<FinishFn>,
    pub label: Option<LabelFn>,
}

impl BuilderInfo {
    /// A top-down builder over boxes and centres (no codes, no compaction, plain label).
    pub fn top_down(
        name: &'static str,
        about: &'static str,
        params: Vec<ParamSpec>,
        run: BuildFn,
    ) -> BuilderInfo {
        BuilderInfo {
            name,
            version: 1,
            about,
            params,
            run,
            codes: None,
            collapse: false,
            finish: None,
            label: None,
        }
    }

    pub fn with_finish(mut self, f: FinishFn) -> BuilderInfo {
        self.finish = Some(f);
        self
    }
    pub fn with_label(mut self, f: LabelFn) -> BuilderInfo {
        self.label = Some(f);
        self
    }

    /// What the build stage produces: the builder, then (bottom-up builders) the SAH compaction.
    pub fn construct(
        &self,
        boxes: &[Aabb],
        centers: &[Vec3],
        codes: Option<&SortedCodes>,
        r: &Resolved,
    ) -> Bvh {
        let bvh = (self.run)(boxes, centers, codes, r);
        if self.collapse {
            bvhlab_bvh::collapse::collapse(&bvh, r.cost)
        } else {
            bvh
        }
    }
}

#[derive(Clone)]
pub struct EncoderInfo {
    pub name: &'static str,
    /// Implementation version, as `BuilderInfo::version`.
    pub version: u32,
    pub about: &'static str,
    pub scheme: Scheme,
    pub params: Vec<ParamSpec>,
}

pub const COST_PARAMS: [ParamSpec; 2] = [
    ParamSpec {
        name: "c_t",
        default: "3",
        kind: Kind::PositiveFloat,
        about: "SAH traversal cost c_T (thesis 2.2.2)",
        in_label: false,
    },
    ParamSpec {
        name: "c_i",
        default: "2",
        kind: Kind::PositiveFloat,
        about: "SAH intersection cost c_I (thesis 2.2.2)",
        in_label: false,
    },
];

const LEAF: ParamSpec = ParamSpec {
    name: "leaf",
    default: "2",
    kind: Kind::UInt {
        min: 1,
        max: 1 << 16,
    },
    about:
        "primitive threshold: nodes with at most this many triangles become leaves (thesis 2.3.1)",
    in_label: false,
};

const BOUNDS: ParamSpec = ParamSpec {
    name: "bounds",
    default: "scene",
    kind: Kind::Choice(&["scene", "centroids", "concise"]),
    about: "quantization frame: scene box, centroid box, or concise bounds (Riemersma eq. 15)",
    in_label: false,
};

const GRID_BITS: ParamSpec = ParamSpec {
    name: "grid_bits",
    default: "0",
    kind: Kind::Choice(&["0", "6", "9", "12"]),
    about: "occupation grid bits (Riemersma 3.2.2; 0 = off)",
    in_label: false,
};

const GRID_FRAME: ParamSpec = ParamSpec {
    name: "grid_frame",
    default: "cell",
    kind: Kind::Choice(&["cell", "tight"]),
    about: "with grid_bits > 0: the in-cell code quantizes the grid cell (cell, Riemersma 3.2.2) or the \
            bounds of the centroids inside it (tight; bvhlab's extension, not in the papers)",
    in_label: false,
};

/// Shortest round-trip form, so `3`, `3.0` and `3.00` share a key.
pub fn fmt_f32(v: f32) -> String {
    format!("{v}")
}

fn canonical(spec: &ParamSpec, value: &str, auto: Option<AutoFor>) -> Result<String, String> {
    let v = value.trim();
    match spec.kind {
        Kind::UInt { min, max } => match v.parse::<u64>() {
            Ok(n) if n >= min as u64 && n <= max as u64 => Ok(n.to_string()),
            _ => Err(format!("an integer in {min}..={max}")),
        },
        Kind::PositiveFloat => match v.parse::<f32>() {
            Ok(x) if x.is_finite() && x > 0.0 => Ok(fmt_f32(x)),
            _ => Err("a finite number > 0".to_string()),
        },
        Kind::NonNegativeFloat => match v.parse::<f32>() {
            // `+ 0.0` turns -0 into 0, so both spellings share a key.
            Ok(x) if x.is_finite() && x >= 0.0 => Ok(fmt_f32(x + 0.0)),
            _ => Err("a finite number >= 0".to_string()),
        },
        Kind::Choice(words) => match words.iter().find(|w| **w == v) {
            Some(w) => Ok(w.to_string()),
            None => Err(format!("one of {}", words.join(", "))),
        },
        Kind::AutoOrUInt { min, max } => {
            let want = || format!("`auto` or an integer in {min}..={max}");
            let auto_name = auto.map(auto_name);
            if v == "auto" || Some(v) == auto_name.map(|a| format!("auto:{a}")).as_deref() {
                return auto_name.map(|a| format!("auto:{a}")).ok_or_else(want);
            }
            match v.parse::<u64>() {
                Ok(n) if n >= min as u64 && n <= max as u64 => Ok(n.to_string()),
                _ => Err(want()),
            }
        }
    }
}

fn auto_name(a: AutoFor) -> &'static str {
    match a {
        AutoFor::Aac => "aac",
        AutoFor::Lbvh => "lbvh",
        AutoFor::Ploc => "ploc",
    }
}

fn names(specs: &[ParamSpec]) -> String {
    if specs.is_empty() {
        return "(none)".into();
    }
    specs.iter().map(|p| p.name).collect::<Vec<_>>().join(", ")
}

/// The pipeline guarantees codes for code-using builders (`BuilderInfo::codes`).
fn sorted<'a>(s: Option<&'a SortedCodes<'a>>) -> &'a SortedCodes<'a> {
    s.expect("the pipeline passes sorted codes to every builder with `codes: Some(..)`")
}

/// AAC: `preset=hq|fast` fills delta / epsilon (thesis table 2); explicit values must agree with it.
/// The canonical parameters are delta and epsilon only, so `preset=hq` and `delta=20,epsilon=0.1`
/// share a key.
fn aac_finish(
    raw: &BTreeMap<String, String>,
    params: &mut BTreeMap<String, String>,
) -> Result<(), String> {
    let preset = params.remove("preset").unwrap_or_else(|| "none".into());
    let cfg = match preset.as_str() {
        "hq" => AacConfig::HQ,
        "fast" => AacConfig::FAST,
        _ => return Ok(()),
    };
    for (name, val) in [
        ("delta", cfg.delta.to_string()),
        ("epsilon", fmt_f32(cfg.epsilon)),
    ] {
        if raw.contains_key(name) && params.get(name) != Some(&val) {
            return Err(format!(
                "preset={preset} sets {name}={val}, but {name}={} was given; give either the preset or delta/epsilon",
                raw[name]
            ));
        }
        params.insert(name.to_string(), val);
    }
    Ok(())
}

/// Bonsai: `t` only matters with `prune=true`; without pruning it is dropped from the key, so
/// BP0 has one spelling.
fn bonsai_finish(
    _raw: &BTreeMap<String, String>,
    params: &mut BTreeMap<String, String>,
) -> Result<(), String> {
    if params.get("prune").map(String::as_str) != Some("true") {
        params.remove("t");
    }
    Ok(())
}

fn bonsai_label(r: &Resolved) -> String {
    let mut s = format!("bonsai n={}", r.u32("n"));
    if r.flag("prune") {
        s.push_str(&format!(
            " prune t={}",
            r.params.get("t").cloned().unwrap_or_default()
        ));
    }
    if r.params.get("leaf").map(String::as_str) != Some(LEAF.default) {
        s.push_str(&format!(" leaf={}", r.u32("leaf")));
    }
    s
}

fn aac_label(r: &Resolved) -> String {
    let c = r.aac_config();
    if c == AacConfig::HQ {
        "aac HQ".into()
    } else if c == AacConfig::FAST {
        "aac fast".into()
    } else {
        format!("aac delta={} epsilon={}", c.delta, fmt_f32(c.epsilon))
    }
}

/// Runs an optimizer on a built BVH with its resolved parameters.
pub type OptimizeFn = fn(&Bvh, &ResolvedOptimizer) -> bvhlab_opt::Optimized;

#[derive(Clone)]
pub struct OptimizerInfo {
    pub name: &'static str,
    /// Implementation version, as `BuilderInfo::version`.
    pub version: u32,
    pub about: &'static str,
    pub params: Vec<ParamSpec>,
    pub run: OptimizeFn,
    pub finish: Option<FinishFn>,
}

/// An optimizer with its parameters resolved (canonical strings, defaults included) and the chain's
/// cost constants (the optimizers minimize thesis eq. 4 with the same c_T / c_I).
#[derive(Clone, Debug, PartialEq)]
pub struct ResolvedOptimizer {
    pub optimizer: String,
    pub params: BTreeMap<String, String>,
    pub cost: CostParams,
}

impl ResolvedOptimizer {
    pub fn u32(&self, name: &str) -> u32 {
        typed(&self.params, name)
    }
    pub fn f64(&self, name: &str) -> f64 {
        typed(&self.params, name)
    }
    pub fn flag(&self, name: &str) -> bool {
        typed(&self.params, name)
    }
    /// `max_seconds > 0`: the result may depend on machine speed.
    pub fn time_capped(&self) -> bool {
        self.f64("max_seconds") > 0.0
    }
    pub fn ibo_config(&self) -> bvhlab_opt::ibo::IboConfig {
        bvhlab_opt::ibo::IboConfig {
            measure: self
                .params
                .get("measure")
                .and_then(|m| bvhlab_opt::ibo::Measure::parse(m))
                .unwrap_or(bvhlab_opt::ibo::Measure::Comb),
            schedule: self
                .params
                .get("schedule")
                .and_then(|s| bvhlab_opt::ibo::Schedule::parse(s))
                .unwrap_or_default(),
            frac: self.f64("ibo_frac") as f32,
            pt: self.u32("pt"),
            pr: self.u32("pr"),
            max_passes: self.u32("max_passes"),
            max_seconds: self.f64("max_seconds"),
            budget: self.params.get("budget").map(String::as_str) != Some("off"),
            frac_of_all: self.params.get("ibo_nodes").map(String::as_str) == Some("all"),
            keep_best: self.flag("keep_best"),
            seed: self.u32("seed") as u64,
            cost: self.cost,
        }
    }
    pub fn kensler_config(&self, anneal: bool) -> bvhlab_opt::kensler::KenslerConfig {
        bvhlab_opt::kensler::KenslerConfig {
            anneal,
            t0: self.f64("t0"),
            cooling: self.f64("cooling"),
            max_passes: self.u32("max_passes"),
            max_seconds: self.f64("max_seconds"),
            budget: self.params.get("budget").map(String::as_str) != Some("off"),
            keep_best: self.flag("keep_best"),
            seed: self.u32("seed") as u64,
            cost: self.cost,
        }
    }
}

/// One chain's resolved builder, encoder (code-using builders) and optimizer.
#[derive(Clone, Debug, PartialEq)]
pub struct ResolvedChain {
    pub build: Resolved,
    pub encoder: Option<ResolvedEncoder>,
    pub optimizer: Option<ResolvedOptimizer>,
}

impl ResolvedChain {
    /// Builder and encoder (for callers that take no optimizer).
    pub fn parts(self) -> (Resolved, Option<ResolvedEncoder>) {
        (self.build, self.encoder)
    }
}

const MAX_PASSES: ParamSpec = ParamSpec {
    name: "max_passes",
    default: "0",
    kind: Kind::UInt {
        min: 0,
        max: u32::MAX,
    },
    about: "stop after this many passes (0 = no limit)",
    in_label: false,
};

const MAX_SECONDS: ParamSpec = ParamSpec {
    name: "max_seconds",
    default: "0",
    kind: Kind::NonNegativeFloat,
    about:
        "stop after this many seconds (0 = no limit); a run stopped by it depends on machine speed",
    in_label: false,
};

const BUDGET: ParamSpec = ParamSpec {
    name: "budget",
    default: "auto",
    kind: Kind::Choice(&["auto", "off"]),
    about: "auto: stop after a pass budget derived from the tree size (ibo: 25 updates per inner node; \
            kensler: 16 log2(nodes) + 64 passes), optimize_stop = pass_budget; off: no budget",
    in_label: false,
};

const KEEP_BEST: ParamSpec = ParamSpec {
    name: "keep_best",
    default: "true",
    kind: Kind::Choice(&["true", "false"]),
    about: "return the best tree seen, not the last (fixes the oscillation of thesis 5.2.1)",
    in_label: false,
};

const SEED: ParamSpec = ParamSpec {
    name: "seed",
    default: "1",
    kind: Kind::UInt {
        min: 0,
        max: u32::MAX,
    },
    about: "seed of the random choices",
    in_label: false,
};

/// ibo: p_R <= p_T (Bittner 2013 section 3.5); `schedule = "thesis"` returns the last tree
/// (thesis 3.4.3, 5.2.1) unless `keep_best` is given.
fn ibo_finish(
    raw: &BTreeMap<String, String>,
    params: &mut BTreeMap<String, String>,
) -> Result<(), String> {
    if params.get("schedule").map(String::as_str) == Some("thesis") {
        // The thesis' run as a whole (3.4.3, 5.2.1): the last tree, and k = 1% of all nodes;
        // either can still be set explicitly.
        if !raw.contains_key("keep_best") {
            params.insert("keep_best".into(), "false".into());
        }
        if !raw.contains_key("ibo_nodes") {
            params.insert("ibo_nodes".into(), "all".into());
        }
    }
    let get = |k: &str| typed::<u32>(params, k);
    if get("pr") > get("pt") {
        return Err(format!(
            "pr={} must not exceed pt={} (Bittner 2013 3.5: p_R <= p_T)",
            get("pr"),
            get("pt")
        ));
    }
    if params.get("measure").map(String::as_str) == Some("random") {
        // Random sampling has nothing to switch to.
        params.insert("pr".into(), "0".into());
    }
    Ok(())
}

fn kensler_sa_finish(
    _raw: &BTreeMap<String, String>,
    params: &mut BTreeMap<String, String>,
) -> Result<(), String> {
    let c: f64 = typed(params, "cooling");
    if !(c > 0.0 && c < 1.0) {
        return Err(format!("cooling={c} must be in (0, 1)"));
    }
    Ok(())
}

#[derive(Clone)]
pub struct Registry {
    pub builders: Vec<BuilderInfo>,
    pub encoders: Vec<EncoderInfo>,
    pub optimizers: Vec<OptimizerInfo>,
}

impl Default for Registry {
    fn default() -> Self {
        Self::standard()
    }
}

impl Registry {
    pub fn standard() -> Registry {
        Registry {
            builders: Self::standard_builders(),
            encoders: Self::standard_encoders(),
            optimizers: Self::standard_optimizers(),
        }
    }

    pub fn standard_optimizers() -> Vec<OptimizerInfo> {
        vec![
            OptimizerInfo {
                name: "ibo",
                version: 1,
                about: "insertion-based optimization: remove a node's children, reinsert each where the cost grows \
                        least (Bittner et al. 2013; thesis 3.4)",
                params: vec![
                    ParamSpec {
                        name: "measure",
                        default: "comb",
                        kind: Kind::Choice(&["sum", "min", "area", "comb", "random"]),
                        about: "node inefficiency measure selecting the nodes of a pass (Bittner 2013 3.4)",
                        in_label: true,
                    },
                    ParamSpec {
                        name: "ibo_frac",
                        default: "0.01",
                        kind: Kind::PositiveFloat,
                        about: "fraction of the nodes updated per pass (k = 1%; which nodes it counts: ibo_nodes)",
                        in_label: false,
                    },
                    ParamSpec {
                        name: "ibo_nodes",
                        default: "inner",
                        kind: Kind::Choice(&["inner", "all"]),
                        about: "what ibo_frac counts: inner nodes (Bittner 2013 fig. 8, \"1% of inner nodes\") or all \
                                nodes (thesis 3.4.3, \"1% of nodes\", of which only inner ones are updated)",
                        in_label: false,
                    },
                    ParamSpec {
                        name: "schedule",
                        default: "bittner",
                        kind: Kind::Choice(&["bittner", "thesis"]),
                        about: "termination: bittner = stop after p_T passes without improving the best cost, \
                                random sampling after p_R of them (Bittner 2013 3.5); thesis = check the cost \
                                every p_T passes against the previous check, at the first check without \
                                improvement switch to random sampling checked every p_R passes, stop at its \
                                first check without improvement and return the last tree (keep_best=false \
                                unless given; Frantal 2019 3.4.3, what tables 20 and 38 measure)",
                        in_label: false,
                    },
                    ParamSpec {
                        name: "pt",
                        default: "10",
                        kind: Kind::UInt { min: 1, max: 1 << 20 },
                        about: "bittner: stop after p_T passes without improving the cost (Bittner 2013 3.5); \
                                thesis: passes between the cost checks of the measure stage",
                        in_label: false,
                    },
                    ParamSpec {
                        name: "pr",
                        default: "5",
                        kind: Kind::UInt { min: 0, max: 1 << 20 },
                        about: "bittner: switch to random sampling after p_R passes without improvement; thesis: \
                                passes between the checks of the random stage (0: no random sampling)",
                        in_label: false,
                    },
                    MAX_PASSES,
                    MAX_SECONDS,
                    BUDGET,
                    KEEP_BEST,
                    SEED,
                ],
                run: |bvh, r| bvhlab_opt::ibo::optimize(bvh, &r.ibo_config()),
                finish: Some(ibo_finish),
            },
            OptimizerInfo {
                name: "kensler-hc",
                version: 1,
                about: "tree rotations, hill climbing: apply the best improving rotation at each node until a pass \
                        finds none (Kensler 2008)",
                params: vec![MAX_PASSES, MAX_SECONDS, BUDGET, KEEP_BEST, SEED],
                run: |bvh, r| bvhlab_opt::kensler::optimize(bvh, &r.kensler_config(false)),
                finish: None,
            },
            OptimizerInfo {
                name: "kensler-sa",
                version: 1,
                about: "tree rotations, simulated annealing (Kensler 2008); capped by max_passes / max_seconds",
                params: vec![
                    ParamSpec {
                        name: "t0",
                        // 0.01 wrecks real trees in the first passes (dragon: cost 414 at pass 10);
                        // 1e-5 still escapes hill climbing's optimum (dragon 144.27 vs HC 144.35).
                        default: "0.00001",
                        kind: Kind::PositiveFloat,
                        about: "start temperature T0, an area relative to the root surface area (T = t0 SA(root))",
                        in_label: false,
                    },
                    ParamSpec {
                        name: "cooling",
                        default: "0.9",
                        kind: Kind::PositiveFloat,
                        about: "temperature factor per pass, in (0, 1)",
                        in_label: false,
                    },
                    ParamSpec { default: "100", ..MAX_PASSES },
                    ParamSpec { default: "600", ..MAX_SECONDS },
                    BUDGET,
                    KEEP_BEST,
                    SEED,
                ],
                run: |bvh, r| bvhlab_opt::kensler::optimize(bvh, &r.kensler_config(true)),
                finish: Some(kensler_sa_finish),
            },
        ]
    }

    pub fn standard_builders() -> Vec<BuilderInfo> {
        vec![
            BuilderInfo::top_down(
                "spatial-median",
                "split the largest axis at its middle (Kay and Kajiya 1986; thesis 3.2)",
                vec![
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
                |b, c, _, r| {
                    use bvhlab_builders::spatial_median::{build_in, Frame};
                    let frame = r.params.get("frame").and_then(|f| Frame::parse(f)).unwrap_or_default();
                    build_in(b, c, &r.config(), frame)
                },
            ),
            BuilderInfo::top_down(
                "sweep-sah",
                "full-sweep SAH over all three axes (thesis 3.3.1)",
                vec![LEAF],
                |b, c, _, r| bvhlab_builders::sweep_sah::build(b, c, &r.config()),
            ),
            BuilderInfo::top_down(
                "binned-sah",
                "binned SAH (Wald 2007; thesis 3.1.1), parallel (thesis 3.1.2)",
                vec![
                    ParamSpec {
                        name: "bins",
                        default: "16",
                        kind: Kind::UInt { min: 2, max: 4096 },
                        about: "number of bins per axis",
                        in_label: true,
                    },
                    LEAF,
                    ParamSpec {
                        name: "centroid_stop",
                        default: "split-axis",
                        kind: Kind::Choice(&["split-axis", "any-axis"]),
                        about: "stop when the centroid extent is < 1e-7 of the node box along the split axis (default) or along any \
                                axis (the thesis' literal rule, 3.1.1; reproduces its BIN column)",
                        in_label: false,
                    },
                ],
                |b, c, _, r| {
                    // Parallel over the current rayon pool (thesis 3.1.2); the same tree bytes as
                    // the sequential builder at any thread count.
                    use bvhlab_builders::binned_sah::{build_parallel, CentroidTermination};
                    let stop = match r.params.get("centroid_stop").map(String::as_str) {
                        Some("any-axis") => CentroidTermination::AnyAxis,
                        _ => CentroidTermination::SplitAxis,
                    };
                    build_parallel(b, c, r.u32("bins"), &r.config(), stop)
                },
            ),
            BuilderInfo::top_down(
                "bonsai",
                "Bonsai: spatial-median mini-tree sets of at most n, full-sweep SAH mini trees in parallel, optional \
                 pruning, full-sweep SAH top tree (Ganestam et al. 2015; thesis 3.3)",
                vec![
                    ParamSpec {
                        name: "n",
                        default: "512",
                        kind: Kind::UInt { min: 2, max: 1 << 24 },
                        about: "primitive set size threshold N (thesis table 3: 512 or 4096)",
                        in_label: true,
                    },
                    ParamSpec {
                        name: "t",
                        default: "0.1",
                        kind: Kind::PositiveFloat,
                        about: "pruning threshold T, times the mean mini-tree area (thesis 3.3.3: 0.1 or 0.01)",
                        in_label: false,
                    },
                    ParamSpec {
                        name: "prune",
                        default: "false",
                        kind: Kind::Choice(&["true", "false"]),
                        about: "prune mini trees larger than T times the mean (thesis 3.3.3)",
                        in_label: true,
                    },
                    LEAF,
                ],
                |b, c, _, r| {
                    let cfg = bvhlab_builders::bonsai::BonsaiConfig {
                        n: r.u32("n"),
                        t: r.f32("t"),
                        prune: r.flag("prune"),
                        top: r.config(),
                    };
                    bvhlab_builders::bonsai::build(b, c, &cfg)
                },
            )
            .with_finish(bonsai_finish)
            .with_label(bonsai_label),
            BuilderInfo {
                name: "incremental",
                version: 1,
                about: "insertion of primitives in input order with branch-and-bound search and an optimization pass \
                        per batch (Bittner et al. 2015; thesis 3.5.1); one primitive per leaf: add compact = \"collapse\"",
                params: vec![
                    ParamSpec {
                        name: "batch",
                        default: "8000",
                        kind: Kind::UInt { min: 1, max: u32::MAX },
                        about: "primitives inserted between optimization passes (thesis table 5)",
                        in_label: false,
                    },
                    ParamSpec {
                        name: "ofrac",
                        default: "0.01",
                        kind: Kind::PositiveFloat,
                        about: "fraction of the touched inner nodes optimized after each batch (thesis table 5)",
                        in_label: false,
                    },
                    ParamSpec {
                        name: "coh",
                        default: "1.5",
                        kind: Kind::NonNegativeFloat,
                        about: "coherence threshold R_max of thesis eq. 13 (0 disables clustering)",
                        in_label: false,
                    },
                ],
                run: |b, _, _, r| {
                    let cfg = bvhlab_builders::incremental::IncConfig {
                        batch: r.u32("batch"),
                        ofrac: r.f32("ofrac"),
                        coh: r.f32("coh"),
                        cost: r.cost,
                    };
                    bvhlab_builders::incremental::build(b, &cfg)
                },
                codes: None,
                collapse: false,
                finish: None,
                label: None,
            },
            BuilderInfo {
                name: "lbvh",
                version: 1,
                about: "LBVH: binary radix tree over sorted codes (Karras 2012; thesis 2.3.4), then SAH compaction",
                params: vec![],
                run: |b, _, s, _| bvhlab_builders::lbvh::build(b, sorted(s)),
                codes: Some(AutoFor::Lbvh),
                collapse: true,
                finish: None,
                label: None,
            },
            BuilderInfo {
                name: "aac",
                version: 1,
                about: "approximate agglomerative clustering (Gu et al. 2013; thesis 3.2), then SAH compaction",
                params: vec![
                    ParamSpec {
                        name: "preset",
                        default: "none",
                        kind: Kind::Choice(&["hq", "fast", "none"]),
                        about: "hq: delta=20 epsilon=0.1, fast: delta=4 epsilon=0.2 (thesis table 2); none: use delta/epsilon",
                        in_label: false,
                    },
                    ParamSpec {
                        name: "delta",
                        default: "20",
                        kind: Kind::UInt { min: 1, max: 1 << 20 },
                        about: "constraint-tree leaf threshold delta (thesis 3.2)",
                        in_label: true,
                    },
                    ParamSpec {
                        name: "epsilon",
                        default: "0.1",
                        kind: Kind::NonNegativeFloat,
                        about: "cluster-count reduction exponent term epsilon (thesis 3.2)",
                        in_label: true,
                    },
                ],
                run: |b, _, s, r| bvhlab_builders::aac::build(b, sorted(s), &r.aac_config()),
                codes: Some(AutoFor::Aac),
                collapse: true,
                finish: Some(aac_finish),
                label: Some(aac_label),
            },
            BuilderInfo {
                name: "ploc",
                version: 1,
                about: "parallel locally-ordered clustering (Meister and Bittner 2018; thesis 3.6), then SAH compaction",
                params: vec![ParamSpec {
                    name: "radius",
                    default: "10",
                    kind: Kind::UInt { min: 1, max: 1 << 16 },
                    about: "nearest-neighbour search radius r (thesis table 6: 10, 25, 100)",
                    in_label: true,
                }],
                run: |b, _, s, r| {
                    bvhlab_builders::ploc::build(b, sorted(s), &bvhlab_builders::ploc::PlocConfig { radius: r.u32("radius") })
                },
                codes: Some(AutoFor::Ploc),
                collapse: true,
                finish: None,
                label: None,
            },
        ]
    }

    pub fn standard_encoders() -> Vec<EncoderInfo> {
        vec![
            EncoderInfo {
                name: "morton",
                version: 1,
                about: "Morton code, bits per axis interleaved x y z (thesis 2.3.4)",
                scheme: Scheme::Morton,
                params: vec![
                    ParamSpec {
                        name: "bits",
                        default: "auto",
                        kind: Kind::AutoOrUInt { min: 1, max: 21 },
                        about: "bits per axis; auto = the builder's own choice (aac: ceil(log4 n), lbvh: 10, ploc: 20)",
                        in_label: false,
                    },
                    BOUNDS,
                    GRID_BITS,
                    GRID_FRAME,
                ],
            },
            EncoderInfo {
                name: "emc64-sort",
                version: 1,
                about: "Extended Morton code, 64 bits, size bit every 4th bit, axes by extent (Vinkler 2017; thesis 3.7.1)",
                scheme: Scheme::Emc64Sort,
                params: vec![BOUNDS, GRID_BITS, GRID_FRAME],
            },
            EncoderInfo {
                name: "emc64-var",
                version: 1,
                about: "Extended Morton code, 64 bits, size bit every 7th bit, others on the largest axis (thesis 3.7.1)",
                scheme: Scheme::Emc64Var,
                params: vec![BOUNDS, GRID_BITS, GRID_FRAME],
            },
        ]
    }

    pub fn names(&self) -> Vec<&'static str> {
        self.builders.iter().map(|b| b.name).collect()
    }

    pub fn encoder_names(&self) -> Vec<&'static str> {
        self.encoders.iter().map(|e| e.name).collect()
    }

    fn code_builder_names(&self) -> String {
        self.builders
            .iter()
            .filter(|b| b.codes.is_some())
            .map(|b| b.name)
            .collect::<Vec<_>>()
            .join(", ")
    }

    pub fn get(&self, name: &str) -> Result<&BuilderInfo> {
        self.builders
            .iter()
            .find(|b| b.name == name)
            .ok_or_else(|| {
                Error::input(format!(
                    "unknown builder `{name}`; valid builders: {}",
                    self.names().join(", ")
                ))
            })
    }

    pub fn encoder(&self, name: &str) -> Result<&EncoderInfo> {
        self.encoders
            .iter()
            .find(|e| e.name == name)
            .ok_or_else(|| {
                Error::input(format!(
                    "unknown encoder `{name}`; valid encoders: {}",
                    self.encoder_names().join(", ")
                ))
            })
    }

    /// Validates `raw` (user-given `name -> value`) against the builder's schema plus the cost
    /// parameters; missing ones take their defaults (`cost` for c_t / c_i).
    pub fn resolve(
        &self,
        builder: &str,
        raw: &BTreeMap<String, String>,
        cost: CostParams,
    ) -> Result<Resolved> {
        let info = self.get(builder)?;
        let valid = || {
            info.params
                .iter()
                .chain(COST_PARAMS.iter())
                .map(|p| p.name)
                .collect::<Vec<_>>()
                .join(", ")
        };
        for k in raw.keys() {
            if !info
                .params
                .iter()
                .chain(COST_PARAMS.iter())
                .any(|p| p.name == k)
            {
                let hint = if info.codes.is_none()
                    && self
                        .encoders
                        .iter()
                        .any(|e| e.params.iter().any(|p| p.name == k))
                {
                    format!(" (`{k}` is an encoder parameter; `{builder}` is top-down and takes no codes)")
                } else {
                    String::new()
                };
                return Err(Error::input(format!(
                    "unknown parameter `{k}` for builder `{builder}`; valid parameters: {}{hint}",
                    valid()
                )));
            }
        }
        let mut params = BTreeMap::new();
        for spec in &info.params {
            let given = raw
                .get(spec.name)
                .map(String::as_str)
                .unwrap_or(spec.default);
            let v = canonical(spec, given, None).map_err(|want| {
                Error::input(format!(
                    "bad value `{given}` for `{}` of `{builder}`: expected {want}",
                    spec.name
                ))
            })?;
            params.insert(spec.name.to_string(), v);
        }
        if let Some(finish) = info.finish {
            finish(raw, &mut params)
                .map_err(|why| Error::input(format!("builder `{builder}`: {why}")))?;
        }
        let mut cost_v = [cost.c_t, cost.c_i];
        for (i, spec) in COST_PARAMS.iter().enumerate() {
            if let Some(given) = raw.get(spec.name) {
                let v = canonical(spec, given, None).map_err(|want| {
                    Error::input(format!(
                        "bad value `{given}` for `{}`: expected {want}",
                        spec.name
                    ))
                })?;
                cost_v[i] = v.parse().unwrap_or(cost_v[i]);
            }
        }
        Ok(Resolved {
            builder: builder.to_string(),
            params,
            cost: CostParams {
                c_t: cost_v[0],
                c_i: cost_v[1],
            },
        })
    }

    /// Validates an encoder and its parameters for a code-using builder (`auto` = that builder's
    /// code length).
    pub fn resolve_encoder(
        &self,
        encoder: &str,
        raw: &BTreeMap<String, String>,
        auto: AutoFor,
    ) -> Result<ResolvedEncoder> {
        let info = self.encoder(encoder)?;
        for k in raw.keys() {
            if !info.params.iter().any(|p| p.name == k) {
                return Err(Error::input(format!(
                    "unknown parameter `{k}` for encoder `{encoder}`; valid parameters: {}",
                    names(&info.params)
                )));
            }
        }
        let mut params = BTreeMap::new();
        for spec in &info.params {
            let given = raw
                .get(spec.name)
                .map(String::as_str)
                .unwrap_or(spec.default);
            let v = canonical(spec, given, Some(auto)).map_err(|want| {
                Error::input(format!(
                    "bad value `{given}` for `{}` of encoder `{encoder}`: expected {want}",
                    spec.name
                ))
            })?;
            params.insert(spec.name.to_string(), v);
        }
        // grid_frame only means something with a grid: keep it out of the key (and the row's
        // encode_params) otherwise, so grid-less encodings keep one canonical spelling.
        if params.get("grid_bits").map(String::as_str) == Some("0") {
            if params.get("grid_frame").map(String::as_str) == Some("tight") {
                return Err(Error::input(format!(
                    "`grid_frame=tight` of encoder `{encoder}` needs an occupation grid: set grid_bits to 6, 9 or 12"
                )));
            }
            params.remove("grid_frame");
        }
        let bits = match params.get("bits").map(String::as_str) {
            // EMC codes have no bits parameter (always 64 bits); the field is not read for them,
            // and a constant keeps the config (and so the output) independent of the builder.
            None => Bits::Fixed(10),
            Some(b) if b.starts_with("auto") => Bits::Auto(auto),
            Some(b) => Bits::Fixed(b.parse().unwrap_or(10)),
        };
        let bounds = match params.get("bounds").map(String::as_str) {
            Some("centroids") => BoundsMode::Centroids,
            Some("concise") => BoundsMode::Concise,
            _ => BoundsMode::Scene,
        };
        let grid_bits = params
            .get("grid_bits")
            .and_then(|g| g.parse().ok())
            .unwrap_or(0);
        let config = EncodeConfig {
            scheme: info.scheme,
            bits,
            bounds,
            grid_bits,
        };
        let cell_frame = match params.get("grid_frame").map(String::as_str) {
            Some("tight") => CellFrame::Tight,
            _ => CellFrame::Lattice,
        };
        Ok(ResolvedEncoder {
            encoder: encoder.to_string(),
            params,
            config,
            cell_frame,
        })
    }

    pub fn optimizer_names(&self) -> Vec<&'static str> {
        self.optimizers.iter().map(|o| o.name).collect()
    }

    pub fn optimizer(&self, name: &str) -> Result<&OptimizerInfo> {
        self.optimizers
            .iter()
            .find(|o| o.name == name)
            .ok_or_else(|| {
                Error::input(format!(
                    "unknown optimizer `{name}`; valid optimizers: {}",
                    self.optimizer_names().join(", ")
                ))
            })
    }

    /// Validates an optimizer's parameters (defaults filled in, canonical strings).
    pub fn resolve_optimizer(
        &self,
        name: &str,
        raw: &BTreeMap<String, String>,
        cost: CostParams,
    ) -> Result<ResolvedOptimizer> {
        let info = self.optimizer(name)?;
        for k in raw.keys() {
            if !info.params.iter().any(|p| p.name == k) {
                return Err(Error::input(format!(
                    "unknown parameter `{k}` for optimizer `{name}`; valid parameters: {}",
                    names(&info.params)
                )));
            }
        }
        let mut params = BTreeMap::new();
        for spec in &info.params {
            let given = raw
                .get(spec.name)
                .map(String::as_str)
                .unwrap_or(spec.default);
            let v = canonical(spec, given, None).map_err(|want| {
                Error::input(format!(
                    "bad value `{given}` for `{}` of optimizer `{name}`: expected {want}",
                    spec.name
                ))
            })?;
            params.insert(spec.name.to_string(), v);
        }
        if let Some(finish) = info.finish {
            finish(raw, &mut params)
                .map_err(|why| Error::input(format!("optimizer `{name}`: {why}")))?;
        }
        Ok(ResolvedOptimizer {
            optimizer: name.to_string(),
            params,
            cost,
        })
    }

    /// Optimizer label: `ibo comb`, plus parameters changed from their defaults.
    pub fn optimizer_label(&self, o: &ResolvedOptimizer) -> String {
        let mut parts = vec![o.optimizer.clone()];
        // The thesis schedule returns the last tree and counts all nodes unless told otherwise
        // (ibo_finish).
        let thesis = o.params.get("schedule").map(String::as_str) == Some("thesis");
        let default_of = |spec: &ParamSpec| {
            if thesis && spec.name == "keep_best" {
                "false"
            } else if thesis && spec.name == "ibo_nodes" {
                "all"
            } else {
                spec.default
            }
        };
        if let Ok(info) = self.optimizer(&o.optimizer) {
            for spec in &info.params {
                let Some(v) = o.params.get(spec.name) else {
                    continue;
                };
                if spec.in_label {
                    parts.push(v.clone());
                } else if v != default_of(spec) && !(spec.name == "pr" && v == "0") {
                    parts.push(format!("{}={v}", spec.name));
                }
            }
        }
        parts.join(" ")
    }

    /// Resolves one chain's builder, encoder (code-using builders only) and optimizer; `raw` holds
    /// the parameters of all three, routed by name (builder first, then encoder, then optimizer).
    /// `encode` given for a top-down builder is an error.
    pub fn resolve_chain(
        &self,
        builder: &str,
        encode: Option<&str>,
        optimize: Option<&str>,
        raw: &BTreeMap<String, String>,
        cost: CostParams,
    ) -> Result<ResolvedChain> {
        let info = self.get(builder)?;
        if let (None, Some(e)) = (info.codes, encode) {
            return Err(Error::input(format!(
                "builder `{builder}` is top-down and takes no codes, so `encode = \"{e}\"` does not apply; \
                 encoders feed the bottom-up builders: {}",
                self.code_builder_names()
            )));
        }
        let einfo = match info.codes {
            Some(_) => Some(self.encoder(encode.unwrap_or("morton"))?),
            None => None,
        };
        let oinfo = optimize.map(|o| self.optimizer(o)).transpose()?;
        let (mut braw, mut eraw, mut oraw) = (BTreeMap::new(), BTreeMap::new(), BTreeMap::new());
        for (k, v) in raw {
            if info
                .params
                .iter()
                .chain(COST_PARAMS.iter())
                .any(|p| p.name == k)
            {
                braw.insert(k.clone(), v.clone());
            } else if einfo.is_some_and(|e| e.params.iter().any(|p| p.name == k)) {
                eraw.insert(k.clone(), v.clone());
            } else if oinfo.is_some_and(|o| o.params.iter().any(|p| p.name == k)) {
                oraw.insert(k.clone(), v.clone());
            } else {
                let mut bp: Vec<&str> = info.params.iter().map(|p| p.name).collect();
                bp.extend(COST_PARAMS.iter().map(|p| p.name));
                let mut msg = format!("unknown parameter `{k}` for builder `{builder}`");
                if let Some(e) = einfo {
                    msg.push_str(&format!(" with encoder `{}`", e.name));
                }
                if let Some(o) = oinfo {
                    msg.push_str(&format!(" and optimizer `{}`", o.name));
                }
                msg.push_str(&format!("; builder parameters: {}", bp.join(", ")));
                if let Some(e) = einfo {
                    msg.push_str(&format!("; encoder parameters: {}", names(&e.params)));
                }
                if let Some(o) = oinfo {
                    msg.push_str(&format!("; optimizer parameters: {}", names(&o.params)));
                }
                if einfo.is_none()
                    && self
                        .encoders
                        .iter()
                        .any(|e| e.params.iter().any(|p| p.name == k))
                {
                    msg.push_str(&format!(" (`{k}` is an encoder parameter; `{builder}` is top-down and takes no codes)"));
                } else if oinfo.is_none()
                    && self
                        .optimizers
                        .iter()
                        .any(|o| o.params.iter().any(|p| p.name == k))
                {
                    msg.push_str(&format!(
                        " (`{k}` is an optimizer parameter; name the optimizer with `optimize`)"
                    ));
                }
                return Err(Error::input(msg));
            }
        }
        let build = self.resolve(builder, &braw, cost)?;
        let encoder = match (info.codes, einfo) {
            (Some(auto), Some(e)) => Some(self.resolve_encoder(e.name, &eraw, auto)?),
            _ => None,
        };
        let optimizer = oinfo
            .map(|o| self.resolve_optimizer(o.name, &oraw, build.cost))
            .transpose()?;
        Ok(ResolvedChain {
            build,
            encoder,
            optimizer,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn raw(kv: &[(&str, &str)]) -> BTreeMap<String, String> {
        kv.iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    }

    #[test]
    fn defaults_and_explicit_defaults_agree() {
        let r = Registry::standard();
        let a = r
            .resolve("binned-sah", &raw(&[]), CostParams::default())
            .unwrap();
        let b = r
            .resolve(
                "binned-sah",
                &raw(&[("bins", "16"), ("c_t", "3.0"), ("leaf", "02")]),
                CostParams::default(),
            )
            .unwrap();
        assert_eq!(a, b);
        assert_eq!(a.key_params(), b.key_params());
        assert_eq!(
            crate::key::params_string(&a.params),
            "bins=16,centroid_stop=split-axis,leaf=2"
        );
    }

    #[test]
    fn errors_list_valid_choices() {
        let r = Registry::standard();
        let e = r
            .resolve("nope", &raw(&[]), CostParams::default())
            .unwrap_err();
        assert!(
            e.message().contains("binned-sah") && e.exit_code() == 2,
            "{e}"
        );
        let e = r
            .resolve("sweep-sah", &raw(&[("bins", "4")]), CostParams::default())
            .unwrap_err();
        assert!(e.message().contains("leaf, c_t, c_i"), "{e}");
        let e = r
            .resolve("binned-sah", &raw(&[("bins", "x")]), CostParams::default())
            .unwrap_err();
        assert!(e.message().contains("bins"), "{e}");
        assert!(r
            .resolve("binned-sah", &raw(&[("c_i", "-1")]), CostParams::default())
            .is_err());
        assert!(r
            .resolve("binned-sah", &raw(&[("c_i", "inf")]), CostParams::default())
            .is_err());
    }

    #[test]
    fn cost_overrides() {
        let r = Registry::standard();
        let a = r
            .resolve(
                "spatial-median",
                &raw(&[("c_t", "1.5")]),
                CostParams { c_t: 9.0, c_i: 7.0 },
            )
            .unwrap();
        assert_eq!(a.cost, CostParams { c_t: 1.5, c_i: 7.0 });
    }

    #[test]
    fn aac_presets_share_keys_with_their_values() {
        let r = Registry::standard();
        let c = CostParams::default();
        let hq = r.resolve("aac", &raw(&[("preset", "hq")]), c).unwrap();
        let explicit = r
            .resolve("aac", &raw(&[("delta", "20"), ("epsilon", "0.10")]), c)
            .unwrap();
        let default = r.resolve("aac", &raw(&[]), c).unwrap();
        assert_eq!(hq, explicit);
        assert_eq!(hq, default);
        assert_eq!(
            crate::key::params_string(&hq.params),
            "delta=20,epsilon=0.1"
        );
        assert_eq!(r.label(&hq), "aac HQ");
        let fast = r
            .resolve("aac", &raw(&[("preset", "fast"), ("delta", "4")]), c)
            .unwrap();
        assert_eq!(fast.aac_config(), AacConfig::FAST);
        assert_eq!(r.label(&fast), "aac fast");
        let other = r
            .resolve("aac", &raw(&[("delta", "8"), ("epsilon", "0")]), c)
            .unwrap();
        assert_eq!(r.label(&other), "aac delta=8 epsilon=0");
        let e = r
            .resolve("aac", &raw(&[("preset", "fast"), ("delta", "20")]), c)
            .unwrap_err();
        assert!(
            e.message().contains("preset=fast sets delta=4") && e.exit_code() == 2,
            "{e}"
        );
        assert!(r.resolve("aac", &raw(&[("delta", "0")]), c).is_err());
        assert!(r.resolve("aac", &raw(&[("epsilon", "-0.1")]), c).is_err());
        assert!(r.resolve("aac", &raw(&[("preset", "best")]), c).is_err());
    }

    #[test]
    fn encoder_routing_and_auto_bits() {
        let r = Registry::standard();
        let c = CostParams::default();
        let (b, e) = r
            .resolve_chain(
                "ploc",
                None,
                None,
                &raw(&[("radius", "25"), ("bounds", "concise")]),
                c,
            )
            .unwrap()
            .parts();
        let e = e.unwrap();
        assert_eq!(crate::key::params_string(&b.params), "radius=25");
        assert_eq!(e.encoder, "morton");
        assert_eq!(
            crate::key::params_string(&e.params),
            "bits=auto:ploc,bounds=concise,grid_bits=0"
        );
        assert_eq!(e.config.bits, Bits::Auto(AutoFor::Ploc));
        assert_eq!(e.config.bounds, BoundsMode::Concise);
        assert_eq!(r.encoder_label(&e), "morton bounds=concise");
        let (_, e) = r
            .resolve_chain("aac", Some("morton"), None, &raw(&[("bits", "auto")]), c)
            .unwrap()
            .parts();
        assert_eq!(e.as_ref().unwrap().params["bits"], "auto:aac");
        let (_, e) = r
            .resolve_chain(
                "lbvh",
                Some("morton"),
                None,
                &raw(&[("bits", "10"), ("grid_bits", "9")]),
                c,
            )
            .unwrap()
            .parts();
        let e = e.unwrap();
        assert_eq!((e.config.bits, e.config.grid_bits), (Bits::Fixed(10), 9));
        assert_eq!(r.encoder_label(&e), "morton bits=10 grid_bits=9");
        assert_eq!(e.cell_frame, CellFrame::Lattice);
        let (_, t) = r
            .resolve_chain(
                "lbvh",
                Some("emc64-var"),
                None,
                &raw(&[("grid_bits", "9"), ("grid_frame", "tight")]),
                c,
            )
            .unwrap()
            .parts();
        let t = t.unwrap();
        assert_eq!(
            (t.cell_frame, r.encoder_label(&t).as_str()),
            (CellFrame::Tight, "emc64-var grid_bits=9 grid_frame=tight")
        );
        assert_eq!(
            crate::key::params_string(&t.params),
            "bounds=scene,grid_bits=9,grid_frame=tight"
        );
        let err = r
            .resolve_chain(
                "lbvh",
                Some("morton"),
                None,
                &raw(&[("grid_frame", "tight")]),
                c,
            )
            .unwrap_err();
        assert!(
            err.message().contains("grid_bits") && err.exit_code() == 2,
            "{err}"
        );
        // EMC encoders have no bits; their key does not depend on the builder.
        let (_, a) = r
            .resolve_chain("aac", Some("emc64-var"), None, &raw(&[]), c)
            .unwrap()
            .parts();
        let (_, p) = r
            .resolve_chain("ploc", Some("emc64-var"), None, &raw(&[]), c)
            .unwrap()
            .parts();
        assert_eq!(a.as_ref().unwrap().params, p.as_ref().unwrap().params);
        assert_eq!(a.unwrap().config, p.unwrap().config);
        // Top-down builders have no encoder.
        assert_eq!(
            r.resolve_chain("binned-sah", None, None, &raw(&[]), c)
                .unwrap()
                .encoder,
            None
        );
    }

    #[test]
    fn encoder_errors() {
        let r = Registry::standard();
        let c = CostParams::default();
        let e = r
            .resolve_chain("ploc", Some("emc64-var"), None, &raw(&[("bits", "10")]), c)
            .unwrap_err();
        assert!(
            e.message().contains("`bits`") && e.message().contains("bounds, grid_bits"),
            "{e}"
        );
        let e = r
            .resolve_chain("sweep-sah", Some("morton"), None, &raw(&[]), c)
            .unwrap_err();
        assert!(
            e.message().contains("top-down") && e.message().contains("lbvh, aac, ploc"),
            "{e}"
        );
        let e = r
            .resolve_chain("sweep-sah", None, None, &raw(&[("bounds", "scene")]), c)
            .unwrap_err();
        assert!(e.message().contains("encoder parameter"), "{e}");
        let e = r
            .resolve_chain("lbvh", Some("hilbert"), None, &raw(&[]), c)
            .unwrap_err();
        assert!(
            e.message().contains("emc64-sort") && e.exit_code() == 2,
            "{e}"
        );
        for (k, v) in [
            ("bits", "0"),
            ("bits", "22"),
            ("bits", "auto:ploc"),
            ("bounds", "box"),
            ("grid_bits", "7"),
        ] {
            let e = r
                .resolve_chain("aac", None, None, &raw(&[(k, v)]), c)
                .unwrap_err();
            assert!(
                e.message().contains(k) && e.exit_code() == 2,
                "{k}={v}: {e}"
            );
        }
    }

    #[test]
    fn ibo_schedule_and_spatial_median_frame() {
        let r = Registry::standard();
        let cost = CostParams::default();
        let bittner = r.resolve_optimizer("ibo", &raw(&[]), cost).unwrap();
        assert_eq!(bittner.params["schedule"], "bittner");
        assert_eq!(bittner.params["keep_best"], "true");
        assert_eq!(
            bittner.ibo_config().schedule,
            bvhlab_opt::ibo::Schedule::Bittner
        );
        assert_eq!(r.optimizer_label(&bittner), "ibo comb");
        // The thesis schedule returns the last tree unless keep_best is given.
        let thesis = r
            .resolve_optimizer("ibo", &raw(&[("schedule", "thesis")]), cost)
            .unwrap();
        assert_eq!(thesis.params["keep_best"], "false");
        // ... and counts k over all nodes (thesis 3.4.3) unless ibo_nodes is given.
        assert_eq!(thesis.params["ibo_nodes"], "all");
        assert!(thesis.ibo_config().frac_of_all);
        assert!(!bittner.ibo_config().frac_of_all);
        let inner = r
            .resolve_optimizer("ibo", &raw(&[("schedule", "thesis"), ("ibo_nodes", "inner")]), cost)
            .unwrap();
        assert!(!inner.ibo_config().frac_of_all);
        let cfg = thesis.ibo_config();
        assert_eq!(
            (cfg.schedule, cfg.keep_best),
            (bvhlab_opt::ibo::Schedule::Thesis, false)
        );
        assert_eq!(r.optimizer_label(&thesis), "ibo comb schedule=thesis");
        let best = r
            .resolve_optimizer(
                "ibo",
                &raw(&[("schedule", "thesis"), ("keep_best", "true")]),
                cost,
            )
            .unwrap();
        assert!(best.ibo_config().keep_best);
        assert_eq!(
            r.optimizer_label(&best),
            "ibo comb schedule=thesis keep_best=true"
        );
        assert!(r
            .resolve_optimizer("ibo", &raw(&[("schedule", "frantal")]), cost)
            .is_err());
        // The spatial median's frame: centroids by default, node on request, in the key.
        let c = r.resolve("spatial-median", &raw(&[]), cost).unwrap();
        assert_eq!(c.key_params()["frame"], "centroids");
        let n = r
            .resolve("spatial-median", &raw(&[("frame", "node")]), cost)
            .unwrap();
        assert_eq!(n.key_params()["frame"], "node");
        assert_eq!(r.label(&n), "spatial-median frame=node");
        assert!(r
            .resolve("sweep-sah", &raw(&[("frame", "node")]), cost)
            .is_err());
    }
}
