//! The "optimization" section: convergence plots (Bittner 2013 figures 7 and 8) per (scene,
//! initial tree), the convergence table with the pass reaching 90% of each curve's final reduction,
//! Bittner 2013 table 2 beside ours, and thesis tables 20 and 38 (IBO after / before) per scene.
//! The tables are written in `sections/optimization.rs`.
use crate::convergence::{self, Group, REDUCTION_FRACTION};
use crate::html::Section;
use crate::plots::convergence::{ConvCurve, ConvergenceFigure};
use crate::reference::ReferenceReport;
use crate::sweeps::PlotFn;
use bvhlab_pipeline::ResultRow;

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
    let extra = crate::sections::optimization::tables(&groups, reference);
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
