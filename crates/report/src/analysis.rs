//! Derived tables of the report, as plain functions over result rows (no polars, no plotting):
//! method identity, flags (methods far worse than the best on a scene), scene-parameter sweeps
//! (generated scenes differing in one numeric parameter) and the Morton-precision drop analysis of
//! Riemersma 2024, section 3.2.4 (eq. 13 and 14).
use bvhlab_pipeline::stats::min_max;
use bvhlab_pipeline::ResultRow;
use std::collections::BTreeMap;

/// What identifies a method: the columns builder / build_params / encoder / encode_params /
/// compact, and for chains with an optimize stage also optimizer / optimize_params, never the
/// display label (which may change with the pipeline's wording).
pub fn method_key(r: &ResultRow) -> String {
    let mut k = format!(
        "{}|{}|{}|{}|{}",
        r.builder,
        r.build_params,
        r.encoder.as_deref().unwrap_or(""),
        r.encode_params.as_deref().unwrap_or(""),
        r.compact
    );
    if let Some(o) = &r.optimizer {
        k.push_str(&format!("|{o}|{}", r.optimize_params.as_deref().unwrap_or("")));
    }
    k
}

/// The whole construction time of a row: encode + build (+ optimize, which the pipeline adds to
/// `total_build_seconds`) (+ a separate compaction stage), so Morton builders are charged for their
/// codes and sort and optimizer chains for their passes (Bittner 2013's build_s). Falls back to build + encode seconds for rows
/// written before `total_build_seconds` existed (0 there).
/// Whether the construction times (encode, build, optimize, compact) of two rows may be compared
/// (a ratio of their build times): both were timed on one CPU model (`build_machine`; an
/// unrecorded model, "", matches any: caches from before issue 12).
pub fn same_build_machine(a: &ResultRow, b: &ResultRow) -> bool {
    let one = |r: &ResultRow| !r.build_machine.contains(" + ");
    one(a) && one(b) && (a.build_machine == b.build_machine || a.build_machine.is_empty() || b.build_machine.is_empty())
}

pub fn total_build_seconds(r: &ResultRow) -> f64 {
    let total = if r.total_build_seconds > 0.0 {
        r.total_build_seconds
    } else {
        r.build_seconds + r.encode_seconds.unwrap_or(0.0) + r.optimize_seconds.unwrap_or(0.0)
    };
    total + r.compact_seconds
}

/// Fastest and slowest whole construction over the timed runs: the sums of each stage's fastest
/// and slowest run (the stages' runs are not paired, so this bounds every combination). None when
/// a stage was timed once or rows predate the runs columns.
pub fn total_build_range(r: &ResultRow) -> Option<(f64, f64)> {
    let mut lo = 0.0;
    let mut hi = 0.0;
    let mut any = false;
    for (median, runs) in [
        (Some(r.build_seconds), &r.build_seconds_runs),
        (r.encode_seconds, &r.encode_seconds_runs),
        (r.optimize_seconds, &r.optimize_seconds_runs),
        (Some(r.compact_seconds), &r.compact_seconds_runs),
    ] {
        if median.filter(|m| *m > 0.0).is_none() {
            continue;
        }
        let runs = runs.as_ref().filter(|v| v.len() > 1)?;
        let (a, b) = min_max(runs.iter().copied());
        lo += a;
        hi += b;
        any = true;
    }
    any.then_some((lo, hi))
}

/// Timing spread above which a row's timing is called noisy on the first screen: the fastest
/// and slowest run differ by more than this fraction of the median.
pub const NOISY_SPREAD: f64 = 0.25;

/// (quantity, median, spread) of each timing of a row whose spread exceeds `NOISY_SPREAD`.
pub fn noisy_timings(r: &ResultRow) -> Vec<(&'static str, f64, f64)> {
    let mut out = Vec::new();
    for (name, median, spread) in [
        ("construction", Some(total_build_seconds(r)), r.total_build_seconds_spread),
        ("trace", r.trace_seconds, r.trace_seconds_spread),
        ("slowdown vs bvh2", r.slowdown, r.slowdown_spread),
    ] {
        if let (Some(m), Some(s)) = (median, spread) {
            if s > NOISY_SPREAD {
                out.push((name, m, s));
            }
        }
    }
    out
}

/// `k=v,k=v` -> map (pairs without `=` are ignored).
pub fn parse_params(s: &str) -> BTreeMap<String, String> {
    s.split(',')
        .filter_map(|kv| kv.split_once('='))
        .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()))
        .collect()
}

