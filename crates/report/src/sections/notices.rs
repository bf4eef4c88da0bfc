//! Notices near the top of the page: an incomplete report, timings from several CPU models.
use crate::{machine_name, TimingGroup};
use bvhlab_pipeline::ResultRow;
use maud::{html, Markup};

/// The notice about machines: one line when every timing comes from one CPU model, a warning box
/// with the per-machine row counts and every mixed row otherwise.
pub fn machines(rows: &[ResultRow], groups: &[TimingGroup]) -> Markup {
    let mixed: Vec<&ResultRow> = rows.iter().filter(|r| r.machine_mixed).collect();
    if groups.len() <= 1 && mixed.is_empty() {
        return html! {
            @if let Some(g) = groups.first() { p.meta { "Timings measured on: " (machine_name(&g.machine)) "." } }
        };
    }
    html! {
        div.invalid-box id="machines" {
            h2 { "Timings from more than one CPU model" }
            p {
                "These rows were computed on different machines (e.g. a sharded Slurm run). Timing plots, Pareto \
                 fronts and time ratios are drawn per CPU model (section titles say which); SAH costs, counts and \
                 bytes do not depend on the machine and merge all rows. Pin one model with "
                code { "bvhlab slurm --constraint" } " (or " code { "--partition" } ") to compare all timings."
            }
            ul { @for g in groups { li { (machine_name(&g.machine)) ": " (g.rows.len()) " rows" } } }
            @if !mixed.is_empty() {
                p.warn {
                    b { (mixed.len()) " rows have stages timed on different CPU models" }
                    " (e.g. built on one, traced on another): their trace times are left out of every timing plot \
                     and ratio; their build times still appear where the construction stages ran on one model."
                }
                table {
                    tr { th { "scene" } th { "method" } th { "machines" } }
                    @for r in &mixed {
                        tr.invalid { td { (r.scene_name) } td { (r.method) } td { (r.machine) } }
                    }
                }
            }
        }
    }
}

/// The box of a report with chains missing from the cache (`sweep --report-only`); empty without.
pub fn incomplete(missing: &[String]) -> Markup {
    html! {
        @if !missing.is_empty() {
            div.invalid-box id="incomplete" {
                h2 { "Incomplete: " (missing.len()) " chains missing from the cache" }
                p {
                    "Compute them (resubmit the same " code { "bvhlab slurm" } " command, or run "
                    code { "bvhlab sweep" } ") and build the report again. Missing:"
                }
                ul { @for m in missing { li { (m) } } }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn incomplete_box_escapes_and_is_empty_without_missing_chains() {
        assert_eq!(super::incomplete(&[]).into_string(), "");
        let h = super::incomplete(&["a <b>".into(), "c".into()]).into_string();
        assert_eq!(
            h,
            "<div class=\"invalid-box\" id=\"incomplete\"><h2>Incomplete: 2 chains missing from the cache</h2>\
             <p>Compute them (resubmit the same <code>bvhlab slurm</code> command, or run <code>bvhlab sweep</code>) \
             and build the report again. Missing:</p><ul><li>a &lt;b&gt;</li><li>c</li></ul></div>"
        );
    }
}
