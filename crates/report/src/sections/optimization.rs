//! The tables of the optimization section (curves in `crate::convergence`, paper numbers in
//! `crate::reference`): convergence per optimizer, thesis tables 38 and 20, Bittner 2013 table 2.
use crate::convergence::{Group, REDUCTION_FRACTION};
use crate::plots::fmt_num;
use crate::reference::{self, ReferenceReport, WITHIN_PERCENT};
use maud::{html, Markup};

fn num(v: f64) -> String {
    if v.is_finite() {
        fmt_num(v)
    } else {
        String::new()
    }
}

fn pct(v: f64) -> String {
    if v.is_finite() && v.abs() < 0.05 {
        "0.0%".into()
    } else if v.is_finite() {
        format!("{v:+.1}%")
    } else {
        String::new()
    }
}

/// Check mark within `WITHIN_PERCENT`, a red flag beyond it.
pub fn flag(diff_percent: f64) -> Markup {
    html! {
        @if diff_percent.is_finite() && diff_percent.abs() <= WITHIN_PERCENT {
            span.ok { "\u{2713}" }
        } @else if diff_percent.is_finite() {
            span.warn { "\u{2691} |diff| > " (fmt_num(WITHIN_PERCENT)) "%" }
        }
    }
}

/// All tables of the section, in page order; the paper tables only with a reference directory.
pub fn tables(groups: &[Group], reference: Option<&ReferenceReport>) -> Markup {
    html! {
        (convergence_table(groups))
        @if let Some(rep) = reference {
            (ibo_thesis_table(rep))
            (bittner_table(rep))
        }
    }
}

fn convergence_table(groups: &[Group]) -> Markup {
    let p = format!("{:.0}", REDUCTION_FRACTION * 100.0);
    html! {
        h3 { "Convergence per optimizer" }
        p {
            "cost = SAH cost before compaction (Bittner's \"cost\"); ocost = after SAH compaction when a chain of \
             the experiment compacts; update s = optimizer seconds; build s = build + optimize seconds (medians); \
             cost change = (cost \u{2212} cost start) / cost start; pass " (p) "% = first pass reaching " (p)
            "% of the final reduction. Rows \"(none)\" are the initial tree without optimizer."
        }
        table {
            tr {
                th { "scene" } th { "initial tree" } th { "optimizer" } th { "passes" } th { "stop" } th { "cost start" }
                th { "cost" } th { "ocost" } th { "cost change" } th { "update s" } th { "build s" }
                th { "pass " (p) "%" } th { "s at " (p) "%" }
            }
            @for g in groups {
                @if let Some((cost, ocost, secs)) = g.baseline {
                    tr {
                        td { (g.scene_name) } td { (g.initial) } td { "(none)" } td {} td {}
                        td.n { (num(cost)) } td.n { (num(cost)) } td.n { (ocost.map(num).unwrap_or_default()) } td {}
                        td.n { "0" } td.n { (num(secs)) } td {} td {}
                    }
                }
                @for c in &g.curves {
                    tr class=[(!c.valid).then_some("invalid")] {
                        td { (g.scene_name) }
                        td { (g.initial) }
                        td { (c.label) }
                        td.n { (c.passes) }
                        td { (c.stop) }
                        td.n { (num(c.start_cost)) }
                        td.n { (num(c.final_cost)) }
                        td.n { (c.ocost.map(num).unwrap_or_default()) }
                        td.n { (pct(-c.reduction_percent())) }
                        td.n { (num(c.optimize_seconds)) }
                        td.n { (num(c.build_seconds)) }
                        @match c.pass90 {
                            Some((p, s)) => { td.n { (p) } td.n { (num(s)) } }
                            None => { td.n { "-" } td.n {} }
                        }
                    }
                }
            }
        }
    }
}