/// Encoder parameters at their defaults are left out of curve labels (the registry's defaults:
/// bounds=scene, grid_bits=0, grid_frame=cell; `bits=auto:<builder>` is the builder's own choice).
const ENCODER_DEFAULTS: &[(&str, &str)] = &[
    ("bounds", "scene"),
    ("grid_bits", "0"),
    ("grid_frame", "cell"),
];

/// Short label of a row's encoder variant: `morton bits=10 grid_bits=9`, `emc64-var`; `None` for
/// rows without an encode stage.
pub fn encoder_label(r: &ResultRow) -> Option<String> {
    let enc = r.encoder.as_deref()?;
    let mut parts = vec![enc.to_string()];
    for (k, v) in parse_params(r.encode_params.as_deref().unwrap_or("")) {
        if ENCODER_DEFAULTS.iter().any(|(dk, dv)| *dk == k && *dv == v) || v.starts_with("auto") {
            continue;
        }
        parts.push(format!("{k}={v}"));
    }
    Some(parts.join(" "))
}

/// Occupation-grid bits of a row's encoder (0 = off or no encoder).
pub fn grid_bits(r: &ResultRow) -> u32 {
    r.encode_params
        .as_deref()
        .map(parse_params)
        .and_then(|p| p.get("grid_bits").and_then(|v| v.parse().ok()))
        .unwrap_or(0)
}

/// Display labels per method key, in first-appearance order. The row's `method` label is used;
/// if two different keys share a label, the encoder and parameters are appended to tell them apart.
pub fn method_labels(rows: &[ResultRow]) -> Vec<(String, String)> {
    let mut out: Vec<(String, String)> = Vec::new();
    for r in rows {
        let k = method_key(r);
        if !out.iter().any(|(x, _)| *x == k) {
            out.push((k, r.method.clone()));
        }
    }
    let labels: Vec<String> = out.iter().map(|(_, l)| l.clone()).collect();
    for (k, l) in out.iter_mut() {
        if labels.iter().filter(|x| *x == l).count() > 1 {
            let parts: Vec<&str> = k.split('|').collect();
            *l = format!(
                "{l} [{}]",
                parts
                    .iter()
                    .filter(|p| !p.is_empty())
                    .cloned()
                    .collect::<Vec<_>>()
                    .join(" ")
            );
        }
    }
    out
}

/// A method on a scene is flagged when its cost is more than this many times the best method's.
pub const FLAG_RATIO: f64 = 1.5;

#[derive(Clone, Debug, PartialEq)]
pub struct Flag {
    pub scene_name: String,
    /// `focus_sah_cost` when the scene has a focus box, else `sah_cost`.
    pub metric: &'static str,
    pub method: String,
    pub value: f64,
    pub best: f64,
    pub best_method: String,
    /// value / best (NaN when the value is not finite).
    pub ratio: f64,
    pub valid: bool,
}

/// The value flags and the best-per-scene comparison use: the focus cost when the scene has one
/// (with a far outlier the whole-scene cost says little about the object), else the SAH cost.
fn flag_metric(scene_rows: &[&ResultRow]) -> (&'static str, fn(&ResultRow) -> Option<f64>) {
    if scene_rows
        .iter()
        .any(|r| r.focus_sah_cost.is_some_and(f64::is_finite))
    {
        ("focus_sah_cost", |r| r.focus_sah_cost)
    } else {
        ("sah_cost", |r| Some(r.sah_cost))
    }
}

/// Every (scene, method) whose cost exceeds `FLAG_RATIO` x the best valid method's cost on that
/// scene, plus every method whose cost is not a finite number. Scenes in row order, methods in row
/// order; rows repeated per ray set count once.
pub fn flags(rows: &[ResultRow]) -> Vec<Flag> {
    let labels: BTreeMap<String, String> = method_labels(rows).into_iter().collect();
    let mut out = Vec::new();
    for scene in unique_by(rows, |r| r.scene.clone()) {
        let scene_rows: Vec<&ResultRow> = rows.iter().filter(|r| r.scene == scene).collect();
        let mut seen = std::collections::HashSet::new();
        let chains: Vec<&ResultRow> = scene_rows
            .iter()
            .copied()
            .filter(|r| seen.insert(method_key(r)))
            .collect();
        let (metric, value) = flag_metric(&chains);
        let best = chains
            .iter()
            .filter(|r| r.valid)
            .filter_map(|r| {
                value(r)
                    .filter(|v| v.is_finite() && *v > 0.0)
                    .map(|v| (v, *r))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0));
        let Some((best, best_row)) = best else {
            continue;
        };
        for r in &chains {
            let Some(v) = value(r) else { continue };
            let ratio = if v.is_finite() { v / best } else { f64::NAN };
            if ratio > FLAG_RATIO || !v.is_finite() {
                out.push(Flag {
                    scene_name: r.scene_name.clone(),
                    metric,
                    method: labels[&method_key(r)].clone(),
                    value: v,
                    best,
                    best_method: labels[&method_key(best_row)].clone(),
                    ratio,
                    valid: r.valid,
                });
            }
        }
    }
    out
}

