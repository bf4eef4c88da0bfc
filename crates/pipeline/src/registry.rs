//! Chains over the method table ([`crate::methods`]): a builder (with its encoder, for builders
//! over codes) and an optional optimizer resolved to canonical parameters, and their labels. Cost
//! constants c_t / c_i are parameters of every builder: they drive the SAH leaf-vs-split test
//! (thesis 2.3.1), the compaction and the metrics (thesis eq. 4), so they are part of the build key.
//!
//! Bottom-up builders (lbvh, aac, ploc) take primitives sorted by code from the encode stage; their
//! chains name an encoder (default `morton`). Parameters of a chain are routed by name: a name the
//! builder has goes to the builder, a name the encoder has goes to the encoder (the two schemas share
//! no names), anything else is an input error listing both.
use crate::error::{Error, Result};
pub use crate::methods::builders::{BuildFn, Builder, BuilderInfo};
pub use crate::methods::encoders::{Encoder, EncoderInfo};
pub use crate::methods::layouts::{LayoutInfo, LayoutMethod};
pub use crate::methods::optimizers::{OptimizeFn, Optimizer, OptimizerInfo};
use crate::methods::{self, any_has, find, names_of, Read};
pub use crate::methods::{fmt_f32, FinishFn, Kind, LabelFn, Method, MethodInfo, ParamSpec, Params};
use crate::stages::LayoutRequest;
use bvhlab_builders::aac::AacConfig;
use bvhlab_builders::TopDownConfig;
pub use bvhlab_bvh::metrics::COST_PARAMS;
use bvhlab_bvh::CostParams;
use bvhlab_morton::{AutoFor, CellFrame, EncodeConfig};
use bvhlab_params::{canonical, names};
use std::collections::BTreeMap;
use std::fmt::Write;
use std::str::FromStr;

/// Parameters resolved against a schema: canonical strings (defaults included) plus typed cost.
#[derive(Clone, Debug, PartialEq)]
pub struct Resolved {
    pub builder: String,
    /// Builder-specific parameters only (e.g. `bins`, `leaf`), canonical.
    pub params: BTreeMap<String, String>,
    pub cost: CostParams,
}

impl Resolved {
    /// A canonical parameter parsed as `T` (see [`Read::typed`]).
    pub fn get<T: FromStr + Default>(&self, name: &str) -> T {
        self.params.typed(name)
    }
    pub fn u32(&self, name: &str) -> u32 {
        self.get(name)
    }
    pub fn f32(&self, name: &str) -> f32 {
        self.get(name)
    }
    pub fn flag(&self, name: &str) -> bool {
        self.get(name)
    }
    pub fn config(&self) -> TopDownConfig {
        TopDownConfig {
            leaf: self.get("leaf"),
            cost: self.cost,
        }
    }
    pub fn aac_config(&self) -> AacConfig {
        AacConfig::from_params(&self.params)
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
        self.params.typed(name)
    }
    pub fn f64(&self, name: &str) -> f64 {
        self.params.typed(name)
    }
    pub fn flag(&self, name: &str) -> bool {
        self.params.typed(name)
    }
    /// `max_seconds > 0`: the result may depend on machine speed.
    pub fn time_capped(&self) -> bool {
        self.f64("max_seconds") > 0.0
    }
    pub fn ibo_config(&self) -> bvhlab_opt::ibo::IboConfig {
        bvhlab_opt::ibo::IboConfig::from_params(&self.params, self.cost)
    }
    pub fn kensler_config(&self, anneal: bool) -> bvhlab_opt::kensler::KenslerConfig {
        bvhlab_opt::kensler::KenslerConfig::from_params(&self.params, self.cost, anneal)
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

/// The method table: every builder, encoder, optimizer and layout.
#[derive(Clone)]
pub struct Registry {
    pub builders: Vec<BuilderInfo>,
    pub encoders: Vec<EncoderInfo>,
    pub optimizers: Vec<OptimizerInfo>,
    pub layouts: Vec<LayoutInfo>,
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
            layouts: Self::standard_layouts(),
        }
    }
    pub fn standard_builders() -> Vec<BuilderInfo> {
        methods::builders::standard()
    }
    pub fn standard_encoders() -> Vec<EncoderInfo> {
        methods::encoders::standard()
    }
    pub fn standard_optimizers() -> Vec<OptimizerInfo> {
        methods::optimizers::standard()
    }
    pub fn standard_layouts() -> Vec<LayoutInfo> {
        methods::layouts::standard()
    }