/// Thesis tables 38 (cost after IBO) and 20 (after / before, %) side by side per (scene, method).
fn ibo_thesis_table(rep: &ReferenceReport) -> Markup {
    let mut cells: Vec<(&str, &str, &str)> = Vec::new();
    for c in rep
        .comparisons
        .iter()
        .filter(|c| c.metric == reference::IBO_COST_LABEL || c.metric == reference::IBO_RELATIVE_LABEL)
    {
        let k = (c.scene_name.as_str(), c.thesis_scene.as_str(), c.abbrev.as_str());
        if !cells.contains(&k) {
            cells.push(k);
        }
    }
    let get = |label: &str, scene: &str, abbrev: &str| {
        rep.comparisons.iter().find(|c| c.metric == label && c.scene_name == scene && c.abbrev == abbrev)
    };
    html! {
        h3 { "Thesis tables 38 and 20: IBO on FSW, BIN, INC" }
        @if cells.is_empty() {
            p {
                "No chain of this experiment reproduces a cell of thesis tables 20/38 (sweep-sah leaf=1, binned-sah \
                 bins=16 centroid_stop=any-axis leaf=2, or incremental, each with ibo (comb, ibo_frac 0.01, pt 10, \
                 pr 5, schedule=thesis, keep_best=false) and compact=collapse, on a thesis scene)."
            }
        } @else {
            p {
                "Table 38: SAH cost after IBO and compaction. Table 20: that cost relative to the non-optimized \
                 method of table 10 (FSW: sweep-sah leaf=2, BIN: binned-sah leaf=2, INC: incremental + collapse), \
                 in percent. Our chains use the thesis' termination (schedule=thesis: the cost checked every p_T = \
                 10 passes against the previous check, then random sampling checked every p_R = 5 passes; thesis \
                 3.4.3) and, like the thesis, return the last tree of the run (5.2.1). Its stop depends on noise in \
                 the random stage (the seed). Flag: |diff| > " (fmt_num(WITHIN_PERCENT)) "%."
            }
            table {
                tr {
                    th { "scene" } th { "thesis scene" } th { "method" } th { "ours after" } th { "thesis" }
                    th { "diff" } th {} th { "ours after/before" } th { "thesis" } th { "diff" } th {}
                    th { "our chain" }
                }
                @for (scene, ts, abbrev) in &cells {
                    @let got = [reference::IBO_COST_LABEL, reference::IBO_RELATIVE_LABEL].map(|l| get(l, scene, abbrev));
                    tr {
                        td { (scene) } td { (ts) } td { (abbrev) }
                        @for c in &got {
                            @if let Some(c) = c {
                                td.n { (fmt_num(c.ours)) } td.n { (fmt_num(c.paper)) } td.n { (pct(c.diff_percent)) }
                                td { (flag(c.diff_percent)) }
                            } @else {
                                td {} td {} td {} td {}
                            }
                        }
                        // The relative cell's chain (the method of table 20) when there is one.
                        td { (got[1].or(got[0]).map(|c| c.method.as_str()).unwrap_or("")) }
                    }
                }
            }
        }
    }
}

/// Bittner 2013 table 2 beside ours: cost, ocost (with differences), and the times, which come from
/// other hardware, also as multiples of the SAH build time of the same table.
fn bittner_table(rep: &ReferenceReport) -> Markup {
    let diff = |o: f64, p: f64| {
        if p != 0.0 && o.is_finite() && p.is_finite() {
            (o - p) / p * 100.0
        } else {
            f64::NAN
        }
    };
    let rel = |v: f64, base: Option<f64>| match base {
        Some(bv) if bv > 0.0 && v.is_finite() => format!("{:.2}x", v / bv),
        _ => String::new(),
    };
    html! {
        h3 { "Bittner 2013 table 2 (objects, SAH-built initial tree)" }
        @if rep.bittner.is_empty() {
            p {
                "No scene of this experiment has the triangle count of a Bittner 2013 table 2 scene, or no chain \
                 matches (sweep-sah leaf=1 + compact=collapse, without optimizer or with ibo random/comb, \
                 kensler-hc, kensler-sa)."
            }
        } @else {
            p {
                "cost = one triangle per leaf after the optimizer, ocost = after SAH compaction, update_s = \
                 optimization seconds, build_s = build + optimization seconds. The paper's times are from its \
                 machine: compare the ratios to the SAH build (x SAH build). Flag: |diff| > "
                (fmt_num(WITHIN_PERCENT)) "%."
            }
            table {
                tr {
                    th { "scene" } th { "paper scene" } th { "paper method" } th { "our chain" } th { "cost" }
                    th { "paper" } th { "diff" } th {} th { "ocost" } th { "paper" } th { "diff" } th {}
                    th { "update_s" } th { "paper" } th { "build_s" } th { "paper" } th { "build_s x SAH build" }
                    th { "paper" }
                }
                @for b in &rep.bittner {
                    @let base = rep.bittner.iter().find(|x| {
                        x.scene_name == b.scene_name
                            && x.paper_method == reference::BITTNER_METHODS[0].abbrev
                            && (x.machine == b.machine || x.machine.is_empty() || b.machine.is_empty())
                    });
                    @let (dc, doc) = (diff(b.ours[0], b.paper[0]), diff(b.ours[1], b.paper[1]));
                    tr {
                        td { (b.scene_name) } td { (b.paper_scene) } td { (b.paper_method) } td { (b.method) }
                        td.n { (num(b.ours[0])) } td.n { (num(b.paper[0])) } td.n { (pct(dc)) } td { (flag(dc)) }
                        td.n { (num(b.ours[1])) } td.n { (num(b.paper[1])) } td.n { (pct(doc)) } td { (flag(doc)) }
                        td.n { (num(b.ours[2])) } td.n { (num(b.paper[2])) }
                        td.n { (num(b.ours[3])) } td.n { (num(b.paper[3])) }
                        td.n { (rel(b.ours[3], base.map(|x| x.ours[3]))) }
                        td.n { (rel(b.paper[3], base.map(|x| x.paper[3]))) }
                    }
                }
            }
        }
    }
}
