//! The "scene-parameter sweeps" section: plots of metrics over generated scenes that differ in one
//! numeric parameter, and for the outlier distance the drop table of Riemersma 2024 (eq. 13/14),
//! written in `sections/sweeps.rs`.
use crate::analysis::{self, Drop, Series, Sweep, DROP_THRESHOLD, SWEEP_METRICS};
use crate::html::Section;
use crate::plots::sweep::{Curve, Marker, MarkerKind, SweepFigure, SweepPanel};
use crate::plots::{fmt_num, Plot};
use crate::DynFigure;
use bvhlab_pipeline::ResultRow;

pub type PlotFn<'a> = dyn FnMut(&dyn DynFigure, &str, &str, &mut Vec<String>) -> Option<Plot> + 'a;

/// Builds the figure of one metric over one sweep: one panel per builder with an encode stage
/// (one curve per encoder variant, colours shared across panels), top-down builders as dashed
/// reference curves in every panel; without encoder methods, one panel with every method.
pub fn figure(sweep: &Sweep, metric_label: &str, series: &[Series], drops: &[Drop]) -> SweepFigure {
    let mut encoders: Vec<&str> = Vec::new();
    let mut builders: Vec<&str> = Vec::new();
    for s in series {
        if let Some(e) = s.encoder.as_deref() {
            if !encoders.contains(&e) {
                encoders.push(e);
            }
            if !builders.contains(&s.builder.as_str()) {
                builders.push(&s.builder);
            }
        }
    }
    let refs: Vec<&Series> = series.iter().filter(|s| s.encoder.is_none()).collect();
    let invalid = |s: &Series, l: String| if s.valid { l } else { format!("{l} (INVALID)") };
    // One curve per series, labelled with its method and coloured by its position.
    let labelled = |series: &[&Series], reference: bool| -> Vec<Curve> {
        series
            .iter()
            .enumerate()
            .map(|(i, s)| Curve { label: invalid(s, s.label.clone()), color_index: i, reference, points: s.points.clone() })
            .collect()
    };
    let color_of = |s: &Series| {
        encoders
            .iter()
            .position(|e| Some(*e) == s.encoder.as_deref())
            .unwrap_or(0)
    };
    let mut panels = Vec::new();
    for b in &builders {
        let mut curves: Vec<Curve> = series
            .iter()
            .filter(|s| s.encoder.is_some() && s.builder == *b)
            .map(|s| Curve {
                label: invalid(s, s.encoder.clone().unwrap_or_default()),
                color_index: color_of(s),
                reference: false,
                points: s.points.clone(),
            })
            .collect();
        curves.extend(labelled(&refs, true));
        let mut markers = Vec::new();
        for d in drops.iter().filter(|d| d.builder == *b) {
            let Some(s) = series.iter().find(|s| s.label == d.method) else {
                continue;
            };
            if let Some(x) = d.measured {
                markers.push(Marker {
                    x,
                    color_index: color_of(s),
                    kind: MarkerKind::Measured,
                    label: format!("drop {}", fmt_num(x)),
                });
            }
            if let Some(x) = d.predicted {
                markers.push(Marker {
                    x,
                    color_index: color_of(s),
                    kind: MarkerKind::Predicted,
                    label: format!("predicted {}", fmt_num(x)),
                });
            }
        }
        panels.push(SweepPanel {
            title: b.to_string(),
            curves,
            markers,
        });
    }
    if builders.is_empty() {
        let curves = labelled(&series.iter().collect::<Vec<_>>(), false);
        panels.push(SweepPanel {
            title: "all methods".into(),
            curves,
            markers: Vec::new(),
        });
    }
    SweepFigure {
        caption: format!("{}: {}", sweep.title(), metric_label),
        x_desc: sweep.param.clone(),
        y_desc: metric_label
            .split(" (")
            .next()
            .unwrap_or(metric_label)
            .to_string(),
        panels,
    }
}

pub fn section(rows: &[ResultRow], plot: &mut PlotFn, problems: &mut Vec<String>) -> Section {
    let sweeps = analysis::find_sweeps(rows);
    let mut plots = Vec::new();
    let mut tables = Vec::new();
    for sw in &sweeps {
        let d = analysis::shift_model(sw);
        let has_focus = !analysis::sweep_series(sw, rows, &SWEEP_METRICS[0]).is_empty();
        for metric in SWEEP_METRICS {
            // The whole-scene cost only where there is no focus cost (with a far outlier it
            // measures the outlier, not the object).
            if metric.id == "sah_cost" && has_focus {
                continue;
            }
            let series = analysis::sweep_series(sw, rows, metric);
            if series.is_empty() {
                continue;
            }
            let cost_metric =
                metric.id == "focus_sah_cost" || (metric.id == "sah_cost" && !has_focus);
            let drops = match d {
                Some(d) if cost_metric => analysis::drops(&series, d),
                _ => Vec::new(),
            };
            let fig = figure(sw, metric.label, &series, &drops);
            let stem = format!("sweep_{}_{}_{}", sw.generator, sw.param, metric.id);
            plots.extend(plot(&fig, &stem, &fig.caption, problems));
            if cost_metric {
                if let Some(d) = d {
                    tables.push(crate::sections::sweeps::drop_table(sw, metric.id, d, &drops));
                }
            }
        }
    }
    let intro = if sweeps.is_empty() {
        "No generated scenes differing in one numeric parameter (e.g. gen:outlier:n=20000,e=0..30)."
            .to_string()
    } else {
        format!(
            "Generated scenes that differ in one numeric generator parameter, one curve per method. \
             Panels are builders with an encode stage, one curve per encoder; top-down builders are the \
             dashed reference curves in every panel. Measured drop: the first parameter value where a \
             method's cost exceeds its value at the smallest parameter value by more than {:.0}% (solid \
             vertical line). Predicted drop (dashed vertical line), Riemersma 2024 eq. 13/14: a grid of f = \
             2^grid_bits cells moves the drop by move_d(f) = log2(f)/d, so drop_d(f) = e_drop + move_d(f), \
             where e_drop is the measured drop of the same builder and encoder without the grid and d is \
             the number of axes the scene bounds grow along (d = 3 for gen:outlier, whose triangle moves \
             along (1,1,1)). Measured values come from this run; predicted ones from the formula.",
            DROP_THRESHOLD * 100.0
        )
    };
    Section {
        id: "sweeps",
        title: "Scene-parameter sweeps".into(),
        intro,
        plots,
        extra: maud::html! { @for t in &tables { (t) } },
        open: false,
    }
}
