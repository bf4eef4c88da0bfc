//! The tables of the layouts section (computations in `crate::layouts`): Kilian's claims checked
//! per case, memory and chunks, speed and accuracy, and the layout=auto choices.
use crate::layouts::{kilian_bits_per_node, kilian_fill, over_within_noise, Case, Finding, Verdict, TIE_PERCENT};
use crate::plots::fmt_num;
use bvhlab_pipeline::ResultRow;
use maud::{html, Markup};
use std::collections::BTreeMap;

fn num(v: Option<f64>) -> String {
    v.filter(|x| x.is_finite()).map(fmt_num).unwrap_or_default()
}

fn pct(v: Option<f64>) -> String {
    v.filter(|x| x.is_finite()).map(|f| format!("{:.1}%", f * 100.0)).unwrap_or_default()
}

/// All tables of the section, in page order.
pub fn tables(findings: &[Finding], cs: &[Case]) -> Markup {
    html! {
        (findings_table(findings))
        (memory_table(cs))
        (speed_table(cs))
        (auto_table(cs))
    }
}

fn findings_table(fs: &[Finding]) -> Markup {
    html! {
        h3 { "Findings: Kilian's claims on our data" }
        p {
            "Each claim checked per scene (and chain / ray set) from the rows of this experiment; times compare \
             slowdowns against bvh2 timed alternately in the same run (else trace seconds). A time verdict needs \
             the difference to exceed the measured noise: |a/b \u{2212} 1| > max(spread" sub { "a" } " + spread"
            sub { "b" } ", " (TIE_PERCENT) "%), spread = (max \u{2212} min) / median over the runs (a stated limit \
             has none); else \"within noise\" (also for a single run: noise not measured). \"tie\": exactly equal \
             sizes or counts. \"not applicable\": a degenerate case (no triangles, or a structure of fewer than \
             two nodes). Kilian's numbers are only those he states in the text (section given); ours are beside \
             them."
        }
        table {
            tr {
                th { "#" } th { "claim" } th { "Kilian (stated)" } th { "agrees" } th { "differs" }
                th { "within noise" } th { "tie" } th { "not applicable" } th { "differing cases (our numbers)" }
            }
            @for f in fs {
                @let n = |v: Verdict| f.cases.iter().filter(|c| c.verdict == v).count();
                tr {
                    td { (f.id) }
                    td { (f.claim) }
                    td { (f.kilian) }
                    td.n { (n(Verdict::Agrees)) }
                    td.n { span class=[(n(Verdict::Differs) > 0).then_some("warn")] { (n(Verdict::Differs)) } }
                    td.n { (n(Verdict::WithinNoise)) }
                    td.n { (n(Verdict::Tie)) }
                    td.n { (n(Verdict::NotApplicable)) }
                    td {
                        @if f.cases.is_empty() {
                            "no data for this claim"
                        } @else {
                            @for (i, c) in f.cases.iter().filter(|c| c.verdict == Verdict::Differs).enumerate() {
                                @if i > 0 { br; }
                                (c.case) ": " (c.numbers)
                            }
                        }
                    }
                }
            }
        }
        h4 { "Per case" }
        table {
            tr { th { "#" } th { "case" } th { "verdict" } th { "our numbers" } }
            @for f in fs {
                @for c in &f.cases {
                    tr {
                        td { (f.id) }
                        td { (c.case) }
                        td { span class=[(c.verdict == Verdict::Differs).then_some("warn")] { (c.verdict.word()) } }
                        td { (c.numbers) }
                    }
                }
            }
        }
    }
}

