//! The method table: builders, encoders, optimizers and layouts, each registered with one line
//! (`builders.rs`, `encoders.rs`, `optimizers.rs`, `layouts.rs`) from the [`Method`] its algorithm
//! file declares (name, paper reference, typed parameters with defaults and ranges), plus what its
//! kind needs to run it (`K`: a builder's call, an encoder's scheme, ...). Lookup, parameter
//! validation and the `bvhlab methods` listing are written once, here, for all four kinds;
//! `crate::registry` resolves chains and labels on top of it.
pub mod builders;
pub mod encoders;
pub mod layouts;
pub mod optimizers;

use crate::error::{Error, Result};
pub use bvhlab_params::Spelling;
use bvhlab_params::{fill, names, unknown};
pub use bvhlab_params::{fmt_f32, FinishFn, Kind, LabelFn, Method, ParamSpec, Params, Read};
use std::fmt::Write;
use std::ops::{Deref, DerefMut};

/// A kind of method (builder, encoder, optimizer, layout): what it is called in errors and how
/// it spells parameter values in keys.
pub trait MethodKind {
    const WHAT: &'static str;
    const SPELLING: Spelling = Spelling::Canonical;
}

/// One registered method: its self-description and its kind's part `K`. Derefs to `K`, so a
/// kind's fields read as the method's own (`builder.run`, `encoder.scheme`).
#[derive(Clone)]
pub struct MethodInfo<K> {
    pub name: &'static str,
    /// Implementation version (`Method::version`): part of its stage's key from 2 on.
    pub version: u32,
    pub about: &'static str,
    pub reference: &'static str,
    pub params: Vec<ParamSpec>,
    pub finish: Option<FinishFn>,
    pub label: Option<LabelFn>,
    pub kind: K,
}

impl<K> MethodInfo<K> {
    pub fn new(m: &Method, kind: K) -> MethodInfo<K> {
        MethodInfo {
            name: m.name,
            version: m.version,
            about: m.about,
            reference: m.reference,
            params: m.params.to_vec(),
            finish: m.finish,
            label: m.label,
            kind,
        }
    }

    /// A method described in place (test doubles): no reference, finish rule or own label.
    pub fn custom(
        name: &'static str,
        about: &'static str,
        params: Vec<ParamSpec>,
        kind: K,
    ) -> MethodInfo<K> {
        MethodInfo {
            params,
            ..MethodInfo::new(&Method::new(name, about, "", &[]), kind)
        }
    }

    pub fn has(&self, param: &str) -> bool {
        self.params.iter().any(|p| p.name == param)
    }
}

impl<K: MethodKind> MethodInfo<K> {
    /// `given` checked against the parameters and in the kind's spelling: defaults filled in,
    /// the method's finish rule applied. `auto` is what an `auto` value resolves for.
    pub fn resolve(&self, given: &Params, auto: Option<&str>) -> Result<Params> {
        self.resolve_with(given, auto, &[], &|_| String::new())
    }

    /// [`Self::resolve`] also accepting the names of `extra` (validated by the caller); `hint`
    /// may add to the unknown-parameter error.
    pub fn resolve_with(
        &self,
        given: &Params,
        auto: Option<&str>,
        extra: &[ParamSpec],
        hint: &dyn Fn(&str) -> String,
    ) -> Result<Params> {
        let (what, name) = (K::WHAT, self.name);
        if let Some(k) = unknown(&[&self.params, extra], given) {
            let all: Vec<ParamSpec> = self.params.iter().chain(extra).cloned().collect();
            return Err(Error::input(format!(
                "unknown parameter `{k}` for {what} `{name}`; valid parameters: {}{}",
                names(&all),
                hint(k)
            )));
        }
        let mut params = fill(&self.params, given, auto, K::SPELLING).map_err(|e| {
            Error::input(format!(
                "bad value `{}` for `{}` of {what} `{name}`: expected {}",
                e.given, e.param, e.want
            ))
        })?;
        if let Some(finish) = self.finish {
            finish(given, &mut params)
                .map_err(|why| Error::input(format!("{what} `{name}`: {why}")))?;
        }
        Ok(params)
    }

    /// `bvhlab methods`: the method, then a line per parameter with its default.
    fn describe(&self, out: &mut String, note: &str) {
        let _ = writeln!(out, "  {}  {}{note}", self.name, self.about);
        for p in &self.params {
            let _ = match p.about {
                "" => writeln!(out, "    {}=[{}]", p.name, p.default),
                about => writeln!(out, "    {}=[{}]  {about}", p.name, p.default),
            };
        }
    }
}

impl<K> Deref for MethodInfo<K> {
    type Target = K;
    fn deref(&self) -> &K {
        &self.kind
    }
}

