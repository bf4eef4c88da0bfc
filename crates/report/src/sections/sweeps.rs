//! The drop table of the sweeps section (Riemersma 2024 eq. 13/14; the drops are computed in
//! `crate::analysis`).
use crate::analysis::{self, Drop, Sweep, DROP_THRESHOLD};
use crate::plots::fmt_num;
use maud::{html, Markup};

/// Measured against predicted drops of `metric` over one sweep; `d` = the number of axes the scene
/// bounds grow along.
pub fn drop_table(sw: &Sweep, metric: &str, d: f64, drops: &[Drop]) -> Markup {
    let last = sw.points.last().map(|p| fmt_num(p.0)).unwrap_or_default();
    let none = format!("none up to {} = {last}", sw.param);
    let opt = |v: Option<f64>| v.map(fmt_num).unwrap_or_else(|| none.clone());
    // Measured drops are sampled values: the true onset lies after the previous sample.
    let step = sw.points.windows(2).map(|w| w[1].0 - w[0].0).fold(f64::INFINITY, f64::min);
    html! {
        h3 { "Drops of " (metric) " over " (sw.title()) " (measured vs predicted, d = " (fmt_num(d)) ")" }
        @if drops.is_empty() {
            p { "No method with an encode stage in this sweep." }
        } @else {
            @if step.is_finite() {
                p {
                    (sw.param) " is sampled in steps of " (fmt_num(step)) ": a measured drop at " (sw.param)
                    " = x means the cost first exceeds " (format!("{:.0}", DROP_THRESHOLD * 100.0)) "% above its \
                     value at " (sw.param) " = " (fmt_num(sw.points[0].0)) " somewhere in (x \u{2212} "
                    (fmt_num(step)) ", x], so measured and predicted drops agree when they differ by less than one \
                     step."
                }
            }
            table {
                tr {
                    th { "builder" } th { "method" } th { "grid bits" } th { "measured drop" }
                    th { "same code without grid" } th { "its measured drop e_drop" } th { "move_d = grid_bits/d" }
                    th { "predicted drop" } th { "measured \u{2212} predicted" }
                }
                @for dr in drops {
                    @let grid = dr.grid_bits > 0;
                    @let with_reference = grid && dr.reference.is_some();
                    tr {
                        td { (dr.builder) }
                        td { (dr.method) }
                        td.n { (dr.grid_bits) }
                        td.n { (opt(dr.measured)) }
                        td { (dr.reference.as_deref().unwrap_or(if grid { "(not in this experiment)" } else { "" })) }
                        td.n { @if with_reference { (opt(dr.reference_drop)) } }
                        td.n { @if grid { (fmt_num(analysis::move_d(2f64.powi(dr.grid_bits as i32), d))) } }
                        td.n {
                            @if with_reference {
                                (dr.predicted.map(fmt_num).unwrap_or_else(|| "no drop of the reference".into()))
                            }
                        }
                        td.n {
                            @if let (Some(m), Some(p)) = (dr.measured, dr.predicted) {
                                @let x = m - p;
                                @if x >= 0.0 { "+" }
                                (fmt_num(x))
                            }
                        }
                    }
                }
            }
        }
    }
}