    pub fn names(&self) -> Vec<&'static str> {
        names_of(&self.builders)
    }
    pub fn encoder_names(&self) -> Vec<&'static str> {
        names_of(&self.encoders)
    }
    pub fn optimizer_names(&self) -> Vec<&'static str> {
        names_of(&self.optimizers)
    }

    pub fn get(&self, name: &str) -> Result<&BuilderInfo> {
        find(&self.builders, name)
    }
    pub fn encoder(&self, name: &str) -> Result<&EncoderInfo> {
        find(&self.encoders, name)
    }
    pub fn optimizer(&self, name: &str) -> Result<&OptimizerInfo> {
        find(&self.optimizers, name)
    }
    pub fn layout(&self, name: &str) -> Result<&LayoutInfo> {
        find(&self.layouts, name)
    }

    fn code_builder_names(&self) -> String {
        let names: Vec<_> = self
            .builders
            .iter()
            .filter(|b| b.codes.is_some())
            .map(|b| b.name)
            .collect();
        names.join(", ")
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
        if let Some(Err(how)) = info.peer.map(|p| p.available()) {
            return Err(Error::input(format!("builder `{builder}`: {how}")));
        }
        let hint = |k: &str| {
            if info.codes.is_none() && any_has(&self.encoders, k) {
                format!(
                    " (`{k}` is an encoder parameter; `{builder}` is top-down and takes no codes)"
                )
            } else {
                String::new()
            }
        };
        let params = info.resolve_with(raw, None, &COST_PARAMS, &hint)?;
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
        let params = info.resolve(raw, Some(auto.name()))?;
        Ok(ResolvedEncoder {
            encoder: encoder.to_string(),
            config: EncodeConfig::from_params(info.scheme, &params, auto),
            cell_frame: CellFrame::from_params(&params),
            params,
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
        let params = info.resolve(raw, None)?;
        Ok(ResolvedOptimizer {
            optimizer: name.to_string(),
            params,
            cost,
        })
    }

    /// A layout spec `NAME[:k=v,...]` checked against the layout table (see
    /// [`methods::layouts::parse`]).
    pub fn parse_layout(&self, spec: &str) -> Result<LayoutRequest> {
        methods::layouts::parse(&self.layouts, spec)
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
            if info.has(k) || COST_PARAMS.iter().any(|p| p.name == k) {
                braw.insert(k.clone(), v.clone());
            } else if einfo.is_some_and(|e| e.has(k)) {
                eraw.insert(k.clone(), v.clone());
            } else if oinfo.is_some_and(|o| o.has(k)) {
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
                if einfo.is_none() && any_has(&self.encoders, k) {
                    msg.push_str(&format!(" (`{k}` is an encoder parameter; `{builder}` is top-down and takes no codes)"));
                } else if oinfo.is_none() && any_has(&self.optimizers, k) {
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

    /// Display label: `binned-sah bins=16`, plus parameters changed from their defaults.
    pub fn label(&self, r: &Resolved) -> String {
        let mut parts = vec![r.builder.clone()];
        if let Ok(info) = self.get(&r.builder) {
            match info.label {
                Some(f) => parts = vec![f(&r.params)],
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

    /// Optimizer label: `ibo comb`, plus parameters changed from their defaults.
    pub fn optimizer_label(&self, o: &ResolvedOptimizer) -> String {
        let mut parts = vec![o.optimizer.clone()];
        // The thesis schedule returns the last tree and counts all nodes unless told otherwise
        // (ibo's finish rule).
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

    /// Every method of the table as `[kind, name, paper reference, about]`, in table order.
    pub fn catalogue(&self) -> Vec<[&'static str; 4]> {
        fn rows<K: methods::MethodKind>(
            list: &[MethodInfo<K>],
        ) -> impl Iterator<Item = [&'static str; 4]> + '_ {
            list.iter().map(|m| [K::WHAT, m.name, m.reference, m.about])
        }
        let all = rows(&self.builders)
            .chain(rows(&self.encoders))
            .chain(rows(&self.optimizers));
        all.chain(rows(&self.layouts)).collect()
    }

    /// `bvhlab methods`: every method of the table with its parameters and defaults.
    pub fn describe(&self) -> String {
        let mut out = String::new();
        let codes = |b: &BuilderInfo| {
            if b.codes.is_some() {
                "  (takes codes: --encode)"
            } else {
                ""
            }
        };
        methods::describe(&mut out, "builders:", &self.builders, codes);
        let [c_t, c_i] = &COST_PARAMS;
        let _ = writeln!(
            out,
            "  every builder also takes {}=[{}] and {}=[{}] (SAH costs, thesis 2.2.2)",
            c_t.name, c_t.default, c_i.name, c_i.default
        );
        methods::describe(
            &mut out,
            "encoders (for builders that take codes):",
            &self.encoders,
            |_| "",
        );
        let heading = "optimizers (--optimize; run after the build, before the compaction):";
        methods::describe(&mut out, heading, &self.optimizers, |_| "");
        let heading = "layouts (--layout NAME[:k=v,...]; the final BVH in memory, traced by --rays beside bvh2):";
        methods::describe(&mut out, heading, &self.layouts, |_| "");
        out
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn raw(kv: &[(&str, &str)]) -> BTreeMap<String, String> {
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
            "axes=largest,bins=16,centroid_stop=split-axis,leaf=2"
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
}