fn unique_by(rows: &[ResultRow], key: impl Fn(&ResultRow) -> String) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for r in rows {
        let k = key(r);
        if !out.contains(&k) {
            out.push(k);
        }
    }
    out
}

/// `gen:NAME[:k=v,...]` -> (NAME, params); `None` for file scenes.
pub fn parse_gen_spec(spec: &str) -> Option<(String, BTreeMap<String, String>)> {
    let rest = spec.strip_prefix("gen:")?;
    let (name, params) = rest.split_once(':').unwrap_or((rest, ""));
    Some((name.to_string(), parse_params(params)))
}

/// Generated scenes of one generator that differ only in one numeric parameter.
#[derive(Clone, Debug, PartialEq)]
pub struct Sweep {
    pub generator: String,
    pub param: String,
    /// The other parameters, `k=v,...` (as written, sorted by key).
    pub fixed: String,
    /// (parameter value, scene spec), sorted by value.
    pub points: Vec<(f64, String)>,
}

impl Sweep {
    pub fn title(&self) -> String {
        if self.fixed.is_empty() {
            format!("{} over {}", self.generator, self.param)
        } else {
            format!("{} ({}) over {}", self.generator, self.fixed, self.param)
        }
    }
}

/// A sweep needs at least this many distinct values to be plotted as one.
pub const MIN_SWEEP_POINTS: usize = 3;

/// Finds every sweep: for each generator and each parameter that is numeric in all its scenes,
/// the groups of scenes whose other parameters are equal (as written) with at least
/// `MIN_SWEEP_POINTS` distinct values. Generator order as the scenes appear; parameters sorted.
pub fn find_sweeps(rows: &[ResultRow]) -> Vec<Sweep> {
    let specs = unique_by(rows, |r| r.scene.clone());
    let parsed: Vec<(String, String, BTreeMap<String, String>)> = specs
        .iter()
        .filter_map(|s| parse_gen_spec(s).map(|(n, p)| (s.clone(), n, p)))
        .collect();
    let mut generators: Vec<&str> = Vec::new();
    for (_, n, _) in &parsed {
        if !generators.contains(&n.as_str()) {
            generators.push(n);
        }
    }
    let mut out = Vec::new();
    for g in generators {
        let scenes: Vec<&(String, String, BTreeMap<String, String>)> =
            parsed.iter().filter(|(_, n, _)| n == g).collect();
        let mut keys: Vec<&String> = scenes.iter().flat_map(|(_, _, p)| p.keys()).collect();
        keys.sort();
        keys.dedup();
        for k in keys {
            // Every scene of the group must have the parameter as a finite number.
            let mut groups: BTreeMap<String, Vec<(f64, String)>> = BTreeMap::new();
            for (spec, _, p) in &scenes {
                let Some(x) = p
                    .get(k)
                    .and_then(|v| v.parse::<f64>().ok())
                    .filter(|x| x.is_finite())
                else {
                    continue;
                };
                let fixed: Vec<String> = p
                    .iter()
                    .filter(|(pk, _)| *pk != k)
                    .map(|(pk, pv)| format!("{pk}={pv}"))
                    .collect();
                groups
                    .entry(fixed.join(","))
                    .or_default()
                    .push((x, spec.clone()));
            }
            for (fixed, mut points) in groups {
                points.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                points.dedup_by(|a, b| a.0 == b.0);
                if points.len() >= MIN_SWEEP_POINTS {
                    out.push(Sweep {
                        generator: g.to_string(),
                        param: k.clone(),
                        fixed,
                        points,
                    });
                }
            }
        }
    }
    out
}