fn memory_table(cs: &[Case]) -> Markup {
    let mut seen: Vec<(&str, &str, &str, &BTreeMap<String, String>)> = Vec::new();
    let mut points = Vec::new();
    for c in cs {
        for p in &c.points {
            let key = (c.scene_name.as_str(), c.chain.as_str(), p.layout.as_str(), &p.params);
            if !seen.contains(&key) {
                seen.push(key);
                points.push((c, p));
            }
        }
    }
    html! {
        h3 { "Memory and chunks (Kilian fig. 4.16, 5.4, 6.3, 6.5)" }
        p {
            "Topology = what traversal reads at every step (nodes; chunks + node info), total adds the leaf arrays \
             (Kilian 6.2). Bits/node = topology bits / layout nodes; Kilian's values are his best cases (every \
             chunk full). Chunk fill = mean used slots / slots. Prim mult. = primitive references / triangles \
             (octrees repeat primitives, fig. 6.5). Peak build = heap growth while building the layout."
        }
        table {
            tr {
                th { "scene" } th { "layout" } th { "params" } th { "topology B/tri" } th { "total B/tri" }
                th { "bits/node" } th { "Kilian (stated) bits/node" } th { "nodes" } th { "chunks" }
                th { "chunk fill" } th { "Kilian (stated) fill" } th { "prim mult." } th { "peak build MB" }
                th { "layout s" }
            }
            @for (c, p) in points {
                @let r = p.row;
                @let chunked = r.chunks.is_some_and(|n| n > 0);
                tr {
                    td { (c.scene_name) }
                    td { (p.layout) }
                    td { (r.layout_params.as_deref().unwrap_or("")) }
                    td.n { (num(r.topology_bytes_per_triangle)) }
                    td.n { (num(r.total_bytes_per_triangle)) }
                    td.n { (num(r.topology_bits_per_node)) }
                    td {
                        @if let Some((v, s)) = kilian_bits_per_node(&p.layout, &p.params) { (fmt_num(v)) " (" (s) ")" }
                    }
                    td.n { @if let Some(n) = r.layout_nodes { (n) } }
                    td.n { @if let Some(n) = r.chunks.filter(|&n| n > 0) { (n) } }
                    td.n { @if chunked { (pct(r.chunk_fill)) } }
                    td { @if chunked { (kilian_fill(&p.layout).unwrap_or("")) } }
                    td.n { (num(r.prim_refs.filter(|_| r.triangles > 0).map(|n| n as f64 / r.triangles as f64))) }
                    td.n { (num(r.peak_build_bytes.map(|b| b as f64 / 1e6))) }
                    td.n { (num(r.layout_seconds)) }
                }
            }
        }
    }
}

fn speed_table(cs: &[Case]) -> Markup {
    html! {
        h3 { "Speed and accuracy" }
        p {
            "Trace s = median seconds of the ray set with the layout's own traversal; bvh2 s = the same rays \
             through bvh2 of the same BVH, timed alternately in the same run; slowdown = their ratio (layout bvh2 \
             is its own anchor: 1 exactly); spreads = (max \u{2212} min) / median over the runs (the slowdown's over \
             the per-run ratios of the alternated pairs). Extra box hits / tests per ray: against the uncompressed \
             structure of the same topology (qbvh_chunks vs bvh2, octree_1bit vs octree). Layout SAH = SAH cost \
             with the boxes the traversal tests (quantized / implicit octant boxes); BVH SAH = the exact SAH cost \
             of the chain's BVH."
        }
        table {
            tr {
                th { "case" } th { "layout" } th { "trace s" } th { "trace spread" } th { "bvh2 s" } th { "slowdown" }
                th { "slowdown spread" } th { "steps/ray" } th { "tests/ray" } th { "extra box hits/ray" }
                th { "extra tests/ray" } th { "layout SAH" } th { "BVH SAH" } th { "ratio" }
            }
            @for c in cs {
                @for p in &c.points {
                    @let r = p.row;
                    tr {
                        td { (c.label) }
                        td { (p.label) }
                        td.n { (num(r.trace_seconds)) }
                        td.n { (pct(r.trace_seconds_spread)) }
                        td.n { (num(r.bvh2_trace_seconds)) }
                        td.n { (num(r.slowdown)) }
                        td.n { (pct(r.slowdown_spread)) }
                        td.n { (num(r.traversal_steps_per_ray)) }
                        td.n { (num(r.intersections_per_ray)) }
                        td.n { (num(r.extra_box_hits_per_ray)) }
                        td.n { (num(r.extra_tests_per_ray)) }
                        td.n { (num(r.layout_sah_cost)) }
                        td.n { (num(Some(r.sah_cost))) }
                        td.n { (num(r.layout_sah_cost.filter(|_| r.sah_cost > 0.0).map(|l| l / r.sah_cost))) }
                    }
                }
            }
        }
    }
}

