//! The results table (collapsed, sortable, filterable), the methods used with their papers, the
//! invalid-chains box and the flags table.
use super::section;
use crate::analysis::{method_key, Flag};
use crate::plots::fmt_num;
use bvhlab_pipeline::{Registry, ResultRow};
use maud::{html, Markup};

fn opt(v: Option<f64>) -> String {
    v.map(fmt_num).unwrap_or_default()
}

/// A sortable table (click a header) with a filter box above it (rows containing the text).
pub fn sortable(id: &str, head: &[&str], rows: impl Iterator<Item = (bool, Vec<(bool, String)>)>) -> Markup {
    html! {
        input.filter type="search" placeholder="filter rows (text anywhere in the row)" data-table=(id);
        div.wide { table.sortable id=(id) {
            thead { tr { @for c in head { th { (c) } } } }
            tbody {
                @for (valid, cells) in rows {
                    tr class=[(!valid).then_some("invalid")] {
                        @for (num, c) in cells { @if num { td.n { (c) } } @else { td { (c) } } }
                    }
                }
            }
        } }
    }
}

pub fn results(rows: &[ResultRow]) -> Markup {
    let head = [
        "scene", "method", "rays", "triangles", "dropped", "SAH cost", "focus SAH", "built SAH", "optimized SAH",
        "encode s", "build s", "optimize s", "passes", "compact s", "total build s", "build spread", "build heap B/tri", "dup codes", "inner SA",
        "leaf SA", "refs/leaf", "leaves", "depth", "bytes/tri", "steps/ray", "isects/ray", "Mrays/s", "trace spread", "valid",
    ];
    let body = html! {
        @if rows.is_empty() {
            p { "No results." }
        } @else {
            p {
                "Selected columns; every column is in results.csv / results.parquet. Times are medians in \
                 seconds. Build heap: the build stage's peak heap growth per triangle (working arrays and \
                 the BVH; not the scene, its boxes and centres, nor the Morton codes; empty for peer \
                 libraries, which allocate outside Rust). Rows failing structural validation are red. \
                 Click a header to sort."
            }
            (sortable("results-table", &head, rows.iter().map(|r| {
                let t = |s: &str| (false, s.to_string());
                let n = |s: String| (true, s);
                (r.valid, vec![
                    t(&r.scene_name),
                    t(&r.method),
                    t(r.rays_kind.as_deref().unwrap_or("")),
                    n(r.triangles.to_string()),
                    n(r.dropped_triangles.to_string()),
                    n(fmt_num(r.sah_cost)),
                    n(opt(r.focus_sah_cost)),
                    n(opt(r.build_sah_cost)),
                    n(opt(r.optimized_sah_cost)),
                    n(opt(r.encode_seconds)),
                    n(fmt_num(r.build_seconds)),
                    n(opt(r.optimize_seconds)),
                    n(r.optimize_passes.map(|p| p.to_string()).unwrap_or_default()),
                    n(fmt_num(r.compact_seconds)),
                    n(fmt_num(crate::analysis::total_build_seconds(r))),
                    n(r.total_build_seconds_spread.map(|s| format!("{:.0} %", s * 100.0)).unwrap_or_default()),
                    n(r.build_heap_bytes_per_triangle.map(|b| format!("{b:.0}")).unwrap_or_default()),
                    n(opt(r.duplicate_code_fraction)),
                    n(fmt_num(r.inner_sa_ratio)),
                    n(fmt_num(r.leaf_sa_ratio)),
                    n(fmt_num(r.refs_per_leaf)),
                    n(r.leaves.to_string()),
                    n(r.depth.to_string()),
                    n(fmt_num(r.bytes_per_triangle)),
                    n(opt(r.traversal_steps_per_ray)),
                    n(opt(r.intersections_per_ray)),
                    n(opt(r.mrays_per_s)),
                    n(r.trace_seconds_spread.map(|s| format!("{:.0} %", s * 100.0)).unwrap_or_default()),
                    t(if r.valid { "yes" } else { "NO" }),
                ])
            })))
        }
    };
    section("results", &format!("Results table ({} rows)", rows.len()), false, body)
}

