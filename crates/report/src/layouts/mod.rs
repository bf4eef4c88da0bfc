//! The "compressed layouts" section (Kilian 2021, chapters 4-6), as plain functions over result
//! rows plus one figure type: per scene (and chain and ray set) bytes per triangle against trace
//! time, slowdown and extra triangle tests, one curve per layout family with the Pareto front; the
//! memory/chunk table (Kilian figures 4.16, 5.4, 6.3, 6.5), the speed/accuracy table, the findings
//! table (Kilian's qualitative claims checked per scene) and the `layout=auto` choices (the tables
//! are written in `sections/layouts.rs`).
use crate::html::Section;
use crate::sweeps::PlotFn;
use bvhlab_pipeline::ResultRow;
use std::collections::BTreeMap;

mod findings;
mod plot;
mod rows;

pub use findings::*;
pub use plot::*;
pub use rows::*;

/// The floor of the noise band (see `beyond_noise`): two timings within this many percent are never
/// told apart, however small their measured spreads (systematic run-to-run effects such as cache
/// and frequency state are not in the range of 5 runs).
pub const TIE_PERCENT: f64 = 2.0;
/// "Almost as fast" (Kilian 6.3: octree_1bit's increase over the octree "only very small"): at most
/// this ratio of trace times.
pub const ALMOST_AS_FAST: f64 = 1.15;
/// Issue 5's targets: qbvh_chunks within 1.5x of bvh2, qbvh_chunks topology at most 0.5x bvh2's, octree_1bit at most
/// 2 bits per node in 16-byte chunks.
pub const QBVH_CHUNKS_TARGET_SLOWDOWN: f64 = 1.5;
pub const QBVH_CHUNKS_TOPOLOGY_RATIO: f64 = 0.5;
pub const OCTREE_1BIT_BITS_16: f64 = 2.0;

/// Kilian's best-case topology bits per node (full chunks), with the section that states it.
/// qbvh_chunks: 5.2.1 (chunk bits plus the 48-bit key and 8-bit axis per node, so only for bits=8);
/// octree_1bit: 4.2.2 (the text's "512/488" for 64 B is a typo for 512/448 = 8/7); bvh2: 5.1 (256);
/// octree: 4.1 (32-bit nodes).
pub fn kilian_bits_per_node(layout: &str, params: &BTreeMap<String, String>) -> Option<(f64, &'static str)> {
    let chunk = params.get("chunk_bytes").map(String::as_str);
    match layout {
        "bvh2" => Some((256.0, "5.1")),
        "octree" => Some((32.0, "4.1")),
        "qbvh_chunks" if params.get("bits").is_none_or(|b| b == "8") => match chunk {
            Some("64") => Some((58.67, "5.2.1, best case")),
            Some("128") => Some((57.45, "5.2.1, best case")),
            _ => None,
        },
        "octree_1bit" => match chunk {
            Some("16") => Some((2.0, "4.2.2, best case")),
            Some("32") => Some((1.33, "4.2.2, best case")),
            Some("64") => Some((1.14, "4.2.2, best case")),
            Some("128") => Some((1.07, "4.2.2, best case")),
            _ => None,
        },
        _ => None,
    }
}

/// Kilian's stated chunk fill rates: octree_1bit about 30% (7, from 6.3), qbvh_chunks below 10% (5.2.3: the
/// highest, 64-byte chunks on Measure-one, "just under 10%"; 128 B lower).
pub fn kilian_fill(layout: &str) -> Option<&'static str> {
    match layout {
        "octree_1bit" => Some("~30% (ch. 7, fig. 6.3)"),
        "qbvh_chunks" => Some("< 10% (5.2.3, fig. 5.4)"),
        _ => None,
    }
}

// ---------------------------------------------------------------------------------------------
// Section (its tables are written in sections/layouts.rs)

/// An auto row over its limit whose measured slowdown is within noise of the limit (`at_most`):
/// still flagged (the flag is the plain comparison), but the excess is not resolved.
pub(crate) fn over_within_noise(r: &ResultRow) -> bool {
    match (r.slowdown, r.auto_max_slowdown) {
        (Some(s), Some(m)) => at_most(Timed { value: s, spread: r.slowdown_spread }, m) == Verdict::WithinNoise,
        _ => false,
    }
}

/// `None` when no row has a layout.
pub(crate) fn section(rows: &[ResultRow], plot: &mut PlotFn, problems: &mut Vec<String>) -> Option<Section> {
    if !rows.iter().any(|r| r.layout.is_some()) {
        return None;
    }
    let cs = cases(rows);
    let mut plots = Vec::new();
    for c in &cs {
        if c.points.is_empty() {
            continue;
        }
        let has = |m: Metric| c.points.iter().any(|p| m.of(p.row).is_some());
        let stem = c.label.replace(" · ", "_");
        for (what, ys, title) in [
            ("speed", [Metric::TraceSeconds, Metric::Slowdown], "bytes vs trace time"),
            ("accuracy", [Metric::ExtraTestsPerRay, Metric::ExtraBoxHitsPerRay], "bytes vs extra tests"),
        ] {
            let ys: Vec<Metric> = ys.into_iter().filter(|m| has(*m)).collect();
            if !ys.is_empty() {
                let fig = figure(c, &format!("{}: memory vs {what}", c.label), &ys);
                plots.extend(plot(&fig, &format!("layouts_{what}_{stem}"), &format!("{}: {title}", c.label), problems));
            }
        }
    }
    let extra = crate::sections::layouts::tables(&findings(rows), &cs);
    Some(Section {
        id: "layouts",
        title: "Compressed layouts (Kilian 2021)".into(),
        intro: "Layout stage: bvh2 (flat 32-byte nodes), bvh4 and bvh8 (4-/8-wide nodes, SIMD box tests), cwbvh (bvh8 in \
                80-byte nodes with 8-bit child boxes; Ylitie et al. 2017), qbvh_chunks (quantized boxes, 1-bit topology in \
                chunks; Kilian 5.2), octree (32-bit nodes; 4.1) and octree_1bit (1-bit octree in chunks; 4.2). Per scene \
                (and chain and ray set): bytes per triangle (topology, total) against trace time and slowdown vs bvh2, and \
                against the extra triangle tests and box hits quantization costs (cwbvh against bvh8, qbvh_chunks against \
                bvh2, octree_1bit against octree); one curve per layout family (a layout with every \
                parameter fixed but one), ringed points on the Pareto front (no other layout is both smaller and \
                cheaper). layout=auto rows are not plotted; they are in the last table."
            .into(),
        plots,
        extra,
        open: false,
    })
}
