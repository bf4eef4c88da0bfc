//! The peers as they describe themselves in bvhlab's method table (crates/params), and their
//! configurations from canonical parameters. The library and its version are part of each
//! method's parameters (`library`), hence of every cache key downstream.
use bvhlab_params::{fmt_f32, Kind, Method, ParamSpec, Params};

const LIBRARY: ParamSpec = ParamSpec {
    name: "library",
    default: "embree-3.13.5",
    kind: Kind::Choice(&["embree-3.13.5"]),
    about: "the library and version (part of the cache key; the only value is the linked one)",
    in_label: false,
};

const MAX_LEAF: ParamSpec = ParamSpec {
    name: "max_leaf",
    default: "32",
    kind: Kind::UInt { min: 1, max: 32 },
    about: "Embree's maxLeafSize (leaves up to this many triangles, sizes chosen by Embree's SAH; 32 as \
            ../shared/tools/embree-anchor)",
    in_label: false,
};

const THREADS: ParamSpec = ParamSpec {
    name: "threads",
    default: "1",
    kind: Kind::UInt { min: 1, max: 256 },
    about: "Embree device threads (its own task system; 1 as the anchor's single-thread figures)",
    in_label: false,
};

const EMBREE_PARAMS: &[ParamSpec] = &[MAX_LEAF, THREADS, LIBRARY];

pub const EMBREE_MORTON: Method = Method::new(
    "embree-morton",
    "Embree 3 rtcBuildBVH, RTC_BUILD_QUALITY_LOW (Morton codes), imported",
    "Embree 3.13 (Wald et al. 2014); peer",
    EMBREE_PARAMS,
);

pub const EMBREE_BINNED: Method = Method::new(
    "embree-binned",
    "Embree 3 rtcBuildBVH, RTC_BUILD_QUALITY_MEDIUM (binned SAH), imported",
    "Embree 3.13 (Wald et al. 2014); peer",
    EMBREE_PARAMS,
);

pub const EMBREE_SBVH: Method = Method::new(
    "embree-sbvh",
    "Embree 3 rtcBuildBVH, RTC_BUILD_QUALITY_HIGH with spatial splits (triangles clipped), imported; \
     references may repeat a triangle",
    "Embree 3.13; Stich et al. 2009; peer",
    EMBREE_PARAMS,
)
// 2: a triangle's fragments in one leaf are imported as one reference.
.with_version(2);

const OBVHS_LIBRARY: ParamSpec = ParamSpec {
    name: "library",
    default: "obvhs-0.4.0",
    kind: Kind::Choice(&["obvhs-0.4.0"]),
    about: "the library and version (part of the cache key; the pinned one)",
    in_label: false,
};

/// obvhs' `BvhBuildParams` fields as the crate names them; defaults are its `medium_build()`, and
/// `preset` fills every field not given (see [`obvhs_finish`]).
const OBVHS_PARAMS: &[ParamSpec] = &[
    ParamSpec {
        name: "preset",
        default: "medium",
        kind: Kind::Choice(crate::obvhs_ploc::PRESETS),
        about: "obvhs BvhBuildParams preset (fastest_build .. very_slow_build); fills the fields not given",
        in_label: true,
    },
    ParamSpec {
        name: "ploc_search_distance",
        default: "14",
        kind: Kind::Choice(&["1", "2", "6", "14", "24", "32"]),
        about: "PLOC search radius (PlocSearchDistance)",
        in_label: false,
    },
    ParamSpec {
        name: "search_depth_threshold",
        default: "3",
        kind: Kind::UInt { min: 0, max: 64 },
        about: "below this depth PLOC searches with radius 1",
        in_label: false,
    },
    ParamSpec {
        name: "reinsertion_batch_ratio",
        default: "0.05",
        kind: Kind::NonNegativeFloat,
        about: "share of nodes considered for reinsertion (0: no reinsertion optimizer)",
        in_label: false,
    },
    ParamSpec {
        name: "post_collapse_reinsertion_batch_ratio_multiplier",
        default: "2",
        kind: Kind::NonNegativeFloat,
        about: "second reinsertion pass after the leaf collapse, relative to the first",
        in_label: false,
    },
    ParamSpec {
        name: "sort_precision",
        default: "64",
        kind: Kind::Choice(&["64", "128"]),
        about: "Morton code bits of PLOC's radix sort",
        in_label: false,
    },
    ParamSpec {
        name: "max_prims_per_leaf",
        default: "8",
        kind: Kind::UInt { min: 1, max: 255 },
        about: "leaf collapse: at most this many triangles per leaf",
        in_label: false,
    },
    ParamSpec {
        name: "collapse_traversal_cost",
        default: "3",
        kind: Kind::PositiveFloat,
        about: "leaf collapse: traversal cost relative to a triangle test",
        in_label: false,
    },
    OBVHS_LIBRARY,
];