/// The methods the rows use, each with the paper it follows, from the pipeline's method table.
pub fn methods(rows: &[ResultRow]) -> Markup {
    let used = |kind: &str, name: &str| {
        rows.iter().any(|r| match kind {
            "builder" => r.builder == name,
            "encoder" => r.encoder.as_deref() == Some(name),
            "optimizer" => r.optimizer.as_deref() == Some(name),
            _ => r.layout.as_deref() == Some(name),
        })
    };
    let list: Vec<[&str; 4]> =
        Registry::standard().catalogue().into_iter().filter(|[kind, name, ..]| used(kind, name)).collect();
    let body = html! {
        p { "Every method these results use (" code { "bvhlab methods" } " lists all, with their parameters)." }
        table {
            tr { th { "kind" } th { "method" } th { "paper" } th { "what it does" } }
            @for [kind, name, reference, about] in &list {
                tr { td { (kind) } td { (name) } td { (reference) } td { (about) } }
            }
        }
    };
    section("methods", &format!("Methods ({})", list.len()), false, body)
}

/// Invalid chains: (first row, number of rows) per scene and method key, in row order.
pub fn invalid_chains(rows: &[ResultRow]) -> Vec<(&ResultRow, usize)> {
    let mut out: Vec<(&ResultRow, usize)> = Vec::new();
    for r in rows.iter().filter(|r| !r.valid) {
        match out.iter_mut().find(|(q, _)| q.scene == r.scene && method_key(q) == method_key(r)) {
            Some((_, n)) => *n += 1,
            None => out.push((r, 1)),
        }
    }
    out
}

/// A red box at the top of the page: every chain whose BVH failed structural validation. Their
/// numbers are not trustworthy; they stay in every table (red rows) so nothing is hidden.
pub fn invalid_box(invalid: &[(&ResultRow, usize)]) -> Markup {
    if invalid.is_empty() {
        return html! {};
    }
    html! {
        div.invalid-box {
            h2 id="invalid" {
                (invalid.len()) " invalid result" @if invalid.len() != 1 { "s" } ": BVH failed validation"
            }
            p {
                "These chains produced a BVH that fails structural validation (every triangle exactly once, \
                 children inside parents, leaves around their triangles). Their costs, times and ray counts \
                 are not trustworthy; they are red in every table below."
            }
            table {
                tr { th{"scene"} th{"method"} th{"builder"} th{"build params"} th{"encoder"} th{"encode params"} th{"compact"} th{"rows"} th{"reason"} }
                @for (r, n) in invalid {
                    tr.invalid {
                        td { (r.scene_name) } td { (r.method) } td { (r.builder) } td { (r.build_params) }
                        td { (r.encoder.as_deref().unwrap_or("")) } td { (r.encode_params.as_deref().unwrap_or("")) }
                        td { (r.compact) } td.n { (n) } td { (r.invalid_reason.as_deref().unwrap_or("")) }
                    }
                }
            }
        }
    }
}

/// The flags table (see `analysis::flags`); invalid chains red.
pub fn flags_table(flags: &[Flag]) -> Markup {
    if flags.is_empty() {
        return html! { p.ok { "No method is flagged." } };
    }
    html! {
        table {
            tr { th{"scene"} th{"metric"} th{"method"} th{"value"} th{"best"} th{"best method"} th{"ratio"} th{"valid"} }
            @for f in flags {
                tr class=[(!f.valid).then_some("invalid")] {
                    td { (f.scene_name) } td { (f.metric) } td { (f.method) } td.n { (fmt_num(f.value)) }
                    td.n { (fmt_num(f.best)) } td { (f.best_method) }
                    td.n { @if f.ratio.is_finite() { (fmt_num(f.ratio)) "x" } @else { "n/a" } }
                    td { @if f.valid { "yes" } @else { "NO" } }
                }
            }
        }
    }
}

/// Rows with a noisy timing, one per (scene, method, ray set).
pub fn noisy_rows(rows: &[ResultRow]) -> Vec<(&ResultRow, Vec<(&'static str, f64, f64)>)> {
    rows.iter()
        .map(|r| (r, crate::analysis::noisy_timings(r)))
        .filter(|(_, n)| !n.is_empty())
        .collect()
}

pub fn noise_table(rows: &[ResultRow]) -> Markup {
    let noisy = noisy_rows(rows);
    if noisy.is_empty() {
        return html! { p.ok { "No timing spread above the threshold." } };
    }
    let head = ["scene", "method", "rays", "quantity", "median", "spread"];
    sortable(
        "noise-table",
        &head,
        noisy.iter().flat_map(|(r, n)| {
            n.iter().map(move |(q, m, s)| {
                (
                    r.valid,
                    vec![
                        (false, r.scene_name.clone()),
                        (false, r.method.clone()),
                        (false, r.rays_kind.clone().unwrap_or_default()),
                        (false, q.to_string()),
                        (true, fmt_num(*m)),
                        (true, format!("{:.0} %", s * 100.0)),
                    ],
                )
            })
        }),
    )
}
