//! Layout rows grouped into cases (scene, chain, ray set): points and their labels, the plot
//! metrics, Pareto fronts and layout families.
use crate::analysis::{method_key, parse_params};
use crate::plots::pareto::pareto_front;
use bvhlab_pipeline::stats::min_max;
use bvhlab_pipeline::ResultRow;
use std::collections::BTreeMap;

/// One layout configuration measured on one case.
#[derive(Clone, Debug)]
pub struct Point<'a> {
    pub layout: String,
    pub params: BTreeMap<String, String>,
    /// Short label: layout name and the parameters that vary in the experiment (`qbvh_chunks 64B frame=parent`).
    pub label: String,
    pub row: &'a ResultRow,
}

/// The layout rows of one (scene, chain, ray set).
#[derive(Clone, Debug)]
pub struct Case<'a> {
    /// Display name: the scene, plus chain and ray set where the experiment has several.
    pub label: String,
    pub scene_name: String,
    pub rays_kind: Option<String>,
    pub chain: String,
    /// One point per layout configuration (first row wins), `auto` rows excluded.
    pub points: Vec<Point<'a>>,
    /// `layout=auto` rows of this case.
    pub auto: Vec<&'a ResultRow>,
}

fn is_auto(r: &ResultRow) -> bool {
    r.layout_choice.is_some() || r.layout.as_deref() == Some("auto")
}

/// Display order of parameter keys in labels.
const KEY_ORDER: [&str; 4] = ["chunk_bytes", "frame", "bits", "fill"];

fn key_rank(k: &str) -> usize {
    KEY_ORDER.iter().position(|x| *x == k).unwrap_or(KEY_ORDER.len())
}

pub(super) fn short(k: &str, v: &str) -> String {
    match k {
        "chunk_bytes" => format!("{v}B"),
        "bits" => format!("{v}bit"),
        "fill" => v.to_string(),
        _ => format!("{k}={v}"),
    }
}

/// Label of a configuration: the name and the given keys, in KEY_ORDER.
pub(super) fn label_of(layout: &str, params: &BTreeMap<String, String>, keys: &[String]) -> String {
    let mut ks: Vec<&String> = keys.iter().filter(|k| params.contains_key(*k)).collect();
    ks.sort_by_key(|k| (key_rank(k), (*k).clone()));
    let mut s = layout.to_string();
    for k in ks {
        s.push(' ');
        s.push_str(&short(k, &params[k]));
    }
    s
}

/// Per layout name, the parameter keys whose values differ among that layout's rows.
fn varying_keys(rows: &[&ResultRow]) -> BTreeMap<String, Vec<String>> {
    let mut seen: BTreeMap<String, BTreeMap<String, Vec<String>>> = BTreeMap::new();
    for r in rows {
        let Some(l) = r.layout.as_deref() else { continue };
        let m = seen.entry(l.to_string()).or_default();
        let p = parse_params(r.layout_params.as_deref().unwrap_or(""));
        for (k, v) in &p {
            let vs = m.entry(k.clone()).or_default();
            if !vs.contains(v) {
                vs.push(v.clone());
            }
        }
    }
    // A key some rows lack also varies (a missing key is its default, unknown here).
    let mut out = BTreeMap::new();
    for (l, m) in seen {
        let n_rows = rows.iter().filter(|r| r.layout.as_deref() == Some(l.as_str())).count();
        let keys = m
            .into_iter()
            .filter(|(k, vs)| {
                vs.len() > 1
                    || rows
                        .iter()
                        .filter(|r| r.layout.as_deref() == Some(l.as_str()))
                        .filter(|r| parse_params(r.layout_params.as_deref().unwrap_or("")).contains_key(k))
                        .count()
                        < n_rows
            })
            .map(|(k, _)| k)
            .collect();
        out.insert(l, keys);
    }
    out
}

/// Groups every row with a layout into cases, in first-appearance order.
pub fn cases(rows: &[ResultRow]) -> Vec<Case<'_>> {
    let lrows: Vec<&ResultRow> = rows.iter().filter(|r| r.layout.is_some()).collect();
    let varying = varying_keys(&lrows.iter().copied().filter(|r| !is_auto(r)).collect::<Vec<_>>());
    let chains: Vec<String> = uniq(lrows.iter().map(|r| method_key(r)));
    let kinds: Vec<Option<String>> = uniq(lrows.iter().map(|r| r.rays_kind.clone()));
    let mut out: Vec<Case> = Vec::new();
    for r in &lrows {
        let chain = method_key(r);
        let idx = match out
            .iter()
            .position(|c| c.scene_name == r.scene_name && c.chain == chain && c.rays_kind == r.rays_kind)
        {
            Some(i) => i,
            None => {
                let mut label = r.scene_name.clone();
                if chains.len() > 1 {
                    label.push_str(&format!(" · {} {}", r.builder, r.build_params));
                    if r.compact != "none" {
                        label.push_str(&format!(" +{}", r.compact));
                    }
                }
                if kinds.len() > 1 {
                    label.push_str(&format!(" · {}", r.rays_kind.as_deref().unwrap_or("no rays")));
                }
                out.push(Case {
                    label,
                    scene_name: r.scene_name.clone(),
                    rays_kind: r.rays_kind.clone(),
                    chain,
                    points: Vec::new(),
                    auto: Vec::new(),
                });
                out.len() - 1
            }
        };
        let case = &mut out[idx];
        if is_auto(r) {
            case.auto.push(r);
            continue;
        }
        let layout = r.layout.clone().unwrap_or_default();
        let params = parse_params(r.layout_params.as_deref().unwrap_or(""));
        if case.points.iter().any(|p| p.layout == layout && p.params == params) {
            continue;
        }
        let keys = varying.get(&layout).cloned().unwrap_or_default();
        case.points.push(Point { label: label_of(&layout, &params, &keys), layout, params, row: r });
    }
    out
}

