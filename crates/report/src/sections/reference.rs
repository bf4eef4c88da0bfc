//! The reference comparison: our numbers beside the papers' tables (../shared/reference).
use super::{figure, Page};
use crate::plots::fmt_num;
use crate::reference::WITHIN_PERCENT;
use maud::{html, Markup};

const HOW: &str = "Only scenes that are the same model as a thesis scene (same triangle count) are compared; \
     FSW and BIN map to our chains as listed in crates/report/src/reference.rs. \
     AHQ/ALQ/PL1-3 are matched on our Morton-code rows (encoder morton, bits=auto, scene bounds, no grid); \
     the EMC-64-var rows of table 25 are ratios emc64-var / morton of the same builder and parameters, \
     in percent (build time = encode + build + compaction). \
     BP0/BP1/BP2 = bonsai n=512 / n=512 prune t=0.1 / n=4096 prune t=0.01; INC = incremental + collapse. \
     Tables 38 and 20: sweep-sah leaf=1, binned-sah (BIN), incremental, each + ibo (comb, schedule=thesis, the \
     last tree) + collapse; table 20 divides by the table-10 chain of the same method. Bittner 2013 table 2 \
     (scenes matched by triangle count in thousands): sweep-sah leaf=1 + collapse without optimizer (SAH build) \
     or with ibo random/comb (schedule=bittner), kensler-hc/-sa; cost before, ocost after compaction. \
     Difference = (ours - paper) / paper; flagged when |difference| > 3%.";

/// What to run to get paper numbers when this experiment has none.
pub const HOW_TO_GET_PAPER_NUMBERS: &str = "The paper tables need the real scenes: `bvhlab scenes fetch --all` \
     (see README, \"Real scenes\"), then `just frantal`, `just morton`, `just ibo`, `just bittner`, `just bonsai` \
     or `just kilian`.";

pub fn section_body(p: &Page) -> Markup {
    let rep = match &p.reference {
        None => {
            return html! {
                p { "No reference directory (../shared/reference) given: nothing compared. " (HOW_TO_GET_PAPER_NUMBERS) }
            }
        }
        Some(Err(e)) => return html! { p.warn { "Reference tables could not be read: " (e) } },
        Some(Ok(r)) => r,
    };
    html! {
        p { (HOW) }
        @if !rep.notes.is_empty() { ul { @for n in &rep.notes { li { (n) } } } }
        @if rep.comparisons.is_empty() {
            p { "No row of this experiment reproduces a paper table cell. " (HOW_TO_GET_PAPER_NUMBERS) }
        } @else {
            table {
                tr {
                    th{"source"} th{"metric"} th{"scene (ours)"} th{"paper scene"} th{"paper method"}
                    th{"our chain"} th{"ours"} th{"paper"} th{"difference"} th{ "within " (fmt_num(WITHIN_PERCENT)) "%" }
                }
                @for c in &rep.comparisons {
                    tr {
                        td { (c.source) } td { (c.metric) } td { (c.scene_name) } td { (c.thesis_scene) }
                        td { (c.abbrev) } td { (c.method) } td.n { (fmt_num(c.ours)) } td.n { (fmt_num(c.paper)) }
                        td.n { @if c.diff_percent.is_finite() { (format!("{:+.1}%", c.diff_percent)) } @else { "n/a" } }
                        td { (super::optimization::flag(c.diff_percent)) }
                    }
                }
            }
            @for plot in &p.reference_plots { (figure(plot)) }
        }
    }
}

pub fn section(p: &Page) -> Markup {
    super::section("reference", "Reference comparison (Frantal 2019 thesis, Bittner 2013)", false, section_body(p))
}
