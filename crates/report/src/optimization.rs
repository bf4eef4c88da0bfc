//! The "optimization" section: convergence plots (Bittner 2013 figures 7 and 8) per (scene,
//! initial tree), the convergence table with the pass reaching 90% of each curve's final reduction,
//! Bittner 2013 table 2 beside ours, and thesis tables 20 and 38 (IBO after / before) per scene.
use crate::convergence::{self, Group, REDUCTION_FRACTION};
use crate::html::{escape, Section};
use crate::plots::convergence::{ConvCurve, ConvergenceFigure};
use crate::plots::fmt_num;
use crate::reference::{self, ReferenceReport, WITHIN_PERCENT};
use crate::sweeps::PlotFn;
use bvhlab_pipeline::ResultRow;
use std::fmt::Write;

/// Figure of one group; colours by the report-wide list of optimizer keys.
pub fn figure(g: &Group, keys: &[String]) -> ConvergenceFigure {
    ConvergenceFigure {
        caption: format!("{}: optimizers on {}", g.scene_name, g.initial),
        curves: g
            .curves
            .iter()
            .map(|c| {
                let at = |pass: u32| {
                    c.points
                        .iter()
                        .find(|p| p.pass == pass)
                        .map(|p| (p.pass, p.seconds, p.sah_cost))
                };
                ConvCurve {
                    label: if c.valid {
                        c.label.clone()
                    } else {
                        format!("{} (INVALID)", c.label)
                    },
                    color_index: keys.iter().position(|k| *k == c.key).unwrap_or(0),
                    points: c
                        .points
                        .iter()
                        .map(|p| (p.pass, p.seconds, p.sah_cost))
                        .collect(),
                    mark: c.pass90.and_then(|(p, _)| at(p)),
                }
            })
            .collect(),
    }
}

/// `None` when no row has an optimize stage.
pub fn section(
    rows: &[ResultRow],
    reference: Option<&ReferenceReport>,
    plot: &mut PlotFn,
    problems: &mut Vec<String>,
) -> Option<Section> {
    if !rows.iter().any(|r| r.optimizer.is_some()) {
        return None;
    }
    let groups = convergence::groups(rows);
    let mut keys: Vec<String> = Vec::new();
    for c in groups.iter().flat_map(|g| g.curves.iter()) {
        if !keys.contains(&c.key) {
            keys.push(c.key.clone());
        }
    }
    let mut plots = Vec::new();
    for g in &groups {
        if g.curves.iter().all(|c| c.points.is_empty()) {
            continue;
        }
        let fig = figure(g, &keys);
        plots.extend(plot(
            &fig,
            &format!("convergence_{}_{}", g.scene_name, g.initial),
            &format!("{}: convergence on {}", g.scene_name, g.initial),
            problems,
        ));
    }
    let mut extra = convergence_table(&groups);
    if let Some(rep) = reference {
        extra.push_str(&ibo_thesis_table(rep));
        extra.push_str(&bittner_table(rep));
    }
    Some(Section {
        id: "optimization",
        title: "Optimization: convergence and cost".into(),
        intro: format!(
            "Optimize stage (ibo: Bittner et al. 2013; kensler-hc/-sa: tree rotations, Kensler 2008). One figure \
             per scene and initial tree, one curve per optimizer and measure from the pass-by-pass trace: SAH cost \
             (before compaction) against the optimizer's own seconds (left) and against the pass (right), like \
             Bittner 2013 figures 7 and 8. A ring marks the first pass whose cost has covered {:.0}% of the curve's \
             final reduction (final = the returned tree: the best one with keep_best). Optimizer chains are also on \
             the build time vs SAH cost chart, with build + optimize time.",
            REDUCTION_FRACTION * 100.0
        ),
        plots,
        extra,
        open: false,
    })
}

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
pub fn flag(diff_percent: f64) -> String {
    if diff_percent.is_finite() && diff_percent.abs() <= WITHIN_PERCENT {
        "<span class=\"ok\">&#10003;</span>".into()
    } else if diff_percent.is_finite() {
        format!(
            "<span class=\"warn\">&#9873; |diff| &gt; {}%</span>",
            fmt_num(WITHIN_PERCENT)
        )
    } else {
        String::new()
    }
}