/// One method's values over a sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    pub key: String,
    pub label: String,
    /// `builder build_params` (the panel the curve goes into).
    pub builder: String,
    /// `Some(encoder label)` for methods with an encode stage.
    pub encoder: Option<String>,
    pub grid_bits: u32,
    pub valid: bool,
    /// (parameter value, metric value), increasing parameter; scenes without a value are skipped.
    pub points: Vec<(f64, f64)>,
}

/// A value of a result row, measured on which rows (ray set): a sweep's metric, a paper table's.
pub struct RowMetric {
    /// What names it (a sweep metric's stem, a paper table's file).
    pub id: &'static str,
    pub label: &'static str,
    /// Only rows whose `rays_kind` starts with this.
    pub rays: Option<&'static str>,
    pub value: fn(&ResultRow) -> Option<f64>,
}

/// Whether `r` was measured with a ray set of kind `kind` (`rays_kind` starts with it; None: any row).
pub fn on_rays(r: &ResultRow, kind: Option<&str>) -> bool {
    kind.is_none_or(|k| r.rays_kind.as_deref().is_some_and(|rk| rk.starts_with(k)))
}

pub const SWEEP_METRICS: &[RowMetric] = &[
    RowMetric {
        id: "focus_sah_cost",
        label: "focus SAH cost (object subtree, normalized by the object's bounds)",
        rays: None,
        value: |r| r.focus_sah_cost,
    },
    RowMetric {
        id: "sah_cost",
        label: "SAH cost (whole scene)",
        rays: None,
        value: |r| Some(r.sah_cost),
    },
    RowMetric {
        id: "steps_primary",
        label: "traversal steps per primary ray",
        rays: Some("primary"),
        value: |r| r.traversal_steps_per_ray,
    },
    RowMetric {
        id: "duplicate_code_fraction",
        label: "fraction of duplicate codes",
        rays: None,
        value: |r| r.duplicate_code_fraction,
    },
];

/// `builder build_params` as a short panel title.
pub fn builder_label(r: &ResultRow) -> String {
    if r.build_params.is_empty() {
        r.builder.clone()
    } else {
        format!("{} {}", r.builder, r.build_params.replace(',', " "))
    }
}

/// The series of every method for `metric` over `sweep` (methods in row order; a method with no
/// value on any scene of the sweep is left out).
pub fn sweep_series(sweep: &Sweep, rows: &[ResultRow], metric: &RowMetric) -> Vec<Series> {
    let labels: BTreeMap<String, String> = method_labels(rows).into_iter().collect();
    let in_sweep: Vec<&ResultRow> = rows
        .iter()
        .filter(|r| sweep.points.iter().any(|(_, s)| *s == r.scene))
        .filter(|r| on_rays(r, metric.rays))
        .collect();
    let mut out: Vec<Series> = Vec::new();
    for r in &in_sweep {
        let key = method_key(r);
        if out.iter().any(|s| s.key == key) {
            continue;
        }
        let mut points = Vec::new();
        let mut valid = true;
        for (x, spec) in &sweep.points {
            // First row of this method on this scene (ray sets repeat the build metrics).
            if let Some(row) = in_sweep
                .iter()
                .find(|q| q.scene == *spec && method_key(q) == key)
            {
                valid &= row.valid;
                if let Some(y) = (metric.value)(row).filter(|y| y.is_finite()) {
                    points.push((*x, y));
                }
            }
        }
        if points.is_empty() {
            continue;
        }
        out.push(Series {
            label: labels[&key].clone(),
            key,
            builder: builder_label(r),
            encoder: encoder_label(r),
            grid_bits: grid_bits(r),
            valid,
            points,
        });
    }
    out
}

/// A value counts as a performance drop when it exceeds the value at the sweep's first (smallest)
/// parameter value by more than this fraction (10 %).
pub const DROP_THRESHOLD: f64 = 0.10;

/// First parameter value where `points` (sorted by x) exceeds `(1 + DROP_THRESHOLD)` x its first
/// value; `None` if it never does (or there are fewer than two points).
pub fn measured_drop(points: &[(f64, f64)]) -> Option<f64> {
    let &(_, y0) = points.first()?;
    points
        .iter()
        .skip(1)
        .find(|(_, y)| *y > y0 * (1.0 + DROP_THRESHOLD))
        .map(|p| p.0)
}

/// Riemersma eq. 13: an occupation grid of `f` cells delays the drop by `log2(f) / d` when the
/// scene bounds grow along `d` dimensions.
pub fn move_d(f: f64, d: f64) -> f64 {
    f.log2() / d
}