impl<K> DerefMut for MethodInfo<K> {
    fn deref_mut(&mut self) -> &mut K {
        &mut self.kind
    }
}

/// The method called `name`; an input error listing the valid ones otherwise.
pub fn find<'a, K: MethodKind>(list: &'a [MethodInfo<K>], name: &str) -> Result<&'a MethodInfo<K>> {
    list.iter().find(|m| m.name == name).ok_or_else(|| {
        Error::input(format!(
            "unknown {0} `{name}`; valid {0}s: {1}",
            K::WHAT,
            names_of(list).join(", ")
        ))
    })
}

pub fn names_of<K>(list: &[MethodInfo<K>]) -> Vec<&'static str> {
    list.iter().map(|m| m.name).collect()
}

/// Whether any method of `list` has a parameter `param`.
pub fn any_has<K>(list: &[MethodInfo<K>], param: &str) -> bool {
    list.iter().any(|m| m.has(param))
}

/// A heading, then every method of `list` (`note` adds to a method's line).
pub fn describe<K: MethodKind>(
    out: &mut String,
    heading: &str,
    list: &[MethodInfo<K>],
    note: impl Fn(&MethodInfo<K>) -> &'static str,
) {
    let _ = writeln!(out, "{heading}");
    for m in list {
        m.describe(out, note(m));
    }
}

#[cfg(test)]
mod tests {
    use crate::registry::Registry;

    /// Every method of the table names its paper, and every default is a valid value.
    #[test]
    fn every_method_has_a_reference_and_valid_defaults() {
        let r = Registry::standard();
        let all: Vec<(&str, &str, &Vec<super::ParamSpec>)> = r
            .builders
            .iter()
            .map(|m| (m.name, m.reference, &m.params))
            .chain(r.encoders.iter().map(|m| (m.name, m.reference, &m.params)))
            .chain(
                r.optimizers
                    .iter()
                    .map(|m| (m.name, m.reference, &m.params)),
            )
            .chain(r.layouts.iter().map(|m| (m.name, m.reference, &m.params)))
            .collect();
        // builders: 9 of bvhlab (with sbvh) + 4 peers; encoders; optimizers; layouts (with bvh4,
        // bvh8, cwbvh) + auto.
        assert_eq!(all.len(), 9 + 4 + 3 + 3 + 8);
        for (name, reference, params) in all {
            assert!(!reference.is_empty(), "{name}");
            for p in params.iter() {
                assert!(
                    bvhlab_params::canonical(p, p.default, Some("aac")).is_ok(),
                    "{name}: default of {}",
                    p.name
                );
            }
        }
    }

    /// The defaults the methods declare are the defaults of their config structs.
    #[test]
    fn declared_defaults_are_the_config_defaults() {
        use bvhlab_builders::{aac::AacConfig, incremental::IncConfig, TopDownConfig};
        use bvhlab_bvh::{metrics::COST_PARAMS, CostParams};
        use bvhlab_layout::{octree, qbvh_chunks, LayoutSpec};
        use bvhlab_opt::{ibo::IboConfig, kensler::KenslerConfig};
        let (r, c, none) = (
            Registry::standard(),
            CostParams::default(),
            super::Params::new(),
        );
        let cost: Vec<f32> = COST_PARAMS
            .iter()
            .map(|p| p.default.parse().unwrap())
            .collect();
        assert_eq!(cost, [c.c_t, c.c_i]);
        let sweep = r.resolve("sweep-sah", &none, c).unwrap();
        assert_eq!(sweep.config(), TopDownConfig::default());
        let inc = r.resolve("incremental", &none, c).unwrap();
        assert_eq!(IncConfig::from_params(&inc.params, c), IncConfig::default());
        assert_eq!(
            r.resolve("aac", &none, c).unwrap().aac_config(),
            AacConfig::HQ
        );
        let ibo = r.resolve_optimizer("ibo", &none, c).unwrap();
        assert_eq!(ibo.ibo_config(), IboConfig::default());
        // Hill climbing has no temperature parameters.
        let hc = r.resolve_optimizer("kensler-hc", &none, c).unwrap();
        let d = KenslerConfig::default();
        assert_eq!(
            hc.kensler_config(false),
            KenslerConfig {
                t0: 0.0,
                cooling: 0.0,
                ..d
            }
        );
        let layout = |name| LayoutSpec::parse(name, &none).unwrap();
        assert_eq!(
            octree::Config::from_spec(&layout("octree")),
            Ok(octree::Config::default())
        );
        let q = qbvh_chunks::Config::from_spec(&layout("qbvh_chunks"));
        assert_eq!(q, Ok(qbvh_chunks::Config::default()));
    }
}