fn convergence_table(groups: &[Group]) -> String {
    let mut h = String::new();
    let _ = write!(
        h,
        "<h3>Convergence per optimizer</h3>\n<p>cost = SAH cost before compaction (Bittner's \"cost\"); ocost = after \
         SAH compaction when a chain of the experiment compacts; update s = optimizer seconds; build s = build + \
         optimize seconds (medians); cost change = (cost &minus; cost start) / cost start; pass {p:.0}% = first pass reaching {p:.0}% of the final reduction. Rows \"(none)\" \
         are the initial tree without optimizer.</p>\n<table><tr><th>scene</th><th>initial tree</th><th>optimizer</th>\
         <th>passes</th><th>stop</th><th>cost start</th><th>cost</th><th>ocost</th><th>cost change</th><th>update s</th>\
         <th>build s</th><th>pass {p:.0}%</th><th>s at {p:.0}%</th></tr>\n",
        p = REDUCTION_FRACTION * 100.0
    );
    for g in groups {
        if let Some((cost, ocost, secs)) = g.baseline {
            let _ = writeln!(
                h,
                "<tr><td>{}</td><td>{}</td><td>(none)</td><td></td><td></td><td class=\"n\">{}</td><td class=\"n\">{}</td>\
                 <td class=\"n\">{}</td><td></td><td class=\"n\">0</td><td class=\"n\">{}</td><td></td><td></td></tr>",
                escape(&g.scene_name),
                escape(&g.initial),
                num(cost),
                num(cost),
                ocost.map(num).unwrap_or_default(),
                num(secs)
            );
        }
        for c in &g.curves {
            let cls = if c.valid { "" } else { " class=\"invalid\"" };
            let (p90, s90) = match c.pass90 {
                Some((p, s)) => (p.to_string(), num(s)),
                None => ("-".into(), String::new()),
            };
            let _ = writeln!(
                h,
                "<tr{cls}><td>{}</td><td>{}</td><td>{}</td><td class=\"n\">{}</td><td>{}</td><td class=\"n\">{}</td>\
                 <td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td>\
                 <td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td></tr>",
                escape(&g.scene_name),
                escape(&g.initial),
                escape(&c.label),
                c.passes,
                escape(&c.stop),
                num(c.start_cost),
                num(c.final_cost),
                c.ocost.map(num).unwrap_or_default(),
                pct(-c.reduction_percent()),
                num(c.optimize_seconds),
                num(c.build_seconds),
                p90,
                s90
            );
        }
    }
    h.push_str("</table>\n");
    h
}

/// Thesis tables 38 (cost after IBO) and 20 (after / before, %) side by side per (scene, method).
fn ibo_thesis_table(rep: &ReferenceReport) -> String {
    let mut cells: Vec<(String, String, String)> = Vec::new();
    for c in rep.comparisons.iter().filter(|c| {
        c.metric == reference::IBO_COST_LABEL || c.metric == reference::IBO_RELATIVE_LABEL
    }) {
        let k = (
            c.scene_name.clone(),
            c.thesis_scene.clone(),
            c.abbrev.clone(),
        );
        if !cells.contains(&k) {
            cells.push(k);
        }
    }
    let mut h = String::from("<h3>Thesis tables 38 and 20: IBO on FSW, BIN, INC</h3>\n");
    if cells.is_empty() {
        h.push_str(
            "<p>No chain of this experiment reproduces a cell of thesis tables 20/38 (sweep-sah leaf=1, binned-sah \
             bins=16 centroid_stop=any-axis leaf=2, or incremental, each with ibo (comb, ibo_frac 0.01, pt 10, pr 5, \
             schedule=thesis, keep_best=false) and compact=collapse, on a thesis scene).</p>\n",
        );
        return h;
    }
    let _ = write!(
        h,
        "<p>Table 38: SAH cost after IBO and compaction. Table 20: that cost relative to the non-optimized method of \
         table 10 (FSW: sweep-sah leaf=2, BIN: binned-sah leaf=2, INC: incremental + collapse), in percent. Our chains \
         use the thesis' termination (schedule=thesis: the cost checked every p_T = 10 passes against the previous \
         check, then random sampling checked every p_R = 5 passes; thesis 3.4.3) and, like the thesis, return the \
         last tree of the run (5.2.1). Its stop depends on noise in the random stage (the seed). Flag: |diff| &gt; \
         {}%.</p>\n<table><tr><th>scene</th><th>thesis scene</th><th>method</th><th>ours after</th><th>thesis</th>\
         <th>diff</th><th></th><th>ours after/before</th><th>thesis</th><th>diff</th><th></th><th>our chain</th></tr>\n",
        fmt_num(WITHIN_PERCENT)
    );
    for (scene, ts, abbrev) in &cells {
        let get = |label: &str| {
            rep.comparisons
                .iter()
                .find(|c| c.metric == label && c.scene_name == *scene && c.abbrev == *abbrev)
        };
        let mut row = format!(
            "<tr><td>{}</td><td>{}</td><td>{}</td>",
            escape(scene),
            escape(ts),
            escape(abbrev)
        );
        let mut method = String::new();
        for label in [reference::IBO_COST_LABEL, reference::IBO_RELATIVE_LABEL] {
            match get(label) {
                Some(c) => {
                    let _ = write!(
                        row,
                        "<td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td>{}</td>",
                        fmt_num(c.ours),
                        fmt_num(c.paper),
                        pct(c.diff_percent),
                        flag(c.diff_percent)
                    );
                    if method.is_empty() || label == reference::IBO_RELATIVE_LABEL {
                        method = c.method.clone();
                    }
                }
                None => row.push_str("<td></td><td></td><td></td><td></td>"),
            }
        }
        let _ = writeln!(h, "{row}<td>{}</td></tr>", escape(&method));
    }
    h.push_str("</table>\n");
    h
}