fn uniq<T: PartialEq>(it: impl Iterator<Item = T>) -> Vec<T> {
    let mut v = Vec::new();
    for x in it {
        if !v.contains(&x) {
            v.push(x);
        }
    }
    v
}

/// What a plot axis shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Metric {
    TopologyBytesPerTriangle,
    TotalBytesPerTriangle,
    TraceSeconds,
    Slowdown,
    ExtraTestsPerRay,
    ExtraBoxHitsPerRay,
}

impl Metric {
    pub fn of(self, r: &ResultRow) -> Option<f64> {
        let v = match self {
            Metric::TopologyBytesPerTriangle => r.topology_bytes_per_triangle,
            Metric::TotalBytesPerTriangle => r.total_bytes_per_triangle,
            Metric::TraceSeconds => r.trace_seconds,
            Metric::Slowdown => r.slowdown,
            Metric::ExtraTestsPerRay => r.extra_tests_per_ray,
            Metric::ExtraBoxHitsPerRay => r.extra_box_hits_per_ray,
        };
        v.filter(|x| x.is_finite())
    }

    /// Fastest and slowest run of a timed metric (an error bar); None for counts and bytes.
    pub fn range(self, r: &ResultRow) -> Option<(f64, f64)> {
        let runs = match self {
            Metric::TraceSeconds => r.trace_seconds_runs.as_ref(),
            Metric::Slowdown => r.slowdown_runs.as_ref(),
            _ => None,
        }?;
        let (lo, hi) = min_max(runs.iter().copied().filter(|v| v.is_finite()));
        (runs.len() > 1 && lo.is_finite() && hi.is_finite()).then_some((lo, hi))
    }

    pub fn desc(self) -> &'static str {
        match self {
            Metric::TopologyBytesPerTriangle => "topology bytes / triangle",
            Metric::TotalBytesPerTriangle => "total bytes / triangle",
            Metric::TraceSeconds => "trace time [s]",
            Metric::Slowdown => "slowdown vs bvh2",
            Metric::ExtraTestsPerRay => "extra triangle tests / ray",
            Metric::ExtraBoxHitsPerRay => "extra box hits / ray",
        }
    }
}

/// Labels of the case's points on the Pareto front of (x, y), both minimized, in increasing x.
pub fn front(case: &Case, x: Metric, y: Metric) -> Vec<String> {
    let pts: Vec<(f64, f64)> = case
        .points
        .iter()
        .map(|p| (x.of(p.row).unwrap_or(f64::NAN), y.of(p.row).unwrap_or(f64::NAN)))
        .collect();
    pareto_front(&pts).into_iter().map(|i| case.points[i].label.clone()).collect()
}

/// A family curve: one layout with all parameters fixed but one (`sweep`), or a single point.
#[derive(Clone, Debug)]
pub struct Family {
    pub label: String,
    /// Indices into `case.points`, ordered by the swept parameter.
    pub members: Vec<usize>,
}

fn num_or_str(v: &str) -> (f64, String) {
    (v.parse::<f64>().unwrap_or(f64::INFINITY), v.to_string())
}

/// Curves of a case: per layout, for each parameter (chunk_bytes first), the groups of points that
/// differ only in it (two or more points); points in no such group are single-point families.
pub fn families(case: &Case) -> Vec<Family> {
    let mut out = Vec::new();
    let layouts = uniq(case.points.iter().map(|p| p.layout.clone()));
    for l in &layouts {
        let idx: Vec<usize> = (0..case.points.len()).filter(|&i| case.points[i].layout == *l).collect();
        let mut keys: Vec<String> = uniq(idx.iter().flat_map(|&i| case.points[i].params.keys().cloned()));
        keys.sort_by_key(|k| (key_rank(k), k.clone()));
        let mut covered = vec![false; case.points.len()];
        for k in &keys {
            let mut groups: Vec<(BTreeMap<String, String>, Vec<usize>)> = Vec::new();
            for &i in &idx {
                let mut rest = case.points[i].params.clone();
                if rest.remove(k).is_none() {
                    continue;
                }
                match groups.iter_mut().find(|g| g.0 == rest) {
                    Some(g) => g.1.push(i),
                    None => groups.push((rest, vec![i])),
                }
            }
            for (rest, mut members) in groups {
                if members.len() < 2 {
                    continue;
                }
                members.sort_by(|&a, &b| {
                    let (x, y) = (num_or_str(&case.points[a].params[k]), num_or_str(&case.points[b].params[k]));
                    x.0.total_cmp(&y.0).then(x.1.cmp(&y.1))
                });
                for &m in &members {
                    covered[m] = true;
                }
                // Label: the fixed parameters that vary elsewhere, then the swept one.
                let shown: Vec<String> = rest
                    .keys()
                    .filter(|rk| {
                        idx.iter().any(|&i| case.points[i].params.get(*rk) != rest.get(*rk))
                    })
                    .cloned()
                    .collect();
                let base = label_of(l, &rest, &shown);
                let swept = if k == "chunk_bytes" { "chunk size".to_string() } else { k.clone() };
                out.push(Family { label: format!("{base} (by {swept})"), members });
            }
        }
        for &i in &idx {
            if !covered[i] {
                out.push(Family { label: case.points[i].label.clone(), members: vec![i] });
            }
        }
    }
    out
}
