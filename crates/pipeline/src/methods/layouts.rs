//! Layouts (the layout stage: the final BVH, or the scene for octrees, in a memory layout of Kilian
//! 2021): every layout of `bvhlab_layout::METHODS` (the registration line of a layout is its entry
//! there, beside the dispatch it needs in that crate) plus the pipeline's `auto` search over them.
//! A spec is `NAME[:k=v,...]`; parameters keep their spelling (see [`Spelling::AsGiven`]).
use super::{find, Kind, Method, MethodInfo, MethodKind, ParamSpec, Params};
use crate::error::{Error, Result};
use crate::stages::{AutoSpec, LayoutRequest};
use bvhlab_layout::LayoutSpec;
use bvhlab_params::Spelling;
use std::collections::BTreeMap;

/// Checked, filled-in parameters of a layout (name, parameters) -> what the layout stage does.
pub type RequestFn = fn(&str, Params) -> std::result::Result<LayoutRequest, String>;

/// What the pipeline needs of a layout: the request its checked parameters make.
#[derive(Clone)]
pub struct LayoutMethod {
    pub request: RequestFn,
}

impl MethodKind for LayoutMethod {
    const WHAT: &'static str = "layout";
    /// Layout keys have held the values as written since the layout stage's first version.
    const SPELLING: Spelling = Spelling::AsGiven;
}

pub type LayoutInfo = MethodInfo<LayoutMethod>;

/// The standard layouts: `bvhlab_layout::METHODS`, then `auto`.
pub fn standard() -> Vec<LayoutInfo> {
    let fixed: RequestFn =
        |name, params| LayoutSpec::checked(name, params).map(LayoutRequest::Fixed);
    let mut v: Vec<LayoutInfo> = bvhlab_layout::METHODS
        .iter()
        .map(|m| MethodInfo::new(m, LayoutMethod { request: fixed }))
        .collect();
    v.push(MethodInfo::new(&AUTO, LayoutMethod { request: auto }));
    v
}

/// [`standard`], built once (`stages::parse_layout` runs for every chain).
pub fn standard_table() -> &'static [LayoutInfo] {
    static TABLE: std::sync::OnceLock<Vec<LayoutInfo>> = std::sync::OnceLock::new();
    TABLE.get_or_init(standard)
}

/// `auto`: the smallest layout within a slowdown against bvh2, per scene (`stages::auto_candidates`,
/// searched in `run.rs`). Its defaults are `stages::AUTO_*` (a test checks they agree).
pub const AUTO: Method = Method::new(
    "auto",
    "smallest total bytes within a trace-time slowdown against bvh2, picked per scene from a small \
     measured search (machine dependent)",
    "bvhlab, over Kilian 2021's layouts",
    &[
        ParamSpec {
            name: "max_slowdown",
            default: "1.25",
            kind: Kind::PositiveFloat,
            about: "largest accepted trace-time ratio against bvh2 of the same BVH (bvh2 always qualifies)",
            in_label: false,
        },
        ParamSpec {
            name: "rays",
            default: "20000",
            kind: Kind::UInt { min: 100, max: 10_000_000 },
            about: "random rays each candidate is timed on",
            in_label: false,
        },
        ParamSpec {
            name: "budget",
            default: "10",
            kind: Kind::PositiveFloat,
            about: "search time in multiples of one bvh2 trace of those rays; then it stops and says so",
            in_label: false,
        },
    ],
);

fn auto(_: &str, p: Params) -> std::result::Result<LayoutRequest, String> {
    // Checked by the table (finite, > 0, in range): the parses cannot fail.
    let f = |k: &str| p[k].parse::<f64>().map_err(|e| format!("{k}: {e}"));
    Ok(LayoutRequest::Auto(AutoSpec {
        max_slowdown: f("max_slowdown")?,
        rays: p["rays"].parse().map_err(|e| format!("rays: {e}"))?,
        budget: f("budget")?,
    }))
}

/// Parses `NAME[:k=v,k=v]` (`bvh2`, `qbvh_chunks:chunk_bytes=128,frame=parent,bits=6`,
/// `octree_1bit:chunk_bytes=16`, `auto:max_slowdown=1.3,rays=20000`) against `list`. Unknown
/// names (an old name names the new one), parameters and bad values are input errors; defaults
/// are filled in.
pub fn parse(list: &[LayoutInfo], spec: &str) -> Result<LayoutRequest> {
    let spec_t = spec.trim();
    let bad = |e: String| Error::input(format!("bad layout `{spec_t}`: {e}"));
    let (name, body) = match spec_t.split_once(':') {
        Some((n, b)) => (n.trim(), Some(b)),
        None => (spec_t, None),
    };
    let given = match body {
        Some(b) => split_kv(spec_t, b)?,
        None => BTreeMap::new(),
    };
    if let Some(e) = bvhlab_layout::renamed(name) {
        return Err(bad(e));
    }
    let info = find(list, name).map_err(|e| bad(e.message().to_string()))?;
    let params = info
        .resolve(&given, None)
        .map_err(|e| bad(e.message().to_string()))?;
    (info.request)(name, params).map_err(bad)
}

fn split_kv(spec: &str, body: &str) -> Result<BTreeMap<String, String>> {
    let mut out = BTreeMap::new();
    for kv in body.split(',') {
        let (k, v) = kv.split_once('=').ok_or_else(|| {
            Error::input(format!(
                "bad layout `{spec}`: `{kv}` is not KEY=VALUE (expected NAME[:k=v,k=v], e.g. qbvh_chunks:chunk_bytes=128,frame=parent)"
            ))
        })?;
        let (k, v) = (k.trim(), v.trim());
        if k.is_empty() || v.is_empty() {
            return Err(Error::input(format!(
                "bad layout `{spec}`: empty key or value in `{kv}`"
            )));
        }
        if out.insert(k.to_string(), v.to_string()).is_some() {
            return Err(Error::input(format!(
                "bad layout `{spec}`: `{k}` given twice"
            )));
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stages::{AUTO_BUDGET, AUTO_MAX_SLOWDOWN, AUTO_RAYS};

    #[test]
    fn auto_defaults_are_the_stage_constants() {
        let d = parse(&standard(), "auto").unwrap();
        assert_eq!(
            d,
            LayoutRequest::Auto(AutoSpec {
                max_slowdown: AUTO_MAX_SLOWDOWN,
                rays: AUTO_RAYS,
                budget: AUTO_BUDGET
            })
        );
    }
}