/// Bittner 2013 table 2 beside ours: cost, ocost (with differences), and the times, which come from
/// other hardware, also as multiples of the SAH build time of the same table.
fn bittner_table(rep: &ReferenceReport) -> String {
    let mut h = String::from("<h3>Bittner 2013 table 2 (objects, SAH-built initial tree)</h3>\n");
    if rep.bittner.is_empty() {
        h.push_str(
            "<p>No scene of this experiment has the triangle count of a Bittner 2013 table 2 scene, or no chain \
             matches (sweep-sah leaf=1 + compact=collapse, without optimizer or with ibo random/comb, kensler-hc, \
             kensler-sa).</p>\n",
        );
        return h;
    }
    let _ = write!(
        h,
        "<p>cost = one triangle per leaf after the optimizer, ocost = after SAH compaction, update_s = optimization \
         seconds, build_s = build + optimization seconds. The paper's times are from its machine: compare the \
         ratios to the SAH build (x SAH build). Flag: |diff| &gt; {}%.</p>\n<table><tr><th>scene</th><th>paper \
         scene</th><th>paper method</th><th>our chain</th><th>cost</th><th>paper</th><th>diff</th><th></th>\
         <th>ocost</th><th>paper</th><th>diff</th><th></th><th>update_s</th><th>paper</th><th>build_s</th>\
         <th>paper</th><th>build_s x SAH build</th><th>paper</th></tr>\n",
        fmt_num(WITHIN_PERCENT)
    );
    let diff = |o: f64, p: f64| {
        if p != 0.0 && o.is_finite() && p.is_finite() {
            (o - p) / p * 100.0
        } else {
            f64::NAN
        }
    };
    for b in &rep.bittner {
        let base = rep.bittner.iter().find(|x| {
            x.scene_name == b.scene_name
                && x.paper_method == reference::BITTNER_METHODS[0].abbrev
                && (x.machine == b.machine || x.machine.is_empty() || b.machine.is_empty())
        });
        let rel = |v: f64, base: Option<f64>| match base {
            Some(bv) if bv > 0.0 && v.is_finite() => format!("{:.2}x", v / bv),
            _ => String::new(),
        };
        let (dc, doc) = (diff(b.ours[0], b.paper[0]), diff(b.ours[1], b.paper[1]));
        let _ = writeln!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td>\
             <td class=\"n\">{}</td><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td>\
             <td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td>\
             <td class=\"n\">{}</td><td class=\"n\">{}</td></tr>",
            escape(&b.scene_name),
            escape(&b.paper_scene),
            escape(&b.paper_method),
            escape(&b.method),
            num(b.ours[0]),
            num(b.paper[0]),
            pct(dc),
            flag(dc),
            num(b.ours[1]),
            num(b.paper[1]),
            pct(doc),
            flag(doc),
            num(b.ours[2]),
            num(b.paper[2]),
            num(b.ours[3]),
            num(b.paper[3]),
            rel(b.ours[3], base.map(|x| x.ours[3])),
            rel(b.paper[3], base.map(|x| x.paper[3]))
        );
    }
    h.push_str("</table>\n");
    h
}
