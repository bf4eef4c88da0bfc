//! Builder names -> function + parameter schema (defaults, validation). Cost constants c_t / c_i
//! are parameters of every builder: they drive the SAH leaf-vs-split test (thesis 2.3.1), the
//! compaction and the metrics (thesis eq. 4), so they are part of the build key.
use crate::error::{Error, Result};
use bvhlab_bvh::{Aabb, Bvh, CostParams, Vec3};
use bvhlab_build::TopDownConfig;
use std::collections::BTreeMap;

#[derive(Clone, Copy, Debug)]
pub enum Kind {
    /// Integer in `min..=max`.
    UInt { min: u32, max: u32 },
    /// Finite float > 0.
    PositiveFloat,
    /// One of a fixed set of words.
    Choice(&'static [&'static str]),
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

impl Resolved {
    pub fn u32(&self, name: &str) -> u32 {
        self.params.get(name).and_then(|v| v.parse().ok()).unwrap_or(0)
    }
    pub fn config(&self) -> TopDownConfig {
        TopDownConfig { leaf: self.u32("leaf"), cost: self.cost }
    }
    /// Builder parameters plus `c_t`, `c_i`: what keys the build stage.
    pub fn key_params(&self) -> BTreeMap<String, String> {
        let mut p = self.params.clone();
        p.insert("c_t".into(), fmt_f32(self.cost.c_t));
        p.insert("c_i".into(), fmt_f32(self.cost.c_i));
        p
    }
}