pub const OBVHS: Method = Method::new(
    "obvhs",
    "obvhs 0.4 build_bvh2: PLOC (Meister and Bittner 2018), reinsertion (Meister and Bittner 2022), leaf \
     collapse; from boxes (no pre-splits), imported",
    "obvhs 0.4 (DGriffin91); peer",
    OBVHS_PARAMS,
)
.with_finish(obvhs_finish)
.with_label(obvhs_label);

/// `preset` fills every field not given; given fields override it (e.g. `reinsertion_batch_ratio=0`
/// for PLOC without the reinsertion optimizer).
fn obvhs_finish(given: &Params, params: &mut Params) -> Result<(), String> {
    let name = params
        .get("preset")
        .cloned()
        .unwrap_or_else(|| "medium".into());
    let p =
        crate::obvhs_ploc::preset(&name).ok_or_else(|| format!("unknown obvhs preset `{name}`"))?;
    let values = [
        (
            "ploc_search_distance",
            crate::obvhs_ploc::search_radius(p.ploc_search_distance).to_string(),
        ),
        (
            "search_depth_threshold",
            p.search_depth_threshold.to_string(),
        ),
        (
            "reinsertion_batch_ratio",
            fmt_f32(p.reinsertion_batch_ratio),
        ),
        (
            "post_collapse_reinsertion_batch_ratio_multiplier",
            fmt_f32(p.post_collapse_reinsertion_batch_ratio_multiplier),
        ),
        (
            "sort_precision",
            crate::obvhs_ploc::sort_bits(p.sort_precision).to_string(),
        ),
        ("max_prims_per_leaf", p.max_prims_per_leaf.to_string()),
        (
            "collapse_traversal_cost",
            fmt_f32(p.collapse_traversal_cost),
        ),
    ];
    for (k, v) in values {
        if !given.contains_key(k) {
            params.insert(k.to_string(), v);
        }
    }
    Ok(())
}

/// `obvhs medium`, plus the fields that differ from the preset.
fn obvhs_label(params: &Params) -> String {
    let name = params.get("preset").map(String::as_str).unwrap_or("medium");
    let mut preset_params = Params::new();
    preset_params.insert("preset".into(), name.into());
    let _ = obvhs_finish(&Params::new(), &mut preset_params);
    let mut out = format!("obvhs {name}");
    for (k, v) in params {
        if k != "preset" && k != "library" && preset_params.get(k) != Some(v) {
            out.push_str(&format!(" {k}={v}"));
        }
    }
    out
}

/// obvhs' parameters from canonical ones (finish already applied).
pub fn obvhs_params(p: &Params) -> Result<obvhs::BvhBuildParams, String> {
    let get = |k: &str| {
        p.get(k)
            .map(String::as_str)
            .ok_or_else(|| format!("obvhs: `{k}` missing"))
    };
    let f = |k: &str| -> Result<f32, String> {
        get(k)?.parse().map_err(|_| format!("obvhs: bad `{k}`"))
    };
    let u = |k: &str| -> Result<u32, String> {
        get(k)?.parse().map_err(|_| format!("obvhs: bad `{k}`"))
    };
    let mut b = crate::obvhs_ploc::preset(get("preset")?).ok_or("obvhs: bad preset")?;
    b.pre_split = false;
    b.ploc_search_distance = crate::obvhs_ploc::search_distance(u("ploc_search_distance")?)
        .ok_or("obvhs: bad ploc_search_distance")?;
    b.search_depth_threshold = u("search_depth_threshold")? as usize;
    b.reinsertion_batch_ratio = f("reinsertion_batch_ratio")?;
    b.post_collapse_reinsertion_batch_ratio_multiplier =
        f("post_collapse_reinsertion_batch_ratio_multiplier")?;
    b.sort_precision = if u("sort_precision")? == 128 {
        obvhs::ploc::SortPrecision::U128
    } else {
        obvhs::ploc::SortPrecision::U64
    };
    b.max_prims_per_leaf = u("max_prims_per_leaf")?;
    b.collapse_traversal_cost = f("collapse_traversal_cost")?;
    Ok(b)
}