fn auto_table(cs: &[Case]) -> Markup {
    let autos: Vec<(&Case, &ResultRow)> = cs.iter().flat_map(|c| c.auto.iter().map(move |r| (c, *r))).collect();
    if autos.is_empty() {
        return html! {};
    }
    // Issue 15: choices above their limit went unflagged; they are listed before the table.
    let over: Vec<&(&Case, &ResultRow)> = autos.iter().filter(|(_, r)| r.auto_over_limit == Some(true)).collect();
    let cut = autos.iter().filter(|(_, r)| r.auto_budget_cut == Some(true)).count();
    html! {
        h3 { "layout=auto: the choice per scene" }
        p {
            "The smallest layout within the slowdown limit, from a search measured on a sample of random rays \
             within a time budget (multiples of one bvh2 trace of them); the reason is the search's own account \
             (layout_choice). Search slowdown = the chosen layout's slowdown in the search (its random-ray \
             sample), the estimate the choice was made on; slowdown = this row's own measurement (its ray set, \
             with its spread). A choice above its limit in either is marked over limit (\"within noise\" when the \
             limit lies inside the measurement's noise band, see the findings); one cut short by the budget is \
             marked too."
        }
        @if !over.is_empty() {
            p.warn {
                b {
                    "Warning: " (over.len()) " layout=auto choice(s) exceed their max_slowdown in this report's own \
                     measurement"
                }
                " (the search judged them on its random-ray sample; other rays or machine load differ): "
                @for (i, (c, r)) in over.iter().enumerate() {
                    @if i > 0 { "; " }
                    (c.label) ": " (r.layout.as_deref().unwrap_or("")) " " (r.layout_params.as_deref().unwrap_or(""))
                    " at slowdown " (num(r.slowdown)) " > max_slowdown " (num(r.auto_max_slowdown)) " (search: "
                    (num(r.auto_search_slowdown)) ")"
                    @if over_within_noise(r) { ", within noise" }
                }
            }
        }
        @if cut > 0 {
            p.warn {
                (cut) " layout=auto search(es) ran out of their time budget before measuring every candidate that \
                 could have won (raise auto:budget=B); their choice is the best of those measured."
            }
        }
        table {
            tr {
                th { "case" } th { "chosen layout" } th { "params" } th { "topology B/tri" } th { "total B/tri" }
                th { "search slowdown" } th { "slowdown" } th { "spread" } th { "max_slowdown" } th { "budget cut" }
                th { "reason" }
            }
            @for (c, r) in &autos {
                tr {
                    td { (c.label) }
                    td { (r.layout.as_deref().unwrap_or("")) }
                    td { (r.layout_params.as_deref().unwrap_or("")) }
                    td.n { (num(r.topology_bytes_per_triangle)) }
                    td.n { (num(r.total_bytes_per_triangle)) }
                    td.n { (num(r.auto_search_slowdown)) }
                    @if r.auto_over_limit == Some(true) {
                        td.n.warn {
                            b {
                                (num(r.slowdown)) " over limit"
                                @if over_within_noise(r) { " (within noise)" }
                            }
                        }
                    } @else {
                        td.n { (num(r.slowdown)) }
                    }
                    td.n { (pct(r.slowdown_spread)) }
                    td.n { (num(r.auto_max_slowdown)) }
                    @match r.auto_budget_cut {
                        Some(true) => td.warn { b { "yes" } },
                        Some(false) => td { "no" },
                        None => td {},
                    }
                    td { (r.layout_choice.as_deref().unwrap_or("")) }
                }
            }
        }
    }
}