impl Registry {
    /// Display label: `binned-sah bins=16`, plus parameters changed from their defaults.
    pub fn label(&self, r: &Resolved) -> String {
        let mut parts = vec![r.builder.clone()];
        if let Ok(info) = self.get(&r.builder) {
            for spec in &info.params {
                let v = r.params.get(spec.name).cloned().unwrap_or_default();
                if spec.in_label || v != spec.default {
                    parts.push(format!("{}={v}", spec.name));
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
}

pub type BuildFn = fn(&[Aabb], &[Vec3], &Resolved) -> Bvh;

#[derive(Clone)]
pub struct BuilderInfo {
    pub name: &'static str,
    pub about: &'static str,
    pub params: Vec<ParamSpec>,
    pub run: BuildFn,
}

pub const COST_PARAMS: [ParamSpec; 2] = [
    ParamSpec { name: "c_t", default: "3", kind: Kind::PositiveFloat, about: "SAH traversal cost c_T (thesis 2.2.2)", in_label: false },
    ParamSpec { name: "c_i", default: "2", kind: Kind::PositiveFloat, about: "SAH intersection cost c_I (thesis 2.2.2)", in_label: false },
];

const LEAF: ParamSpec = ParamSpec {
    name: "leaf",
    default: "2",
    kind: Kind::UInt { min: 1, max: 1 << 16 },
    about: "primitive threshold: nodes with at most this many triangles become leaves (thesis 2.3.1)",
    in_label: false,
};

/// Shortest round-trip form, so `3`, `3.0` and `3.00` share a key.
pub fn fmt_f32(v: f32) -> String {
    format!("{v}")
}

fn canonical(spec: &ParamSpec, value: &str) -> Result<String, String> {
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
        Kind::Choice(words) => match words.iter().find(|w| **w == v) {
            Some(w) => Ok(w.to_string()),
            None => Err(format!("one of {}", words.join(", "))),
        },
    }
}

#[derive(Clone)]
pub struct Registry {
    pub builders: Vec<BuilderInfo>,
}

impl Default for Registry {
    fn default() -> Self {
        Self::standard()
    }
}

impl Registry {
    pub fn standard() -> Registry {
        Registry {
            builders: vec![
                BuilderInfo {
                    name: "spatial-median",
                    about: "split the largest axis at its middle (Kay and Kajiya 1986; thesis 3.2)",
                    params: vec![LEAF],
                    run: |b, c, r| bvhlab_build::spatial_median::build(b, c, &r.config()),
                },
                BuilderInfo {
                    name: "sweep-sah",
                    about: "full-sweep SAH over all three axes (thesis 3.3.1)",
                    params: vec![LEAF],
                    run: |b, c, r| bvhlab_build::sweep_sah::build(b, c, &r.config()),
                },
                BuilderInfo {
                    name: "binned-sah",
                    about: "binned SAH (Wald 2007; thesis 3.1.1)",
                    params: vec![
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
                            about: "stop when the centroid extent is < 1e-7 along the split axis (default) or along any \
                                    axis (the thesis' literal rule, 3.1.1; reproduces its BIN column)",
                            in_label: false,
                        },
                    ],
                    run: |b, c, r| {
                        use bvhlab_build::binned_sah::{build_with_termination, CentroidTermination};
                        let stop = match r.params.get("centroid_stop").map(String::as_str) {
                            Some("any-axis") => CentroidTermination::AnyAxis,
                            _ => CentroidTermination::SplitAxis,
                        };
                        build_with_termination(b, c, r.u32("bins"), &r.config(), stop)
                    },
                },
            ],
        }
    }

    pub fn names(&self) -> Vec<&'static str> {
        self.builders.iter().map(|b| b.name).collect()
    }

    pub fn get(&self, name: &str) -> Result<&BuilderInfo> {
        self.builders.iter().find(|b| b.name == name).ok_or_else(|| {
            Error::input(format!("unknown builder `{name}`; valid builders: {}", self.names().join(", ")))
        })
    }

    /// Validates `raw` (user-given `name -> value`) against the builder's schema plus the cost
    /// parameters; missing ones take their defaults (`cost` for c_t / c_i).
    pub fn resolve(&self, builder: &str, raw: &BTreeMap<String, String>, cost: CostParams) -> Result<Resolved> {
        let info = self.get(builder)?;
        let valid = || {
            info.params.iter().chain(COST_PARAMS.iter()).map(|p| p.name).collect::<Vec<_>>().join(", ")
        };
        for k in raw.keys() {
            if !info.params.iter().chain(COST_PARAMS.iter()).any(|p| p.name == k) {
                return Err(Error::input(format!(
                    "unknown parameter `{k}` for builder `{builder}`; valid parameters: {}",
                    valid()
                )));
            }
        }
        let mut params = BTreeMap::new();
        for spec in &info.params {
            let given = raw.get(spec.name).map(String::as_str).unwrap_or(spec.default);
            let v = canonical(spec, given).map_err(|want| {
                Error::input(format!("bad value `{given}` for `{}` of `{builder}`: expected {want}", spec.name))
            })?;
            params.insert(spec.name.to_string(), v);
        }
        let mut cost_v = [cost.c_t, cost.c_i];
        for (i, spec) in COST_PARAMS.iter().enumerate() {
            if let Some(given) = raw.get(spec.name) {
                let v = canonical(spec, given)
                    .map_err(|want| Error::input(format!("bad value `{given}` for `{}`: expected {want}", spec.name)))?;
                cost_v[i] = v.parse().unwrap_or(cost_v[i]);
            }
        }
        Ok(Resolved { builder: builder.to_string(), params, cost: CostParams { c_t: cost_v[0], c_i: cost_v[1] } })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn raw(kv: &[(&str, &str)]) -> BTreeMap<String, String> {
        kv.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect()
    }

    #[test]
    fn defaults_and_explicit_defaults_agree() {
        let r = Registry::standard();
        let a = r.resolve("binned-sah", &raw(&[]), CostParams::default()).unwrap();
        let b = r.resolve("binned-sah", &raw(&[("bins", "16"), ("c_t", "3.0"), ("leaf", "02")]), CostParams::default()).unwrap();
        assert_eq!(a, b);
        assert_eq!(a.key_params(), b.key_params());
        assert_eq!(crate::key::params_string(&a.params), "bins=16,centroid_stop=split-axis,leaf=2");
    }

    #[test]
    fn errors_list_valid_choices() {
        let r = Registry::standard();
        let e = r.resolve("nope", &raw(&[]), CostParams::default()).unwrap_err();
        assert!(e.message().contains("binned-sah") && e.exit_code() == 2, "{e}");
        let e = r.resolve("sweep-sah", &raw(&[("bins", "4")]), CostParams::default()).unwrap_err();
        assert!(e.message().contains("leaf, c_t, c_i"), "{e}");
        let e = r.resolve("binned-sah", &raw(&[("bins", "x")]), CostParams::default()).unwrap_err();
        assert!(e.message().contains("bins"), "{e}");
        assert!(r.resolve("binned-sah", &raw(&[("c_i", "-1")]), CostParams::default()).is_err());
        assert!(r.resolve("binned-sah", &raw(&[("c_i", "inf")]), CostParams::default()).is_err());
    }

    #[test]
    fn cost_overrides() {
        let r = Registry::standard();
        let a = r.resolve("spatial-median", &raw(&[("c_t", "1.5")]), CostParams { c_t: 9.0, c_i: 7.0 }).unwrap();
        assert_eq!(a.cost, CostParams { c_t: 1.5, c_i: 7.0 });
    }
}