/// Riemersma eq. 14: the drop of a grid method, `e_drop + move_d(f)`, where `e_drop` is the drop
/// of the same code without the grid and `f = 2^grid_bits` cells.
pub fn predicted_drop(e_drop: f64, grid_bits: u32, d: f64) -> f64 {
    e_drop + move_d(2f64.powi(grid_bits as i32), d)
}

/// Sweeps for which the shift model applies: generator, parameter (the exponent e of the outlier
/// distance 2^e) and d, the number of dimensions the scene bounds grow in. gen:outlier moves its
/// triangle along (1,1,1), so the bounds grow along all three axes: d = 3.
pub const SHIFT_MODELS: &[(&str, &str, f64)] = &[("outlier", "e", 3.0)];

pub fn shift_model(sweep: &Sweep) -> Option<f64> {
    SHIFT_MODELS
        .iter()
        .find(|(g, p, _)| *g == sweep.generator && *p == sweep.param)
        .map(|m| m.2)
}

/// One method's drop: measured, and for grid methods the prediction from the same code without
/// the grid (`reference`).
#[derive(Clone, Debug, PartialEq)]
pub struct Drop {
    pub builder: String,
    pub method: String,
    pub grid_bits: u32,
    pub measured: Option<f64>,
    /// The same builder and encoder with grid_bits=0 (label), for grid methods.
    pub reference: Option<String>,
    pub reference_drop: Option<f64>,
    pub predicted: Option<f64>,
}

/// Method key with grid_bits set to 0 and the other grid parameters (`grid_frame`, which only
/// exists with a grid) removed: the grid method's reference code.
fn without_grid(key: &str) -> String {
    let mut parts: Vec<String> = key.split('|').map(str::to_string).collect();
    if parts.len() >= 5 {
        let p: Vec<String> = parts[3]
            .split(',')
            .filter(|kv| kv.starts_with("grid_bits=") || !kv.starts_with("grid_"))
            .map(|kv| {
                if kv.starts_with("grid_bits=") {
                    "grid_bits=0".to_string()
                } else {
                    kv.to_string()
                }
            })
            .collect();
        parts[3] = p.join(",");
    }
    parts.join("|")
}

/// Drop analysis of the series of one metric (the focus cost): every encoder method's measured
/// drop; grid methods also get `predicted_drop(reference drop, grid_bits, d)`.
pub fn drops(series: &[Series], d: f64) -> Vec<Drop> {
    series
        .iter()
        .filter(|s| s.encoder.is_some())
        .map(|s| {
            let measured = measured_drop(&s.points);
            let (reference, reference_drop, predicted) = if s.grid_bits > 0 {
                let rk = without_grid(&s.key);
                match series.iter().find(|r| r.key == rk) {
                    Some(r) => {
                        let rd = measured_drop(&r.points);
                        (
                            Some(r.label.clone()),
                            rd,
                            rd.map(|e| predicted_drop(e, s.grid_bits, d)),
                        )
                    }
                    None => (None, None, None),
                }
            } else {
                (None, None, None)
            };
            Drop {
                builder: s.builder.clone(),
                method: s.label.clone(),
                grid_bits: s.grid_bits,
                measured,
                reference,
                reference_drop,
                predicted,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gen_specs() {
        let (n, p) = parse_gen_spec("gen:outlier:n=20000,e=4").unwrap();
        assert_eq!(n, "outlier");
        assert_eq!(p["e"], "4");
        assert_eq!(p["n"], "20000");
        assert_eq!(parse_gen_spec("gen:city").unwrap().1.len(), 0);
        assert!(parse_gen_spec("../shared/scenes/x.obj.gz").is_none());
    }

    #[test]
    fn grid_reference_key() {
        assert_eq!(
            without_grid("ploc|radius=10|morton|bits=10,bounds=scene,grid_bits=9|none"),
            "ploc|radius=10|morton|bits=10,bounds=scene,grid_bits=0|none"
        );
        // grid_frame exists only with a grid (the registry drops it at grid_bits=0).
        assert_eq!(
            without_grid(
                "aac|delta=4,epsilon=0.2|emc64-var|bounds=scene,grid_bits=9,grid_frame=tight|none"
            ),
            "aac|delta=4,epsilon=0.2|emc64-var|bounds=scene,grid_bits=0|none"
        );
    }
}
